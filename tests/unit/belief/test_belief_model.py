"""Transition model: stochasticity, the naive reference, injection zones, motion, advance."""

from __future__ import annotations

import numpy as np
import pytest
from belief_testkit import (
    corridors_graph,
    edge,
    fine_of,
    house_graph,
    location,
    naive_transition,
    odd_graph,
    route_graph,
    to_dense,
)

from server.belief.model import (
    Action,
    BeliefModel,
    TransitionParams,
    build_model,
    expected_advance,
)
from server.belief.tracker import predict
from server.domain import Edge, TourGraph


def all_actions(graph: TourGraph) -> list[Action]:
    acts = [Action.do_nothing(), Action.explore(), Action.navigate(), Action.navigate(0)]
    acts += [Action.rotate(j) for j in range(graph.n_edges)]
    return acts


GRAPHS = {
    "corridors": corridors_graph(12),
    "house": house_graph(),
    "odd": odd_graph(),
    "route": route_graph(),
}


@pytest.mark.parametrize("name", list(GRAPHS))
@pytest.mark.parametrize("advance", [0.0, 0.35, 1.0, 2.6])
def test_transition_is_row_stochastic_and_non_negative(name: str, advance: float) -> None:
    graph = GRAPHS[name]
    model = build_model(graph)
    for action in all_actions(graph):
        t = model.transition(action, advance=advance)
        assert t.shape == (graph.n_fine, graph.n_fine)
        assert t.data.min() >= 0
        np.testing.assert_allclose(t.sum(axis=1), 1.0, atol=1e-12)


@pytest.mark.parametrize("name", list(GRAPHS))
def test_transition_equals_naive_reference(name: str) -> None:
    graph = GRAPHS[name]
    params = TransitionParams()
    model = BeliefModel(graph, params)
    rng = np.random.default_rng(1)
    for action in all_actions(graph):
        # advances on the quantisation grid (0.05 images), different per edge
        advance = list(np.round(rng.uniform(0, 3, graph.n_edges) / 0.05) * 0.05)
        got = model.transition(action, advance=np.array(advance)).toarray()
        want = to_dense(naive_transition(graph, params, action, advance), graph.n_fine)
        np.testing.assert_allclose(got, want, atol=1e-12, err_msg=str(action))


@pytest.mark.parametrize("name", list(GRAPHS))
def test_factored_operator_equals_explicit_matrix(name: str) -> None:
    graph = GRAPHS[name]
    model = BeliefModel(graph)
    rng = np.random.default_rng(2)
    for action in all_actions(graph):
        adv = rng.uniform(0, 2, graph.n_edges)
        op = model.operator(action, advance=adv)
        t = model.transition(action, advance=np.round(adv / 0.05) * 0.05)
        b = rng.random(graph.n_fine)
        np.testing.assert_allclose(op.apply(b), t.T @ b, atol=1e-12)
        np.testing.assert_allclose(predict(b, op), predict(b, t), atol=1e-12)
        x = rng.random(graph.n_fine)
        np.testing.assert_allclose(op.apply_transpose(x), t @ x, atol=1e-12)


def test_predict_with_teleport_mixes_in_the_prior() -> None:
    graph = corridors_graph(10)
    model = BeliefModel(graph, TransitionParams(teleport=0.1))
    b = np.zeros(graph.n_fine)
    b[0] = 1.0
    out = model.predict(b, Action.do_nothing())
    np.testing.assert_allclose(out, 0.9 * b + 0.1 * model.prior)
    assert out.sum() == pytest.approx(1.0)


def test_prior_is_uniform_over_upper_states_and_within_edges() -> None:
    graph = corridors_graph(10)
    model = BeliefModel(graph)
    state = model.upper_mass(model.prior)
    np.testing.assert_allclose(state, 1 / graph.n_states)
    lo, hi = fine_of(graph, 0, 0), fine_of(graph, 0, 9) + 1
    np.testing.assert_allclose(model.prior[lo:hi], 1 / graph.n_states / 10)


def test_prior_skips_edges_without_images() -> None:
    graph = odd_graph()
    model = BeliefModel(graph)
    state = model.upper_mass(model.prior)
    assert state[graph.n_locations + 4] == 0.0
    np.testing.assert_allclose(state.sum(), 1.0)
    assert np.count_nonzero(state) == graph.n_states - 1


@pytest.mark.parametrize(
    "params",
    [
        TransitionParams(),
        # 001 Section 3.1's setting: tr(s, a, s_g) > tr(s, a, s)
        TransitionParams(rotate_loc_to_goal_edge=0.55, rotate_loc_to_other_edges=0.05),
    ],
)
def test_rotate_from_origin_lands_on_the_first_five_percent(params: TransitionParams) -> None:
    graph = TourGraph((location("a"), location("b")), (edge(0, 1, 100), edge(1, 0, 100)))
    model = BeliefModel(graph, params)
    b = np.zeros(graph.n_fine)
    b[0] = 1.0
    out = predict(b, model.transition(Action.rotate(0)))
    head = out[fine_of(graph, 0, 0) : fine_of(graph, 0, 5)]
    np.testing.assert_allclose(head, params.rotate_loc_to_goal_edge / 5)
    assert out[fine_of(graph, 0, 5) : fine_of(graph, 0, 99) + 1].sum() == 0
    assert out[0] == pytest.approx(1 - params.rotate_loc_to_goal_edge)
    if params.rotate_loc_to_goal_edge > 0.5:
        assert head.sum() > out[0]


def test_navigate_exits_only_from_the_last_five_percent() -> None:
    graph = TourGraph((location("a"), location("b")), (edge(0, 1, 40),))
    model = BeliefModel(graph)
    for k, expect_exit in ((37, False), (38, True), (39, True)):
        b = np.zeros(graph.n_fine)
        b[fine_of(graph, 0, k)] = 1.0
        out = model.operator(Action.navigate(0), advance=0.0).apply(b)
        assert (out[1] > 0) == expect_exit, k
        if expect_exit:
            assert out[1] == pytest.approx(model.params.navigate_exit)


def test_navigate_from_a_dead_end_spreads_like_the_prior() -> None:
    graph = route_graph()
    model = BeliefModel(graph)
    b = np.zeros(graph.n_fine)
    b[2] = 1.0  # all mass at "end", where no edge leaves
    out = model.operator(Action.navigate(), advance=0.0).apply(b)
    leave = model.params.navigate_dead_end
    assert out.sum() == pytest.approx(1.0)
    assert out[2] == pytest.approx(1 - leave + leave * model.prior[2])
    others = np.arange(graph.n_fine) != 2
    np.testing.assert_allclose(out[others], leave * model.prior[others], atol=1e-15)
    # a location with a way out sends Navigate's mass along it, not everywhere
    b[:] = 0.0
    b[1] = 1.0
    out = model.operator(Action.navigate(1), advance=0.0).apply(b)
    assert out[0] == 0.0 and out[fine_of(graph, 0, 0)] == 0.0
    # standing at a dead end under any other action keeps the mass there
    b[:] = 0.0
    b[2] = 1.0
    assert model.operator(Action.do_nothing(), advance=0.0).apply(b)[2] == pytest.approx(1.0)


def test_standing_still_stays_and_moving_advances_by_the_expected_amount() -> None:
    graph = TourGraph((location("a"), location("b")), (edge(0, 1, 60),))
    model = BeliefModel(graph)
    b = np.zeros(graph.n_fine)
    b[fine_of(graph, 0, 10)] = 1.0
    still = model.operator(Action.navigate(0), advance=0.0).apply(b)
    np.testing.assert_allclose(still, b)
    for a in (0.4, 1.0, 3.0):
        out = model.operator(Action.navigate(0), advance=a).apply(b)
        pos = np.arange(60)
        inner = out[fine_of(graph, 0, 0) : fine_of(graph, 0, 59) + 1]
        mean = float(inner @ pos)
        stall = model.params.navigate_stall
        assert mean == pytest.approx(10 + (1 - stall) * a, abs=1e-9)
        spread = float(inner @ (pos - mean) ** 2) ** 0.5
        assert spread < 0.6 + 0.5 * a  # a small kernel
    # rotating or doing nothing never moves along the edge
    for action in (Action.do_nothing(), Action.rotate(0)):
        out = model.operator(action, advance=5.0).apply(b)
        np.testing.assert_allclose(out, b)


def test_reverse_edge_gets_mass_near_the_mirrored_image() -> None:
    graph = TourGraph((location("a"), location("b")), (edge(0, 1, 50), edge(1, 0, 50)))
    model = BeliefModel(graph)
    b = np.zeros(graph.n_fine)
    b[fine_of(graph, 0, 10)] = 1.0  # 20% along a -> b
    out = predict(b, model.transition(Action.rotate(1)))
    rev = out[fine_of(graph, 1, 0) : fine_of(graph, 1, 49) + 1]
    assert rev.sum() == pytest.approx(model.params.rotate_edge_to_goal)
    assert abs(int(np.argmax(rev)) - 39) <= model.params.reverse_spread_images


def test_sibling_edge_gets_mass_uniformly() -> None:
    locs = (location("a"), location("b"), location("c"))
    graph = TourGraph(locs, (edge(0, 1, 20), edge(0, 2, 10)))
    model = BeliefModel(graph)
    b = np.zeros(graph.n_fine)
    b[fine_of(graph, 0, 7)] = 1.0
    out = predict(b, model.transition(Action.rotate(1)))
    sib = out[fine_of(graph, 1, 0) : fine_of(graph, 1, 9) + 1]
    np.testing.assert_allclose(sib, model.params.rotate_edge_to_goal / 10)


def test_expected_advance_from_speed_and_from_time() -> None:
    with_speed = edge(0, 1, 11, dt=0.5, v=0.2)  # 0.1 m per image
    ts = np.arange(5, dtype=np.float64) * 2.0
    no_speed = Edge(1, 0, (1, 2, 3, 4, 5), ts, np.zeros(5), np.zeros(5))  # 2 s per image
    single = edge(0, 1, 1)
    graph = TourGraph((location("a"), location("b")), (with_speed, no_speed, single))
    adv = expected_advance(graph, v=0.3, dt=0.5)
    np.testing.assert_allclose(adv, [1.5, 0.25, 0.0])
    np.testing.assert_allclose(expected_advance(graph, v=0.0, dt=0.5), [0, 0, 0])
    np.testing.assert_allclose(expected_advance(graph, v=float("nan"), dt=0.5), [0, 0.25, 0])
    np.testing.assert_allclose(BeliefModel(graph).expected_advance(v=0.3, dt=0.5), adv)


def test_invalid_parameters_and_actions_have_clear_errors() -> None:
    with pytest.raises(ValueError, match="sum to"):
        TransitionParams(rotate_loc_to_goal_edge=0.8, rotate_loc_to_other_edges=0.3)
    with pytest.raises(ValueError, match="teleport"):
        TransitionParams(teleport=-0.1)
    model = BeliefModel(corridors_graph(5))
    with pytest.raises(ValueError, match="edge index"):
        model.transition(Action.rotate(99))
    with pytest.raises(ValueError, match="RotateAndFindEdge needs"):
        model.transition(Action(Action.rotate(0).kind))
    with pytest.raises(ValueError, match="finite"):
        model.operator(Action.navigate(), advance=float("nan"))


def test_transition_is_cached() -> None:
    model = BeliefModel(house_graph())
    a = model.transition(Action.navigate(), advance=1.0)
    assert model.transition(Action.navigate(), advance=1.0) is a


def test_warm_up_builds_structures_once() -> None:
    model = BeliefModel(house_graph())
    model.warm_up()
    before = model.operator(Action.explore(), advance=1.0).structure
    assert model.operator(Action.explore(), advance=2.0).structure is before
    with pytest.raises(ValueError, match="edge index"):
        model.warm_up((Action.rotate(42),))
