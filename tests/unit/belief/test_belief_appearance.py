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
    familiarity,
    gated_mixture,
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


def test_familiarity_is_the_quantile_of_the_best_error_among_the_levels() -> None:
    levels = np.linspace(0.3, 0.7, 101)
    assert familiarity(0.1, levels) == 0.0
    assert familiarity(0.5, levels) == pytest.approx(50 / 101)  # 50 levels below 0.5
    assert familiarity(0.9, levels) == 1.0
    assert np.isnan(familiarity(float("nan"), levels))
    assert np.isnan(familiarity(0.5, np.zeros(0)))


def test_change_evidence_rises_from_change_low_to_change_high() -> None:
    p = AppearanceParams(change_low=0.5, change_high=0.6)
    assert change_evidence(0.2, p) == 0.0
    assert change_evidence(0.55, p) == pytest.approx(0.5)
    assert change_evidence(0.9, p) == 1.0
    # without information, or with the gate off, the models compete freely
    assert change_evidence(float("nan"), p) == 1.0
    assert change_evidence(0.2, AppearanceParams(change_gate=False)) == 1.0
    with pytest.raises(ValueError):
        AppearanceParams(change_low=0.5, change_high=0.5)
    with pytest.raises(ValueError):
        AppearanceParams(change_rate=0.0)


@settings(max_examples=60, deadline=None)
@given(
    st.floats(0.0, 2.0, allow_nan=False),
    arrays(np.float64, st.integers(1, 40), elements=st.floats(0.0, 1.5, allow_nan=False)),
)
def test_familiarity_and_change_are_bounded_and_monotone(error: float, levels: np.ndarray) -> None:
    levels = np.sort(levels)
    q = familiarity(error, levels)
    assert 0.0 <= q <= 1.0 and familiarity(error + 0.05, levels) >= q
    p = AppearanceParams()
    assert 0.0 <= change_evidence(q, p) <= change_evidence(min(q + 0.05, 1.0), p) <= 1.0


@settings(max_examples=60, deadline=None)
@given(
    arrays(np.float64, st.integers(1, 4), elements=st.floats(1e-3, 10.0, allow_nan=False)),
    st.floats(0.0, 1.0),
)
def test_gated_scores_and_mixture_match_the_naive_rules(scores: np.ndarray, g: float) -> None:
    naive = [scores[0]] + [s if s <= scores[0] else scores[0] ** (1 - g) * s**g for s in scores[1:]]
    np.testing.assert_allclose(gated_scores(scores, g), naive, rtol=1e-12)
    np.testing.assert_allclose(gated_scores(scores, 1.0), scores, rtol=1e-12)
    assert np.all(gated_scores(scores, 0.0)[1:] <= scores[0] * (1 + 1e-12))
    w = scores / scores.sum()
    mixed = gated_mixture(w, g)
    naive_w = np.array([w[0]] + [x * g for x in w[1:]])
    np.testing.assert_allclose(mixed, naive_w / naive_w.sum(), rtol=1e-12)
    np.testing.assert_allclose(gated_mixture(w, 0.0), np.eye(len(w))[0])


def test_in_the_tours_own_light_the_update_is_the_tours_model_alone(model: BeliefModel) -> None:
    """The changed model explains the frames better (the scenario above). Frames familiar to
    the tour (``familiarity`` 0): the belief is the one-model belief bit for bit and the
    changed model gains nothing; unfamiliar frames (1): it gains, as without the gate."""
    n = model.n_fine
    ends = {}
    for known in (0.0, 1.0):
        one, two = Tracker(model, TrackerParams()), Tracker(model, TrackerParams())
        rng = np.random.default_rng(1)
        for k in range(20):
            follows = _peak(n, 2 + k)
            wanders = _peak(n, int(rng.integers(0, n)))
            lik = np.stack([wanders, follows])
            a = two.step(Action.navigate(None), lik, v=0.3, dt=0.3, familiarity=known)
            b = one.step(Action.navigate(None), wanders, v=0.3, dt=0.3)
            if known == 0.0:
                np.testing.assert_array_equal(a.belief, b.belief)
                assert a.light_change == 0.0 and a.appearance == (1.0, 0.0)
        ends[known] = a
    assert ends[1.0].light_change == 1.0 and ends[1.0].appearance[1] > 0.9
    # no information (NaN, the default): the models compete freely
    free = Tracker(model, TrackerParams()).step(
        Action.navigate(None), np.stack([_peak(n, 3)] * 2), v=0, dt=0
    )
    assert free.light_change == 1.0
    single = Tracker(model, TrackerParams()).step(Action.navigate(None), _peak(n, 3), v=0, dt=0)
    assert single.light_change == 1.0


def test_the_change_evidence_follows_a_running_mean_of_the_familiarity(model: BeliefModel) -> None:
    """One unfamiliar frame among familiar ones moves the change evidence little; a stretch
    of them raises it to 1 (AppearanceParams.change_rate)."""
    p = AppearanceParams(change_rate=0.1, change_low=0.5, change_high=0.6)
    tracker = Tracker(model, TrackerParams(appearance=p))
    lik = np.stack([_peak(model.n_fine, 3)] * 2)
    g = [tracker.step(Action.navigate(None), lik, v=0, dt=0, familiarity=0.3).light_change]
    g.append(tracker.step(Action.navigate(None), lik, v=0, dt=0, familiarity=1.0).light_change)
    assert g == [0.0, 0.0]  # running mean 0.37
    for _ in range(30):
        last = tracker.step(Action.navigate(None), lik, v=0, dt=0, familiarity=1.0)
    assert last.light_change == 1.0
    tracker.reset()
    assert tracker.step(Action.navigate(None), lik, v=0, dt=0, familiarity=0.3).light_change == 0.0
