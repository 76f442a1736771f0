"""turn_rescale and the tracker's turning frames: a naive reference, properties, the switch."""

from __future__ import annotations

import math

import numpy as np
import pytest
from belief_testkit import house_graph
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from server.belief.model import Action, BeliefModel
from server.belief.tracker import Tracker, TrackerParams, turn_rescale

GRAPH = house_graph()
MODEL = BeliefModel(GRAPH)
N = GRAPH.n_fine
L = GRAPH.n_locations

beliefs = arrays(np.float64, N, elements=st.floats(1e-6, 1)).filter(
    lambda b: b[:L].sum() > 1e-4 and b[L:].sum() > 1e-4
)
likelihoods = arrays(np.float64, N, elements=st.floats(1e-6, 1.0))


def naive_turn_update(b: np.ndarray, lik: np.ndarray, power: float) -> np.ndarray:
    """The posterior of a turning frame written out: places' and edges' shares from the
    predicted shares and the evidence's, each side's inner ratios as a plain update."""
    places = [b[i] * lik[i] for i in range(L)]
    edges = [b[i] * lik[i] for i in range(L, N)]
    pred_p, pred_e = sum(b[:L]), sum(b[L:])
    ev_p, ev_e = sum(places), sum(edges)
    share_p = pred_p * (ev_p / (ev_p + ev_e) / pred_p) ** power
    share_e = pred_e * (ev_e / (ev_p + ev_e) / pred_e) ** power
    total = share_p + share_e
    out = [x / ev_p * share_p / total for x in places] + [x / ev_e * share_e / total for x in edges]
    return np.array(out)


@settings(max_examples=60, deadline=None)
@given(b=beliefs, lik=likelihoods, power=st.floats(0, 1))
def test_turn_rescale_equals_the_naive_reference(
    b: np.ndarray, lik: np.ndarray, power: float
) -> None:
    out = turn_rescale(b, lik, L, power)
    post = b * out
    np.testing.assert_allclose(post / post.sum(), naive_turn_update(b, lik, power), rtol=1e-8)


@settings(max_examples=60, deadline=None)
@given(b=beliefs, lik=likelihoods)
def test_power_zero_moves_no_mass_between_places_and_edges(b: np.ndarray, lik: np.ndarray) -> None:
    post = b * turn_rescale(b, lik, L, 0.0)
    post /= post.sum()
    assert post[:L].sum() == pytest.approx(b[:L].sum() / b.sum(), rel=1e-9)
    # within each side the frame weighs as any other
    inner = b[:L] * lik[:L]
    np.testing.assert_allclose(post[:L] / post[:L].sum(), inner / inner.sum(), rtol=1e-9)


@settings(max_examples=60, deadline=None)
@given(b=beliefs, lik=likelihoods)
def test_power_one_is_the_plain_update(b: np.ndarray, lik: np.ndarray) -> None:
    out = turn_rescale(b, lik, L, 1.0)
    np.testing.assert_allclose(out, lik, rtol=1e-9)


def test_a_side_without_mass_or_evidence_is_left_alone() -> None:
    b = np.zeros(N)
    b[L:] = 1.0
    lik = np.linspace(0.1, 1, N)
    np.testing.assert_array_equal(turn_rescale(b, lik, L, 0.0), lik)
    lik0 = lik.copy()
    lik0[:L] = 0.0
    np.testing.assert_array_equal(turn_rescale(np.ones(N), lik0, L, 0.0), lik0)


def _run(params: TrackerParams, v: float, w: float) -> np.ndarray:
    """Two frames: the first one driving (both trackers alike), the second with ``v``, ``w``
    and views that favour the places strongly."""
    tracker = Tracker(MODEL, params)
    rng = np.random.default_rng(7)
    tracker.step(Action.navigate(0), rng.random(N) + 0.05, v=0.25, w=0.0, dt=0.2)
    lik = np.full(N, 0.05)
    lik[:L] = 0.9
    tracker.step(Action.rotate(0), lik, v=v, w=w, dt=0.2)
    return tracker.belief


def test_the_tracker_keeps_the_split_only_while_turning_on_the_spot() -> None:
    on = TrackerParams(turn_split_power=0.0)
    off = TrackerParams()
    # turning on the spot: the places gain nothing from the frame with the split kept
    kept, plain = _run(on, 0.0, 0.5), _run(off, 0.0, 0.5)
    assert kept[:L].sum() < 0.5 * plain[:L].sum()
    # driving, or turning too slowly: the same as without it
    np.testing.assert_allclose(_run(on, 0.2, 0.5), _run(off, 0.2, 0.5))
    np.testing.assert_allclose(_run(on, 0.0, 0.1), _run(off, 0.0, 0.1))
    assert math.isclose(float(kept.sum()), 1.0)


def test_turn_split_parameters_are_checked() -> None:
    with pytest.raises(ValueError, match="turn_split_power"):
        TrackerParams(turn_split_power=1.5)
    with pytest.raises(ValueError, match="turn_split_power"):
        TrackerParams(turn_w=-1.0)
