"""The belief over appearance models (server/belief/appearance.py) and the tracker's use of it."""

from __future__ import annotations

import numpy as np
import pytest
from belief_testkit import route_graph
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from server.belief.appearance import (
    AppearanceParams,
    change_evidence,
    gated_scores,
    model_scores,
    posterior,
    update_log_posterior,
)
from server.belief.model import Action, BeliefModel, build_model
from server.belief.tracker import Tracker, TrackerParams

positive = st.floats(0.01, 1.0, allow_nan=False)


@settings(max_examples=50, deadline=None)
@given(arrays(np.float64, 6, elements=positive), arrays(np.float64, (3, 6), elements=positive))
def test_scores_match_the_naive_formula(b: np.ndarray, lik: np.ndarray) -> None:
    naive = [sum(b[i] * row[i] for i in range(6)) / (b.sum() * row.mean()) for row in lik]
    np.testing.assert_allclose(model_scores(b, lik), naive, rtol=1e-12)
    np.testing.assert_allclose(model_scores(3.0 * b, 7.0 * lik), naive, rtol=1e-9)  # scale free


def test_a_model_peaked_where_the_belief_is_scores_above_a_flat_one_and_a_wrong_one() -> None:
    b = np.array([0.0, 0.9, 0.1, 0.0])
    right = np.array([0.1, 1.0, 0.2, 0.1])
    flat = np.ones(4)
    wrong = np.array([1.0, 0.1, 0.1, 0.2])
    s = model_scores(b, np.stack([right, flat, wrong]))
    assert s[0] > 1.0 > s[2]
    assert s[1] == pytest.approx(1.0)


def test_the_log_posterior_forgets_and_the_posterior_is_a_distribution() -> None:
    p = AppearanceParams(memory=0.5)
    lp = update_log_posterior(np.zeros(2), [4.0, 1.0], p)
    assert lp.max() == 0.0 and lp[1] == pytest.approx(-np.log(4.0))
    again = update_log_posterior(lp, [1.0, 1.0], p)  # no new evidence: half forgotten
    assert again[1] == pytest.approx(-0.5 * np.log(4.0))
    pi = posterior(again)
    assert pi.sum() == pytest.approx(1.0) and pi[0] > pi[1]
    floored = update_log_posterior(np.zeros(2), [1.0, 0.0], p)  # one blank frame cannot veto
    assert np.isfinite(floored).all()
    with pytest.raises(ValueError):
        AppearanceParams(memory=1.0)


@pytest.fixture(scope="module")
def model() -> BeliefModel:
    return build_model(route_graph(30))


def _peak(n: int, at: int, width: float = 1.5) -> np.ndarray:
    return 0.05 + np.exp(-0.5 * ((np.arange(n) - at) / width) ** 2)


def test_two_identical_models_give_the_single_model_belief(model: BeliefModel) -> None:
    one, two = Tracker(model, TrackerParams()), Tracker(model, TrackerParams())
    rng = np.random.default_rng(0)
    for _ in range(15):
        lik = rng.uniform(0.05, 1.0, model.n_fine)
        a = one.step(Action.navigate(None), lik, v=0.3, dt=0.5)
        b = two.step(Action.navigate(None), np.stack([lik, lik]), v=0.3, dt=0.5)
        np.testing.assert_allclose(a.belief, b.belief, rtol=1e-10, atol=1e-14)
        assert b.appearance == pytest.approx((0.5, 0.5)) and a.appearance == (1.0,)


def test_the_model_that_follows_the_motion_gains_the_belief(model: BeliefModel) -> None:
    tracker = Tracker(model, TrackerParams())
    rng = np.random.default_rng(1)
    n = model.n_fine
    for k in range(20):
        follows = _peak(n, 2 + k)  # a robot advancing about one image per step
        wanders = _peak(n, int(rng.integers(0, n)))
        summary = tracker.step(Action.navigate(None), np.stack([wanders, follows]), v=0.3, dt=0.3)
    assert summary.appearance[1] > 0.9
    tracker.reset()
    assert tracker.step(Action.navigate(None), np.ones((2, n)), v=0.3, dt=0.3).appearance == (
        pytest.approx(0.5),
        pytest.approx(0.5),
    )


# ------------------------------------------------------------------ the change evidence


def test_change_evidence_rises_from_the_low_to_the_high_quantile_of_the_levels() -> None:
    levels = np.linspace(0.3, 0.7, 101)  # quantiles 0.1 / 0.5 = 0.34 / 0.5
    p = AppearanceParams()
    assert change_evidence(0.1, levels, p) == 0.0
    assert change_evidence(0.34, levels, p) == pytest.approx(0.0, abs=1e-12)
    assert change_evidence(0.42, levels, p) == pytest.approx(0.5)
    assert change_evidence(0.5, levels, p) == pytest.approx(1.0)
    assert change_evidence(0.9, levels, p) == 1.0
    # without information, or with the gate off, the models compete freely
    assert change_evidence(float("nan"), levels, p) == 1.0
    assert change_evidence(0.1, np.zeros(0), p) == 1.0
    assert change_evidence(0.1, levels, AppearanceParams(change_gate=False)) == 1.0
    with pytest.raises(ValueError):
        AppearanceParams(familiar_low=0.5, familiar_high=0.5)


@settings(max_examples=60, deadline=None)
@given(
    st.floats(0.0, 2.0, allow_nan=False),
    arrays(np.float64, st.integers(1, 40), elements=st.floats(0.0, 1.5, allow_nan=False)),
)
def test_change_evidence_is_bounded_and_monotone(error: float, levels: np.ndarray) -> None:
    p = AppearanceParams()
    g = change_evidence(error, levels, p)
    assert 0.0 <= g <= 1.0
    assert change_evidence(error + 0.05, levels, p) >= g


@settings(max_examples=60, deadline=None)
@given(
    arrays(np.float64, st.integers(1, 4), elements=st.floats(1e-3, 10.0, allow_nan=False)),
    st.floats(0.0, 1.0),
)
def test_gated_scores_match_the_naive_rule(scores: np.ndarray, g: float) -> None:
    naive = [scores[0]] + [s if s <= scores[0] else scores[0] ** (1 - g) * s**g for s in scores[1:]]
    out = gated_scores(scores, g)
    np.testing.assert_allclose(out, naive, rtol=1e-12)
    assert np.all(out[1:] <= np.maximum(scores[1:], scores[0]) * (1 + 1e-12))
    np.testing.assert_allclose(gated_scores(scores, 1.0), scores, rtol=1e-12)
    assert np.all(gated_scores(scores, 0.0)[1:] <= scores[0] * (1 + 1e-12))


def test_in_the_tours_own_light_the_changed_model_cannot_gain_the_belief(
    model: BeliefModel,
) -> None:
    """The scenario of the test above, the changed model explaining the frames better: with
    the change evidence at 0 (every frame seen in the tour's light) it never gains; at 1 it
    does, as before the gate."""
    n = model.n_fine
    runs = {}
    for change in (0.0, 1.0):
        tracker = Tracker(model, TrackerParams())
        rng = np.random.default_rng(1)
        for k in range(20):
            follows = _peak(n, 2 + k)
            wanders = _peak(n, int(rng.integers(0, n)))
            lik = np.stack([wanders, follows])
            summary = tracker.step(Action.navigate(None), lik, v=0.3, dt=0.3, change=change)
            assert summary.light_change == change
        runs[change] = summary.appearance[1]
    assert runs[0.0] <= 0.5
    assert runs[1.0] > 0.9
    single = Tracker(model, TrackerParams()).step(Action.navigate(None), _peak(n, 3), v=0, dt=0)
    assert single.light_change == 1.0
