"""Cost to goal (networkx) and the voting policy of 001 Section 7 on a small hand-made house."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from server.belief.model import Action, ActionKind, BeliefModel
from server.domain import Edge, Location, TourGraph
from server.policy.costs import CostParams, cost_to_goal, edge_costs, edge_remaining_s
from server.policy.voting import PolicyParams, build_vote_plan, decide

HALL, KITCHEN, OFFICE, BEDROOM, GARAGE = range(5)
_ids = iter(range(1_000_000))


def edge(source: int, target: int, n: int, dt: float = 0.5) -> Edge:
    ts = np.arange(n, dtype=np.float64) * dt
    return Edge(
        source, target, tuple(next(_ids) for _ in range(n)), ts, np.full(n, 0.3), np.zeros(n)
    )


def house() -> TourGraph:
    """Edge durations: 0-3 and 7 are 10 s, 4-5 (the long hall <-> office corridor) 40 s,
    6 (office -> bedroom, no reverse edge) 30 s. The garage has no edges at all."""
    names = ("hall", "kitchen", "office", "bedroom", "garage")
    locs = tuple(Location(n, tuple(next(_ids) for _ in range(4))) for n in names)
    es = (
        edge(HALL, KITCHEN, 21),  # 0
        edge(KITCHEN, HALL, 21),  # 1
        edge(KITCHEN, OFFICE, 21),  # 2
        edge(OFFICE, KITCHEN, 21),  # 3
        edge(HALL, OFFICE, 81),  # 4
        edge(OFFICE, HALL, 81),  # 5
        edge(OFFICE, BEDROOM, 61),  # 6
        edge(BEDROOM, HALL, 21),  # 7
    )
    return TourGraph(locs, es)


G = house()
TURN = CostParams().turn_into_edge_s  # 4 s


def at(graph: TourGraph, *weights: tuple[int, float]) -> np.ndarray:
    b = np.zeros(graph.n_fine)
    for f, w in weights:
        b[f] += w
    return b / b.sum()


def img(graph: TourGraph, j: int, k: int) -> int:
    return graph.n_locations + int(graph.edge_offsets[j]) + k


def test_edge_costs_are_duration_plus_turning() -> None:
    np.testing.assert_allclose(edge_costs(G)[[0, 4, 6]], [10 + TURN, 40 + TURN, 30 + TURN])


def test_cost_to_goal_uses_shortest_paths() -> None:
    costs = cost_to_goal(G, OFFICE)
    # hall: via the kitchen (14 + 14) beats the long corridor (44); bedroom: via the hall
    np.testing.assert_allclose(costs[:4], [28, 14, 0, 42])
    assert math.isinf(costs[GARAGE])
    np.testing.assert_allclose(cost_to_goal(G, BEDROOM)[:4], [62, 48, 34, 0])
    with pytest.raises(ValueError, match="location index"):
        cost_to_goal(G, 17)


def test_cost_params_change_the_route() -> None:
    # turning is so slow that one long corridor (one turn) beats two short ones (two turns)
    slow = CostParams(rotation_s=80.0)
    costs = cost_to_goal(G, OFFICE, slow)
    assert costs[HALL] == pytest.approx(40 + 40)


def test_costs_are_time_only_whatever_the_images_entropy() -> None:
    """The images' distinctiveness is shown, not planned with: costs and votes are the same
    with any entropies (least-ambiguous routes were removed, docs/ambiguity.md section 2)."""
    h = np.random.default_rng(0).uniform(0.0, 2.0, G.n_images)
    graph = dataclasses.replace(G, image_entropy=h)
    np.testing.assert_array_equal(edge_costs(graph), edge_costs(G))
    np.testing.assert_array_equal(edge_remaining_s(graph), edge_remaining_s(G))
    for goal in range(G.n_locations):
        np.testing.assert_array_equal(cost_to_goal(graph, goal), cost_to_goal(G, goal))
        plan = build_vote_plan(graph, goal, cost_to_goal(graph, goal))
        np.testing.assert_array_equal(
            plan.vote, build_vote_plan(G, goal, cost_to_goal(G, goal)).vote
        )


def test_location_picks_the_cheaper_route() -> None:
    d = decide(G, at(G, (HALL, 1.0)), OFFICE, cost_to_goal(G, OFFICE))
    assert d.action == Action.rotate(0)  # hall -> kitchen, not the long corridor (edge 4)
    assert d.votes[ActionKind.ROTATE_AND_FIND_EDGE] == pytest.approx(1.0)
    assert d.active_edge is None and d.target_image is None


def test_goal_says_do_nothing() -> None:
    d = decide(G, at(G, (OFFICE, 1.0)), OFFICE, cost_to_goal(G, OFFICE))
    assert d.action == Action.do_nothing()


def test_a_goal_not_yet_approached_votes_for_its_cheapest_round_trip() -> None:
    # office -> kitchen -> office (14 + 14 s) beats office -> hall -> ... (44 + 28 s)
    d = decide(G, at(G, (OFFICE, 1.0)), OFFICE, cost_to_goal(G, OFFICE), hold_goal=False)
    assert d.action == Action.rotate(3)
    # the cached plan for hold_goal=True is a different one
    d = decide(G, at(G, (OFFICE, 1.0)), OFFICE, cost_to_goal(G, OFFICE))
    assert d.action == Action.do_nothing()


def test_a_round_trip_goes_out_far_enough_to_come_back_along_taught_path() -> None:
    costs = cost_to_goal(G, OFFICE)
    # office -> kitchen (edge 3) is taught at 0.3 m/s, 0.15 m per image: 1.5 m is image 10
    near, far = img(G, 3, 2), img(G, 3, 15)
    held = build_vote_plan(G, OFFICE, costs)
    out = build_vote_plan(G, OFFICE, costs, hold_goal=False)
    # 0.3 m out, turning back onto kitchen -> office is cheapest, but coming back from there
    # would not be an approach: the round trip goes on
    assert held.vote[near] == 3 + 2
    assert out.vote[near] == 0  # Navigate
    # 2.25 m out it turns round as usual
    assert held.vote[far] == out.vote[far] == 3 + 2
    # edges that do not leave the goal are not affected
    assert np.array_equal(
        held.vote[img(G, 2, 0) : img(G, 2, 20) + 1], out.vote[img(G, 2, 0) : img(G, 2, 20) + 1]
    )
    # no commitment at all: the plain vote
    bare = build_vote_plan(G, OFFICE, costs, PolicyParams(round_trip_m=0.0), hold_goal=False)
    assert bare.vote[near] == 3 + 2


def test_a_goal_with_no_way_out_does_nothing_even_when_not_approached() -> None:
    plan = build_vote_plan(G, GARAGE, cost_to_goal(G, GARAGE), hold_goal=False)
    assert plan.vote[GARAGE] == 1  # DoNothing


def test_turns_back_on_an_edge_when_that_is_cheaper() -> None:
    costs = cost_to_goal(G, HALL)
    # 5 images into the 40 s corridor hall -> office, going to the hall: turn round (edge 5)
    d = decide(G, at(G, (img(G, 4, 5), 1.0)), HALL, costs)
    assert d.action == Action.rotate(5)
    # ... but near its end, going on to the office and back via the kitchen is cheaper
    d = decide(G, at(G, (img(G, 4, 78), 1.0)), HALL, costs)
    assert d.action.kind is ActionKind.NAVIGATE and d.active_edge == 4


def test_edge_without_reverse_can_only_go_on() -> None:
    costs = cost_to_goal(G, OFFICE)
    d = decide(G, at(G, (img(G, 6, 2), 1.0)), OFFICE, costs)  # office -> bedroom, just left
    assert d.action == Action.navigate(6)
    assert d.target_image == 3


def test_ties_go_to_navigate() -> None:
    costs = cost_to_goal(G, OFFICE)
    # half on hall (votes RotateAndFindEdge(0)), half inside hall -> kitchen (votes Navigate)
    b = at(G, (HALL, 0.5), (img(G, 0, 10), 0.5))
    d = decide(G, b, OFFICE, costs)
    assert d.votes[ActionKind.NAVIGATE] == pytest.approx(d.votes[ActionKind.ROTATE_AND_FIND_EDGE])
    assert d.action == Action.navigate(0)
    assert d.target_image == 11


def test_highest_vote_mass_wins_per_action() -> None:
    costs = cost_to_goal(G, OFFICE)
    b = at(G, (HALL, 0.4), (img(G, 0, 10), 0.35), (img(G, 2, 3), 0.25))
    d = decide(G, b, OFFICE, costs)
    assert d.action.kind is ActionKind.NAVIGATE  # 0.6 Navigate beats 0.4 Rotate
    assert d.active_edge == 0  # the navigating edge with the most belief
    assert sum(d.votes.values()) == pytest.approx(1.0)


def test_target_image_is_clipped_to_the_edge() -> None:
    costs = cost_to_goal(G, OFFICE)
    d = decide(G, at(G, (img(G, 2, 20), 1.0)), OFFICE, costs)
    assert d.action == Action.navigate(2) and d.target_image == 20


def test_explore_when_flat_or_no_route() -> None:
    costs = cost_to_goal(G, OFFICE)
    prior = BeliefModel(G).prior
    d = decide(G, prior, OFFICE, costs)
    assert d.action == Action.explore()
    assert sum(d.votes.values()) == pytest.approx(1.0)
    # the garage has no edge toward the goal: it votes Explore
    d = decide(G, at(G, (GARAGE, 1.0)), OFFICE, costs)
    assert d.action == Action.explore()
    assert d.votes[ActionKind.EXPLORE] == pytest.approx(1.0)
    # a threshold above 1 never explores for flatness: the plain vote decides
    d = decide(G, prior, OFFICE, costs, PolicyParams(explore_entropy=1.1))
    assert d.action.kind is not ActionKind.EXPLORE


def naive_votes(
    graph: TourGraph, goal: int, costs: np.ndarray, p: PolicyParams, hold_goal: bool = True
) -> list[Action]:
    """One action per fine state, with plain loops (the reference for the vectorised plan)."""
    L = graph.n_locations
    turn = p.costs.turn_into_edge_s
    out: list[Action] = []
    for k in range(L):
        if k == goal and hold_goal:
            out.append(Action.do_nothing())
            continue
        options = [
            (max(e.duration, p.costs.min_edge_s) + turn + costs[e.target], j)
            for j, e in enumerate(graph.edges)
            if e.source == k and e.n_images
        ]
        best = min(options, default=(math.inf, -1))
        if math.isfinite(best[0]):
            out.append(Action.rotate(best[1]))
        else:
            out.append(Action.do_nothing() if k == goal else Action.explore())
    for e in graph.edges:
        driven = 0.0
        for k in range(e.n_images):
            if k:
                driven += abs(e.v[k - 1]) * max(e.timestamps[k] - e.timestamps[k - 1], 0.0)
            go_on = (e.timestamps[-1] - e.timestamps[k]) + costs[e.target]
            back, back_edge = math.inf, -1
            committed = not hold_goal and e.source == goal and driven < p.round_trip_m
            for r, f in enumerate(graph.edges):
                if committed:
                    break
                if (f.source, f.target) != (e.target, e.source) or not f.n_images:
                    continue
                frac = k / (e.n_images - 1) if e.n_images > 1 else 0.5
                m = round((1 - frac) * (f.n_images - 1))
                c = p.costs.turn_back_s + (f.timestamps[-1] - f.timestamps[m]) + costs[f.target]
                if c < back:
                    back, back_edge = c, r
            if math.isinf(go_on) and math.isinf(back):
                out.append(Action.explore())
            elif go_on <= back:
                out.append(Action.navigate())
            else:
                out.append(Action.rotate(back_edge))
    return out


@pytest.mark.parametrize("hold_goal", [True, False])
@pytest.mark.parametrize("goal", [HALL, KITCHEN, OFFICE, BEDROOM, GARAGE])
def test_vote_plan_equals_naive_reference(goal: int, hold_goal: bool) -> None:
    p = PolicyParams()
    costs = cost_to_goal(G, goal)
    plan = build_vote_plan(G, goal, costs, p, hold_goal=hold_goal)
    want = naive_votes(G, goal, costs, p, hold_goal)
    code = {ActionKind.NAVIGATE: 0, ActionKind.DO_NOTHING: 1, ActionKind.EXPLORE: 2}
    got = [
        Action.rotate(int(v) - 3) if v >= 3 else Action(next(k for k, c in code.items() if c == v))
        for v in plan.vote
    ]
    assert got == want
    # and decide() on random peaked beliefs matches a naive tally
    rng = np.random.default_rng(goal)
    for _ in range(20):
        b = rng.random(G.n_fine) ** 8
        b /= b.sum()
        d = decide(
            G, b, goal, costs, PolicyParams(explore_entropy=2.0), plan=plan, hold_goal=hold_goal
        )
        tally: dict[Action, float] = {}
        for f, a in enumerate(want):
            tally[a] = tally.get(a, 0.0) + b[f]
        best = max(tally.values())
        winners = [a for a, v in tally.items() if v >= best - 1e-9]
        expect = next((a for a in winners if a.kind is ActionKind.NAVIGATE), None) or min(
            winners, key=lambda a: (a.kind is not ActionKind.ROTATE_AND_FIND_EDGE, a.edge or 0)
        )
        if expect.kind is ActionKind.NAVIGATE:
            assert d.action.kind is ActionKind.NAVIGATE
        else:
            assert d.action == expect
        for kind in ActionKind:
            total = sum(v for a, v in tally.items() if a.kind is kind)
            assert d.votes[kind] == pytest.approx(total)


def test_decide_errors() -> None:
    costs = cost_to_goal(G, OFFICE)
    with pytest.raises(ValueError, match="shape"):
        decide(G, np.ones(3), OFFICE, costs)
    with pytest.raises(ValueError, match="costs"):
        decide(G, BeliefModel(G).prior, OFFICE, costs[:2])
