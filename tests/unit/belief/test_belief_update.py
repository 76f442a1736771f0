"""predict / update / fine_likelihood: naive references, named errors, hypothesis properties."""

from __future__ import annotations

import numpy as np
import pytest
from belief_testkit import corridors_graph, edge, house_graph, location
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from server.belief.model import Action, BeliefModel
from server.belief.tracker import (
    InvalidLikelihoodError,
    Tracker,
    ZeroLikelihoodError,
    fine_likelihood,
    predict,
    update,
)
from server.domain import Location, TourGraph

GRAPH = house_graph()
MODEL = BeliefModel(GRAPH)
N = GRAPH.n_fine

beliefs = arrays(np.float64, N, elements=st.floats(0, 1)).filter(lambda b: b.sum() > 1e-3)
likelihoods = arrays(np.float64, N, elements=st.floats(1e-6, 1.0))
actions = st.sampled_from(
    [Action.do_nothing(), Action.explore(), Action.navigate(2)]
    + [Action.rotate(j) for j in range(GRAPH.n_edges)]
)


def naive_update(belief: np.ndarray, likelihood: np.ndarray) -> np.ndarray:
    post = [b * lik for b, lik in zip(belief, likelihood, strict=True)]
    total = sum(post)
    return np.array([x / total for x in post])


def test_update_equals_naive_reference() -> None:
    rng = np.random.default_rng(3)
    b, lik = rng.random(N), rng.random(N)
    np.testing.assert_allclose(update(b, lik), naive_update(b, lik))


def test_predict_and_update_return_new_arrays() -> None:
    b = MODEL.prior.copy()
    lik = np.linspace(0.1, 1, N)
    before = b.copy()
    out = predict(b, MODEL.transition(Action.navigate(), advance=1.0))
    post = update(b, lik)
    assert out is not b and post is not b
    np.testing.assert_array_equal(b, before)


def test_update_errors_are_named_and_say_what_to_do() -> None:
    b = np.zeros(N)
    b[0] = 1.0
    lik = np.ones(N)
    lik[0] = 0.0
    with pytest.raises(ZeroLikelihoodError, match="floor"):
        update(b, lik)
    with pytest.raises(InvalidLikelihoodError, match="NaN"):
        update(b, np.full(N, np.nan))
    with pytest.raises(InvalidLikelihoodError, match="negative"):
        update(b, -np.ones(N))
    with pytest.raises(InvalidLikelihoodError, match="shape"):
        update(b, np.ones(N + 1))
    tracker = Tracker(MODEL)
    with pytest.raises(InvalidLikelihoodError):
        tracker.step(Action.do_nothing(), np.full(N, np.inf), v=0.0, dt=0.1)


def test_fine_likelihood_max_over_location_images_and_floor() -> None:
    locs = (location("a", 3), Location("empty", ()), location("b", 2))
    graph = TourGraph(locs, (edge(0, 2, 4),))
    sim = np.array([0.2, 0.9, 0.1, 0.3, 0.05, 0.5, 0.6, 0.0, 0.7])
    lik = fine_likelihood(sim, graph, floor=0.01)
    np.testing.assert_allclose(lik, [0.9, 0.01, 0.3, 0.5, 0.6, 0.01, 0.7])
    # naive reference through the domain maps
    ref = np.full(graph.n_fine, 0.01)
    for i, f in enumerate(graph.image_fine):
        ref[f] = max(ref[f], sim[i])
    np.testing.assert_allclose(lik, ref)
    with pytest.raises(InvalidLikelihoodError, match="canonical order"):
        fine_likelihood(sim[:-1], graph)


@settings(max_examples=60, deadline=None)
@given(b=beliefs, action=actions, advance=st.floats(0, 4))
def test_predict_keeps_mass_and_non_negativity(
    b: np.ndarray, action: Action, advance: float
) -> None:
    out = MODEL.predict(b, action, advance=advance)
    assert np.all(out >= 0)
    assert out.sum() == pytest.approx(b.sum(), rel=1e-9)


@settings(max_examples=60, deadline=None)
@given(b=beliefs, lik=likelihoods, scale=st.floats(1e-3, 1e3))
def test_update_sums_to_one_and_ignores_likelihood_scale(
    b: np.ndarray, lik: np.ndarray, scale: float
) -> None:
    post = update(b, lik)
    assert np.all(post >= 0)
    assert post.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(update(b, lik * scale), post, rtol=1e-9, atol=1e-15)


@settings(max_examples=40, deadline=None)
@given(
    liks=st.lists(likelihoods, min_size=1, max_size=4),
    action=actions,
    v=st.floats(0, 1),
    scale=st.floats(1e-2, 1e2),
)
def test_tracker_step_properties(
    liks: list[np.ndarray], action: Action, v: float, scale: float
) -> None:
    a, b = Tracker(MODEL), Tracker(MODEL)
    for lik in liks:
        s1 = a.step(action, lik, v=v, dt=0.2)
        s2 = b.step(action, lik * scale, v=v, dt=0.2)
    assert np.all(a.belief >= 0)
    assert a.belief.sum() == pytest.approx(1.0)
    assert s1.state.sum() == pytest.approx(1.0)
    # the evidence ratio is scale-free, so the whole step is
    np.testing.assert_allclose(a.belief, b.belief, rtol=1e-8, atol=1e-14)
    assert s1.localised == s2.localised


def test_summary_fields_match_a_naive_computation() -> None:
    graph = corridors_graph(10)
    model = BeliefModel(graph)
    rng = np.random.default_rng(5)
    tracker = Tracker(model)
    s = tracker.step(Action.navigate(0), rng.random(graph.n_fine) + 0.01, v=0.25, dt=0.5)
    b = s.belief
    L = graph.n_locations
    ref_state = np.zeros(graph.n_states)
    for f, st_ in enumerate(graph.fine_state):
        ref_state[st_] += b[f]
    np.testing.assert_allclose(s.state, ref_state)
    for j in range(graph.n_edges):
        lo, hi = L + int(graph.edge_offsets[j]), L + int(graph.edge_offsets[j + 1])
        np.testing.assert_allclose(s.along_edge[j], b[lo:hi] / b[lo:hi].sum())
        assert s.best_image[j] == int(np.argmax(b[lo:hi]))
    order = sorted(range(graph.n_states), key=lambda k: -ref_state[k])
    assert [k for k, _ in s.top_states] == order[: len(s.top_states)]
    p = ref_state[ref_state > 0]
    assert s.entropy == pytest.approx(float(-(p * np.log(p)).sum()))
    assert tracker.belief is not tracker.belief  # copies


def test_reset_gives_the_uniform_prior() -> None:
    tracker = Tracker(MODEL)
    tracker.step(Action.navigate(), np.linspace(0.01, 1, N), v=0.3, dt=0.2)
    tracker.reset()
    np.testing.assert_allclose(tracker.belief, MODEL.prior)
    s = tracker.last_summary
    np.testing.assert_allclose(s.state, 1 / GRAPH.n_states)
    assert not s.localised
