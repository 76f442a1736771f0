"""The places' heading filter: naive references, hypothesis properties, what it is for."""

from __future__ import annotations

import math

import numpy as np
import pytest
from belief_testkit import edge
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from server.belief.headings import (
    HeadingBins,
    HeadingParams,
    PlaceHeadings,
    correct,
    expect,
    spin_headings,
    turn,
)
from server.belief.tracker import fine_likelihood
from server.domain import Location, TourGraph

N_SPIN = 80
STEP = 2 * math.pi / N_SPIN


def spin_location(name: str, first_id: int, n: int = N_SPIN, w: float = 0.8) -> Location:
    """A place taught by one counter-clockwise turn at ``w`` rad/s, one image per 0.1 s."""
    dt = 2 * math.pi / n / w
    t = tuple(k * dt for k in range(n))
    return Location(name, tuple(range(first_id, first_id + n)), first_id, t, (w,) * n)


def two_places() -> TourGraph:
    a, b = spin_location("a", 0), spin_location("b", N_SPIN)
    e = edge(0, 1, 10)
    e = type(e)(0, 1, tuple(range(2 * N_SPIN, 2 * N_SPIN + 10)), e.timestamps, e.v, e.w)
    return TourGraph(locations=(a, b), edges=(e,))


def naive_turn(q: np.ndarray, dtheta: float, p: HeadingParams) -> np.ndarray:
    """Bin by bin: each bin's mass moved by the turn, shared between the two bins it lands
    between, then blurred to the neighbours, then mixed with uniform."""
    bins = len(q)
    width = 2 * math.pi / bins
    moved = np.zeros(bins)
    for b, mass in enumerate(q):
        target = b + dtheta / width
        lo = math.floor(target)
        moved[lo % bins] += mass * (1 - (target - lo))
        moved[(lo + 1) % bins] += mass * (target - lo)
    sd = p.sd_rad + p.turn_sd * abs(dtheta)
    a = min(0.25, 0.5 * (sd / width) ** 2)
    blurred = np.zeros(bins)
    for b, mass in enumerate(moved):
        blurred[b] += (1 - 2 * a) * mass
        blurred[(b - 1) % bins] += a * mass
        blurred[(b + 1) % bins] += a * mass
    return (1 - p.forget) * blurred + p.forget / bins


distributions = arrays(np.float64, 36, elements=st.floats(0, 1)).filter(lambda q: q.sum() > 1e-3)


@settings(max_examples=60, deadline=None)
@given(distributions, st.floats(-3.0, 3.0))
def test_turn_equals_naive_reference_and_keeps_mass(q: np.ndarray, dtheta: float) -> None:
    q = q / q.sum()
    p = HeadingParams()
    out = turn(q, dtheta, p)
    np.testing.assert_allclose(out, naive_turn(q, dtheta, p), atol=1e-12)
    assert out.sum() == pytest.approx(1.0)
    assert np.all(out >= 0)


def test_turn_moves_the_mean_heading_by_the_odometry() -> None:
    p = HeadingParams(sd_rad=0.0, turn_sd=0.0, forget=0.0)
    q = np.zeros(36)
    q[10] = 1.0
    width = 2 * math.pi / 36
    bins = np.arange(36)
    for dtheta in (0.05, 0.3, -0.7, 2.5):
        out = turn(q, dtheta, p)
        assert np.sum(out * bins) * width == pytest.approx(10 * width + dtheta, abs=1e-9)
    # fifty small turns add up to their sum (no bin swallows a turn smaller than itself)
    r = q.copy()
    for _ in range(50):
        r = turn(r, 0.02, p)
    assert np.sum(r * bins) * width == pytest.approx(10 * width + 1.0, abs=1e-9)


@settings(max_examples=60, deadline=None)
@given(distributions, arrays(np.float64, 36, elements=st.floats(0, 1)))
def test_expect_and_correct_equal_bayes_by_hand(q: np.ndarray, s: np.ndarray) -> None:
    q = q / q.sum()
    assert expect(q, s) == pytest.approx(sum(a * b for a, b in zip(q, s, strict=True)))
    post = correct(q, s)
    total = float(np.sum(q * s))
    if total > 0:
        np.testing.assert_allclose(post, q * s / total, atol=1e-12)
    else:
        np.testing.assert_allclose(post, np.full(36, 1 / 36))


def test_spin_headings_from_the_odometry_else_evenly_spaced() -> None:
    t = np.arange(40) * 0.25
    w = np.full(40, -0.7)  # clockwise, 0.175 rad per image
    h = spin_headings(t, w)
    assert h[0] == 0.0 and h[1] == pytest.approx(-0.175) and h[-1] == pytest.approx(-39 * 0.175)
    # no odometry, NaN, or less than half a turn: one turn evenly spaced
    for tt, ww in ((t, np.zeros(40)), (t, np.full(40, np.nan)), (np.zeros(40), w), ([], [])):
        np.testing.assert_allclose(spin_headings(tt, ww), np.arange(len(tt)) * 2 * math.pi / 40)


def test_bins_take_the_best_image_facing_into_each() -> None:
    g = two_places()
    bins = HeadingBins.of(g, 36)
    rng = np.random.default_rng(1)
    sims = rng.random((2, g.n_images))
    s = bins.similarities(sims[:, : 2 * N_SPIN], floor=1e-3)
    width = 2 * math.pi / 36
    # naive: every image's heading from its place's spin, its bin centred on heading 0
    for loc_k, loc in enumerate(g.locations):
        h = spin_headings(loc.timestamps, loc.w)
        for b in range(36):
            members = [
                i
                for i in range(N_SPIN)
                if round(((h[i] + width / 2) % (2 * math.pi)) // width) % 36 == b
            ]
            expected = (
                np.max(sims[:, [loc_k * N_SPIN + i for i in members]], axis=1)
                if members
                else np.full(2, 1e-3)
            )
            np.testing.assert_allclose(s[:, loc_k, b], np.maximum(expected, 1e-3))


def test_edges_keep_their_own_similarity_and_a_fresh_place_its_mean_bin() -> None:
    g = two_places()
    sims = np.random.default_rng(2).random(g.n_images)
    out = PlaceHeadings(g, HeadingParams()).likelihood(sims[None, :], 0.0)
    assert out.shape == (1, g.n_fine)
    np.testing.assert_allclose(out[0, 2:], fine_likelihood(sims, g)[2:])
    s = HeadingBins.of(g, 36).similarities(sims[None, : 2 * N_SPIN], 1e-3)[0]
    # uniform before the first frame, turned (the blur keeps it uniform): the mean bin
    np.testing.assert_allclose(out[0, :2], s.mean(axis=1))
    assert np.all(out[0, :2] <= fine_likelihood(sims, g)[:2] + 1e-12)


def views(heading: float, spin: np.ndarray, width: float = 0.25) -> np.ndarray:
    """Similarities of a frame facing ``heading`` to the spin views at ``spin`` (a smooth
    peak of ``width`` rad on the view that faces the same way, 0.1 elsewhere)."""
    d = np.angle(np.exp(1j * (spin - heading)))
    return 0.1 + 0.9 * np.exp(-0.5 * (d / width) ** 2)


def test_a_robot_turning_at_the_place_reaches_its_best_view_and_elsewhere_does_not() -> None:
    """At place ``a`` the frames follow ``a``'s spin as the odometry turns; for place ``b`` the
    same frames match its views in no order (each frame a view at random, as a wall matches
    some spin view of any place): the best view's similarity is the same for both (the max of
    001 eq. 2 cannot tell them apart), the filter's likelihood is not."""
    g = two_places()
    h = spin_headings(g.locations[0].timestamps, g.locations[0].w)
    headings = PlaceHeadings(g, HeadingParams())
    rng = np.random.default_rng(4)
    heading, a_lik, b_lik = 0.7, [], []
    for _ in range(40):
        heading += 0.05  # 0.5 rad/s for 0.1 s, as the odometry says
        sims = np.concatenate([views(heading, h), views(rng.uniform(-np.pi, np.pi), h)])
        sims = np.concatenate([sims, np.full(10, 0.1)])
        out = headings.likelihood(sims[None, :], 0.05)
        a_lik.append(out[0, 0])
        b_lik.append(out[0, 1])
        maxes = fine_likelihood(sims, g)[:2]
        assert maxes[0] == pytest.approx(maxes[1], abs=0.01)
    assert np.median(a_lik[10:]) > 0.8  # the best view's 1.0, less the filter's spread
    assert np.median(b_lik[10:]) < 0.5 * np.median(a_lik[10:])


def test_reset_and_the_number_of_models() -> None:
    g = two_places()
    headings = PlaceHeadings(g, HeadingParams())
    sims = np.random.default_rng(5).random((2, g.n_images))
    first = headings.likelihood(sims, 0.0)
    headings.likelihood(sims, 0.3)
    headings.reset()
    np.testing.assert_allclose(headings.likelihood(sims, 0.0), first)
    assert headings.likelihood(sims[:1], 0.0).shape == (1, g.n_fine)  # one model now
    with pytest.raises(ValueError, match="canonical order"):
        headings.likelihood(np.ones((1, 5)), 0.0)
    with pytest.raises(ValueError, match="bins"):
        HeadingParams(bins=2)


def test_a_bin_the_spin_did_not_face_takes_its_nearest_neighbours() -> None:
    """A spin of 12 images fills every third bin of 36; the bins between take the mean of
    the nearest filled bins either side (not the floor: a peak turning through them would
    be wiped out), and a place without images keeps the floor."""
    sparse = spin_location("sparse", 0, n=12)
    g = TourGraph(locations=(sparse, Location("bare")))
    sims = np.linspace(0.1, 1.0, 12)[None, :]
    s = HeadingBins.of(g, 36).similarities(sims, floor=1e-3)[0]
    filled = s[0, ::3]
    np.testing.assert_allclose(filled, sims[0])
    for b in range(36):
        if b % 3:
            lo, hi = filled[b // 3], filled[(b // 3 + 1) % 12]
            assert s[0, b] == pytest.approx((lo + hi) / 2)
    np.testing.assert_allclose(s[1], 1e-3)
