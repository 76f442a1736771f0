"""Least-ambiguous routes and active disambiguation (seed 000) on small hand-made tours."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_policy_voting import G, edge, house, img

from server.belief.model import Action, ActionKind, build_model
from server.domain import Location, TourGraph
from server.policy.costs import CostParams, cost_to_goal, edge_costs, edge_remaining_s
from server.policy.disambiguation import (
    DisambiguationParams,
    adjacency,
    disambiguate,
    expected_entropy,
    hypotheses,
    view_likelihood,
)
from server.policy.voting import PolicyParams, build_vote_plan, decide

HALL, KITCHEN, OFFICE, BEDROOM = range(4)


def with_entropy(graph: TourGraph, per_state: dict[int, float]) -> TourGraph:
    """``graph`` with every image's entropy set by its upper state (0 unless listed)."""
    h = np.array([per_state.get(int(s), 0.0) for s in graph.image_state])
    return dataclasses.replace(graph, image_entropy=h)


# ---------------------------------------------------------------- least-ambiguous routes


@settings(max_examples=40, deadline=None)
@given(entropy=st.lists(st.floats(0.0, 3.0), min_size=1, max_size=1).map(lambda x: x[0]))
def test_with_the_trade_off_at_zero_the_costs_are_todays(entropy: float) -> None:
    """lambda = 0: with or without entropies, every cost is exactly the time-only one."""
    rng = np.random.default_rng(int(entropy * 1000))
    graph = dataclasses.replace(G, image_entropy=rng.uniform(0, entropy + 1e-9, G.n_images))
    zero = CostParams(ambiguity_weight=0.0)
    np.testing.assert_array_equal(edge_costs(graph, zero), edge_costs(G))
    np.testing.assert_array_equal(edge_remaining_s(graph, zero), edge_remaining_s(G))
    for goal in range(G.n_locations):
        np.testing.assert_array_equal(cost_to_goal(graph, goal, zero), cost_to_goal(G, goal))
        plan = build_vote_plan(graph, goal, cost_to_goal(graph, goal, zero))
        today = build_vote_plan(G, goal, cost_to_goal(G, goal))
        np.testing.assert_array_equal(plan.vote, today.vote)


def test_each_step_costs_its_time_times_one_plus_lambda_mean_entropy() -> None:
    """Edge 0 (hall -> kitchen, 20 steps of 0.5 s) with every image at 0.5 nats and lambda 2
    costs 10 s x (1 + 2 x 0.5) = 20 s, plus the turn; remaining times scale alike."""
    graph = with_entropy(G, {G.n_locations + 0: 0.5})
    p = CostParams(ambiguity_weight=2.0)
    assert edge_costs(graph, p)[0] == pytest.approx(20.0 + p.turn_into_edge_s)
    assert edge_costs(graph, p)[1] == pytest.approx(edge_costs(G)[1])  # entropy 0: unchanged
    rem = edge_remaining_s(graph, p)[: G.edges[0].n_images]
    np.testing.assert_allclose(rem, 2.0 * edge_remaining_s(G)[: G.edges[0].n_images])
    # entropies not all known: time only
    unknown = dataclasses.replace(graph, image_entropy=np.full(G.n_images, np.nan))
    np.testing.assert_array_equal(edge_costs(unknown, p), edge_costs(G))


def test_a_longer_route_through_distinctive_images_wins_when_lambda_is_large() -> None:
    """hall -> office: through the kitchen (edges 0 and 2, 10 s each plus two 4 s turns: 28 s)
    or along the corridor (edge 4, 40 s plus one turn: 44 s). Time alone goes through the
    kitchen; when the kitchen's images look alike (1 nat) it costs 28 + 20 lambda, and from
    lambda 0.8 on the longer corridor wins."""
    graph = with_entropy(G, {G.n_locations + 0: 1.0, G.n_locations + 2: 1.0})
    route = {
        lam: decide(
            graph,
            np.eye(graph.n_fine)[HALL],
            OFFICE,
            cost_to_goal(graph, OFFICE, CostParams(ambiguity_weight=lam)),
            PolicyParams(costs=CostParams(ambiguity_weight=lam)),
        ).action
        for lam in (0.0, 0.5, 1.0)
    }
    assert route[0.0] == route[0.5] == Action.rotate(0)
    assert route[1.0] == Action.rotate(4)


# ---------------------------------------------------------------- disambiguation


def test_expected_entropy_matches_a_naive_loop_and_its_limits() -> None:
    prior = np.array([0.5, 0.3, 0.2])
    lik = np.array([[1.0, 0.2, 0.5], [0.3, 0.9, 0.1], [0.4, 0.4, 0.8]])
    naive = 0.0
    for h in range(3):
        post = [prior[k] * lik[h, k] ** 2 for k in range(3)]
        post = [x / sum(post) for x in post]
        naive += prior[h] * -sum(x * math.log(x) for x in post)
    assert expected_entropy(prior, lik, sharpness=2) == pytest.approx(naive)
    h_prior = -float((prior * np.log(prior)).sum())
    assert expected_entropy(prior, np.ones((3, 3))) == pytest.approx(h_prior)  # no information
    assert expected_entropy(prior, np.eye(3) + 1e-9, sharpness=4) == pytest.approx(0, abs=1e-6)
    # each row scaled: the same beliefs
    assert expected_entropy(prior, lik * [[2], [5], [0.1]], sharpness=2) == pytest.approx(naive)


def test_hypotheses_are_separated_regions_of_the_belief() -> None:
    """Mass on the hall and the edge leaving it is one region; the bedroom, not touching them
    (its edge to the hall holds nothing), is another; the kitchen's 0.01 is no one's."""
    model = build_model(G)
    b = np.zeros(G.n_fine)
    b[HALL], b[img(G, 0, 2)], b[BEDROOM], b[KITCHEN] = 0.3, 0.2, 0.49, 0.01
    hyp = hypotheses(model.upper_mass(b), adjacency(G), floor=0.02, min_mass=0.15)
    assert [s.tolist() for s in hyp.states] == [[HALL, G.n_locations + 0], [BEDROOM]]
    np.testing.assert_allclose(hyp.mass, [0.5, 0.49])
    assert hyp.leaders == ((HALL, 0.5), (BEDROOM, 0.49))


def twin_rooms() -> tuple[TourGraph, np.ndarray]:
    """Two look-alike rooms, A (0) and B (1), off a hall (2); a garden (3) reached from both.

    Edges: 0 A -> hall, 1 B -> hall (their first images look alike: the same door), 2 hall ->
    A, 3 hall -> B, 4 A -> garden, 5 B -> garden (the garden's sides look nothing alike), 6
    garden -> hall. The goal is the hall: from A or B the cheapest is the door (10 s), the
    garden way costs 10 s more. The view profile: A and B's spin views and the two doors look
    alike (0.9), everything else looks only like itself."""
    locs = tuple(Location(n, (900 + k,)) for k, n in enumerate(("A", "B", "hall", "garden")))
    es = (
        edge(0, 2, 21),
        edge(1, 2, 21),
        edge(2, 0, 21),
        edge(2, 1, 21),
        edge(0, 3, 21),
        edge(1, 3, 21),
        edge(3, 2, 21),
    )
    graph = TourGraph(locs, es)
    L = graph.n_locations
    alike = {0: 1, 1: 0, L + 0: L + 1, L + 1: L + 0}
    profile = np.full((graph.n_fine, graph.n_states), 0.05)
    for f, s in enumerate(graph.fine_state):
        profile[f, s] = 1.0
        if int(s) in alike:
            profile[f, alike[int(s)]] = 0.9
    return graph, profile


def test_disambiguation_picks_the_action_whose_next_views_separate_the_rooms() -> None:
    """Belief half in A, half in B. The votes head for the door (the same view from both
    rooms); the garden side tells them apart: disambiguation turns to find it."""
    graph, profile = twin_rooms()
    model = build_model(graph)
    goal = 2
    costs = cost_to_goal(graph, goal)
    plan = build_vote_plan(graph, goal, costs)
    belief = np.zeros(graph.n_fine)
    belief[0], belief[1] = 0.52, 0.48
    voted = decide(graph, belief, goal, costs, plan=plan).action
    assert voted == Action.rotate(0)  # A's door, the cheapest for the more likely room
    sep = disambiguate(graph, model, belief, plan, voted, costs, profile)
    assert sep is not None and sep.separating
    assert sep.action.kind is ActionKind.ROTATE_AND_FIND_EDGE and sep.action.edge in (4, 5)
    assert sep.expected_entropy < sep.voted_entropy - 0.1
    assert [s for s, _ in sep.hypotheses.leaders] == [0, 1]
    # a bound on the detour below the garden's 10 s keeps the door
    tight = DisambiguationParams(max_detour_s=5.0)
    kept = disambiguate(graph, model, belief, plan, voted, costs, profile, tight)
    assert kept is not None and not kept.separating and kept.action == voted
    # one room trusted: nothing to separate
    belief[0], belief[1] = 0.9, 0.1
    assert disambiguate(graph, model, belief, plan, voted, costs, profile) is None


def test_view_likelihood_is_the_expected_view_against_where_the_other_went() -> None:
    graph, profile = twin_rooms()
    q = np.zeros((2, graph.n_fine))
    q[0, 0] = q[1, 1] = 1.0  # in A, in B
    lik = view_likelihood(q, profile, graph.fine_state)
    np.testing.assert_allclose(lik, [[1.0, 0.9], [0.9, 1.0]])


def test_parameters_are_checked() -> None:
    with pytest.raises(ValueError):
        DisambiguationParams(min_mass=0.9, max_leader=0.5)
    assert house().n_locations == 5
