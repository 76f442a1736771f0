"""The belief over appearance models (server/belief/appearance.py) and the tracker's use of it."""

from __future__ import annotations

import json

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
from server.belief.tracker import BeliefError, Tracker, TrackerMemory, TrackerParams

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
    fixed = TrackerParams(changed_likelihood_power=None)  # the same power at any change evidence
    one, two = Tracker(model, fixed), Tracker(model, fixed)
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


# ------------------------------------------------------------------ memory across a restart


def _run(tracker: Tracker, n: int, start: int, rng: np.random.Generator) -> list:
    """``n`` steps of the scenario above, frames unfamiliar from the fifth on."""
    out = []
    size = tracker.model.n_fine
    for k in range(start, start + n):
        lik = np.stack([_peak(size, int(rng.integers(0, size))), _peak(size, 2 + k)])
        known = 0.2 if k < 4 else 0.9
        out.append(tracker.step(Action.navigate(None), lik, v=0.3, dt=0.3, familiarity=known))
    return out


def test_a_belief_restored_with_the_trackers_memory_goes_on_as_the_tracker_would(
    model: BeliefModel,
) -> None:
    """A restarted server restores the belief and the memory saved with it: the next steps
    are the original tracker's (to rounding: the restored belief is normalised again). Restored
    without it, the appearance models start level again and the steps differ."""
    original = Tracker(model, TrackerParams())
    _run(original, 30, 0, np.random.default_rng(2))  # the gate opens from the 20th
    saved = TrackerMemory.from_dict(json.loads(json.dumps(original.memory().to_dict())))
    assert saved == original.memory() and saved.appearance[0] != saved.appearance[1]
    restored, forgetful = Tracker(model, TrackerParams()), Tracker(model, TrackerParams())
    restored.set_belief(original.belief, saved)
    forgetful.set_belief(original.belief)
    ahead = [_run(t, 6, 30, np.random.default_rng(3)) for t in (original, restored, forgetful)]
    for a, b in zip(ahead[0], ahead[1], strict=True):
        np.testing.assert_allclose(a.belief, b.belief, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(a.appearance, b.appearance, rtol=1e-12)
        assert a.light_change == b.light_change  # the running mean is restored exactly
        assert a.evidence == pytest.approx(b.evidence, rel=1e-12)
    assert ahead[2][0].appearance != pytest.approx(ahead[0][0].appearance, rel=1e-3)
    assert ahead[2][0].light_change < ahead[0][0].light_change  # the running mean restarted


def test_a_fresh_tracker_assumes_the_tours_light_until_a_stretch_of_frames_says_otherwise(
    model: BeliefModel,
) -> None:
    """The running mean starts at ``change_prior`` (0), not at the first frame's own
    familiarity: a robot that starts facing a bare wall (every frame unfamiliar) uses the
    tour's model alone for 16 frames and both from the 21st on (change_rate 0.05)."""
    tracker = Tracker(model, TrackerParams())
    lik = np.stack([_peak(model.n_fine, 3)] * 2)
    g = [
        tracker.step(Action.navigate(None), lik, v=0, dt=0, familiarity=0.9).light_change
        for _ in range(25)
    ]
    assert g[:15] == [0.0] * 15 and 0.0 < g[17] < 1.0 and g[21:] == [1.0] * 4
    started_at_first = Tracker(model, TrackerParams(appearance=AppearanceParams(change_prior=0.9)))
    assert (
        started_at_first.step(Action.navigate(None), lik, v=0, dt=0, familiarity=0.9).light_change
        == 1.0
    )
    with pytest.raises(ValueError):
        AppearanceParams(change_prior=1.5)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(-50, 0, allow_nan=False), max_size=4),
    st.one_of(st.just(float("nan")), st.floats(0, 1)),
    st.floats(-1, 2, allow_nan=False),
    st.floats(-1, 2, allow_nan=False),
)
def test_tracker_memory_survives_strict_json(
    appearance: list[float], familiar: float, fast: float, slow: float
) -> None:
    memory = TrackerMemory(tuple(appearance), familiar, fast, slow)
    text = json.dumps(memory.to_dict(), allow_nan=False)  # strict JSON: NaN as null
    back = TrackerMemory.from_dict(json.loads(text))
    assert back.appearance == memory.appearance
    assert (back.evidence_fast, back.evidence_slow) == (fast, slow)
    assert back.familiar == familiar or (np.isnan(back.familiar) and np.isnan(familiar))


@pytest.mark.parametrize(
    "bad",
    [
        [1, 2],
        {"appearance": "ab"},
        {"appearance": [None]},
        {"familiar": "0.5"},
        {"evidence_fast": True},
    ],
)
def test_unreadable_tracker_memory_is_a_belief_error(bad: object) -> None:
    with pytest.raises(BeliefError):
        TrackerMemory.from_dict(bad)  # type: ignore[arg-type]


@pytest.mark.parametrize(("known", "power"), [(0.0, 1.0), (1.0, 0.75), (0.55, 0.875)])
def test_the_likelihood_is_tempered_as_the_change_evidence_rises(
    model: BeliefModel, known: float, power: float
) -> None:
    """Two identical models give the one-model belief at ``likelihood_power`` (1) while the
    frames are familiar (running mean 0: ``g`` = 0, bit for bit), at ``changed_likelihood_power``
    (0.75) once the gate is open (``g`` = 1), and in between halfway (``g`` = 0.5). One model
    alone keeps ``likelihood_power`` whatever the frames."""
    rng = np.random.default_rng(4)
    start = rng.uniform(0.0, 1.0, model.n_fine)
    lik = rng.uniform(0.05, 1.0, model.n_fine)
    two, alone, plain = (Tracker(model, TrackerParams()) for _ in range(3))
    one = Tracker(model, TrackerParams(likelihood_power=power))
    two.set_belief(start, TrackerMemory(familiar=known))
    for t in (one, alone, plain):
        t.set_belief(start)
    a = two.step(Action.navigate(None), np.stack([lik, lik]), v=0.3, dt=0.5, familiarity=known)
    b = one.step(Action.navigate(None), lik, v=0.3, dt=0.5)
    c = alone.step(Action.navigate(None), lik, v=0.3, dt=0.5, familiarity=known)
    d = plain.step(Action.navigate(None), lik, v=0.3, dt=0.5)
    assert a.light_change == pytest.approx((power - 1.0) / (0.75 - 1.0))
    np.testing.assert_array_equal(c.belief, d.belief)
    if known == 0.0:
        np.testing.assert_array_equal(a.belief, b.belief)
    else:
        np.testing.assert_allclose(a.belief, b.belief, rtol=1e-9, atol=1e-14)
        assert not np.allclose(a.belief, d.belief, rtol=1e-3)  # tempered, not as at power 1
