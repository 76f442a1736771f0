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
