"""Monte-Carlo localisation weighted by retrieval scores (seed 002): vectorised against a naive
per-particle loop, converging on a synthetic corridor with a look-alike stretch; the tempered
likelihood against a naive loop and, at temper 1, the likelihood as it is."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.belief.mcl import (
    MclParams,
    MonteCarloLocaliser,
    effective_size,
    estimate,
    likelihood,
    predict,
    resample,
    temper,
    wrap,
)

P = MclParams()


def _naive_predict(particles, v, w, dt, noise, params):
    out = []
    for (x, y, th), z in zip(particles, noise, strict=True):
        vi, wi = v * (1 + params.noise_v * z[0]), w * (1 + params.noise_w * z[1])
        spread = max(params.noise_xy_m * abs(v * dt), 0.005)
        h = th + 0.5 * wi * dt
        along, across = vi * dt + spread * z[2], spread * z[3]
        nx = x + along * math.cos(h) - across * math.sin(h)
        ny = y + along * math.sin(h) + across * math.cos(h)
        nth = math.remainder(th + wi * dt + params.noise_theta * z[4], 2 * math.pi)
        out.append((nx, ny, nth))
    return np.array(out)


def _naive_likelihood(particles, poses, scores, params):
    out = []
    for x, y, th in particles:
        total = params.floor * max(s**params.sharpness for s in scores)
        for (px, py, pth), s in zip(poses, scores, strict=True):
            d2 = (x - px) ** 2 + (y - py) ** 2
            dth = math.remainder(th - pth, 2 * math.pi)
            total += s**params.sharpness * math.exp(
                -0.5 * d2 / params.sigma_xy_m**2 + (math.cos(dth) - 1) / params.sigma_theta**2
            )
        out.append(total)
    return np.array(out)


coords = st.floats(-20, 20, allow_nan=False)
angles = st.floats(-math.pi, math.pi, allow_nan=False)


@settings(max_examples=40, deadline=None)
@given(
    n=st.integers(1, 30),
    k=st.integers(1, 8),
    seed=st.integers(0, 2**32 - 1),
    v=st.floats(-1, 1),
    w=st.floats(-2, 2),
    dt=st.floats(0.01, 1.0),
)
def test_vectorised_steps_match_a_naive_loop_over_particles(
    n: int, k: int, seed: int, v: float, w: float, dt: float
) -> None:
    rng = np.random.default_rng(seed)
    particles = np.column_stack(
        [rng.uniform(-5, 5, n), rng.uniform(-5, 5, n), rng.uniform(-np.pi, np.pi, n)]
    )
    noise = rng.standard_normal((n, 5))
    moved = predict(particles, v, w, dt, noise, P)
    naive = _naive_predict(particles, v, w, dt, noise, P)
    np.testing.assert_allclose(moved[:, :2], naive[:, :2], atol=1e-9)
    np.testing.assert_allclose(wrap(moved[:, 2] - naive[:, 2]), 0.0, atol=1e-9)
    poses = np.column_stack(
        [rng.uniform(-5, 5, k), rng.uniform(-5, 5, k), rng.uniform(-np.pi, np.pi, k)]
    )
    scores = rng.uniform(0.01, 1.0, k)
    lik = likelihood(moved, poses, scores, P)
    np.testing.assert_allclose(lik, _naive_likelihood(moved, poses, scores, P), rtol=1e-9)
    assert np.all(lik > 0)


@settings(max_examples=40, deadline=None)
@given(weights=st.lists(st.floats(0.0, 1.0), min_size=1, max_size=50), u=st.floats(0, 0.999))
def test_systematic_resampling_draws_each_particle_by_its_weight(
    weights: list[float], u: float
) -> None:
    w = np.array(weights) + 1e-12
    idx = resample(w, u)
    counts = np.bincount(idx, minlength=len(w))
    expected = len(w) * w / w.sum()
    assert counts.sum() == len(w)
    assert np.all(counts >= np.floor(expected) - 1) and np.all(counts <= np.ceil(expected) + 1)
    assert 0 < effective_size(w) <= 1 + 1e-12


def test_the_estimate_is_the_densest_mode_not_the_mean_of_two() -> None:
    """60 % of the weight at (0, 0) facing east, 40 % at (5, 0): the estimate is (0, 0)."""
    particles = np.array([[0.0, 0.0, 0.0]] * 6 + [[5.0, 0.0, np.pi]] * 4)
    x, y, theta, std, mode_mass = estimate(particles, np.ones(10), P)
    assert (x, y, theta) == pytest.approx((0.0, 0.0, 0.0))
    assert mode_mass == pytest.approx(0.6)
    assert std == pytest.approx(math.sqrt(0.6 * 2**2 + 0.4 * 3**2))


def _corridor_scores(x_taught: np.ndarray, x_true: float) -> np.ndarray:
    """What an engine would score along a corridor whose stretches 0-5 m and 10-15 m look
    alike: every image taught near the true place, or near its look-alike, scores high."""

    def look(x: np.ndarray | float) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        return np.where((x >= 10) & (x < 15), x - 10, x)

    return np.exp(-0.5 * ((look(x_taught) - look(x_true)) / 0.3) ** 2)


def test_it_converges_on_a_synthetic_corridor_with_a_look_alike_stretch() -> None:
    """A 20 m corridor taught every 0.1 m facing +x. The robot starts at 1 m (which looks
    like 11 m) and drives on at 0.5 m/s, its odometry 5 % off: while it is in the look-alike
    stretch the cloud holds both; past 5 m it is one mode, within 0.3 m of the truth."""
    x_taught = np.arange(0.0, 20.0, 0.1)
    poses = np.column_stack([x_taught, np.zeros_like(x_taught), np.zeros_like(x_taught)])
    mcl = MonteCarloLocaliser(poses, MclParams(enabled=True, seed=3))
    x, dt, v = 1.0, 0.1, 0.5
    errors, stds = [], []
    for _ in range(160):  # 16 s: to 9 m
        x += v * dt
        est = mcl.step(v=v * 1.05, w=0.0, dt=dt, scores=_corridor_scores(x_taught, x))
        errors.append(abs(est.x - x) + abs(est.y))
        stds.append(est.std_m)
    assert max(stds[:40]) > 2.0  # two modes 10 m apart early on
    assert max(errors[-40:]) < 0.3 and max(stds[-40:]) < 0.5
    assert mcl.particles.shape == (1000, 3) and np.isclose(mcl.weights.sum(), 1.0)


def test_the_same_seed_gives_the_same_estimates() -> None:
    poses = np.column_stack([np.arange(50) * 0.1, np.zeros(50), np.zeros(50)])
    scores = np.exp(-np.arange(50) / 10)
    a, b = MonteCarloLocaliser(poses), MonteCarloLocaliser(poses)
    b.step(v=0.3, w=0.1, dt=0.1, scores=scores)
    b.reset()
    for _ in range(5):
        ea = a.step(v=0.3, w=0.1, dt=0.1, scores=scores)
        eb = b.step(v=0.3, w=0.1, dt=0.1, scores=scores)
    assert (ea.x, ea.y, ea.theta) == (eb.x, eb.y, eb.theta)


def test_poses_must_all_be_known() -> None:
    with pytest.raises(ValueError, match="needs a pose"):
        MonteCarloLocaliser(np.array([[0.0, 0.0, np.nan]]))
    with pytest.raises(ValueError):
        MclParams(sigma_xy_m=0.0)


@settings(max_examples=40, deadline=None)
@given(
    lik=st.lists(st.floats(0, 1e6, allow_nan=False), min_size=1, max_size=20),
    power=st.floats(0, 1),
)
def test_tempering_matches_a_naive_loop_and_keeps_the_order(lik: list[float], power: float) -> None:
    out = temper(lik, power)
    top = max(lik)
    naive = [1.0 if top == 0 or power == 0 else (x / top) ** power for x in lik]
    assert out == pytest.approx(naive, rel=1e-9, abs=1e-12)
    order = np.argsort(lik, kind="stable")
    assert np.all(np.diff(out[order]) >= -1e-12)  # a likelier particle never weighs less


def test_temper_zero_leaves_the_weights_as_they_were() -> None:
    """temper 0: the particles move with the odometry but no frame changes a weight."""
    poses = np.column_stack([np.arange(50) * 0.1, np.zeros(50), np.zeros(50)])
    mcl = MonteCarloLocaliser(poses, MclParams(enabled=True, temper=0.0, resample_ess=0.0))
    mcl.weights = np.linspace(1, 2, len(mcl.weights))
    mcl.weights /= mcl.weights.sum()
    before = mcl.weights.copy()
    mcl.step(v=0.3, w=0.0, dt=0.1, scores=np.exp(-np.arange(50) / 5))
    assert mcl.weights == pytest.approx(before)


def test_temper_one_and_the_old_floor_weigh_as_the_likelihood_itself() -> None:
    """temper 1 with floor 1e-3 (the defaults before 2026-11-29): the new weights are the
    old ones times the likelihood, normalised, as before."""
    poses = np.column_stack([np.arange(50) * 0.1, np.zeros(50), np.zeros(50)])
    scores = np.exp(-np.arange(50) / 5)
    params = MclParams(enabled=True, floor=1e-3, temper=1.0, resample_ess=0.0, seed=4)
    top = np.argsort(-scores)[: params.top_k]
    a = MonteCarloLocaliser(poses, params)
    prior = a.weights.copy()
    a.step(v=0.3, w=0.0, dt=0.1, scores=scores)
    lik = likelihood(a.particles, poses[top], scores[top], params)
    assert a.weights == pytest.approx(prior * lik / (prior * lik).sum(), rel=1e-9)
