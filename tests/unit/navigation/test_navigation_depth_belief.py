"""The depth profile's word on every state of the belief (``TopometricParams.depth_belief``):
:func:`~server.navigation.scanmatch.profile_agreement` against a naive reference, and
:meth:`TourRuntime.depth_evidence` weighing the states whose taught profiles the frame's
does not agree with."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from navigation_testkit import WALLS, A, B, C, room_profile, runtime

from server.navigation.pathtrack import TopometricParams
from server.navigation.runtime import TourRuntime
from server.navigation.scanmatch import log_ranges, profile_agreement

MAX_RANGE = TopometricParams().scan_fit.max_range_m


def naive_agreement(q: np.ndarray, taught: np.ndarray, sigma: float, max_shift: int) -> np.ndarray:
    """Ray by ray, shift by shift, in plain Python."""
    n = len(q)
    out = []
    for row in taught:
        if np.isnan(row).any():
            out.append(math.nan)
            continue
        best = -math.inf
        for s in range(-max_shift, max_shift + 1):
            pairs = [(q[i], row[i - s]) for i in range(n) if 0 <= i - s < n]
            mean = sum(1.0 / (1.0 + ((b - a) / sigma) ** 2) for a, b in pairs) / len(pairs)
            best = max(best, mean)
        out.append(best)
    return np.array(out)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(1, 6),
    sigma=st.floats(0.05, 1.0),
    max_shift=st.integers(0, 4),
)
def test_agreement_matches_the_naive_reference(
    seed: int, n: int, sigma: float, max_shift: int
) -> None:
    rng = np.random.default_rng(seed)
    rays = 11
    q = log_ranges(rng.uniform(0.2, 6.0, rays), MAX_RANGE)
    taught = log_ranges(rng.uniform(0.2, 6.0, (n, rays)), MAX_RANGE)
    taught[rng.random(n) < 0.2] = np.nan  # images taught without a profile
    got = profile_agreement(q, taught, sigma=sigma, max_shift=max_shift)
    np.testing.assert_allclose(got, naive_agreement(q, taught, sigma, max_shift), rtol=1e-12)
    finite = got[np.isfinite(got)]
    assert np.all((finite > 0) & (finite <= 1))
    # float32 rows give the same to float32's precision
    got32 = profile_agreement(q, taught.astype(np.float32), sigma=sigma, max_shift=max_shift)
    np.testing.assert_allclose(got32, got, rtol=1e-5)


def test_a_profile_agrees_fully_with_itself_and_with_itself_turned_a_little() -> None:
    ranges = room_profile(1.5, 1.2, 0.3, walls=WALLS)
    q = log_ranges(ranges, MAX_RANGE)
    assert profile_agreement(q, q[None, :], sigma=0.2, max_shift=0)[0] == pytest.approx(1.0)
    turned = np.roll(q, 2)
    turned[:2] = q[0]
    assert profile_agreement(q, turned[None, :], sigma=0.2, max_shift=3)[0] > 0.99
    assert profile_agreement(q, turned[None, :], sigma=0.2, max_shift=0)[0] < 0.9


def test_rays_that_saw_nothing_agree_with_each_other_and_not_with_a_surface() -> None:
    far = log_ranges(np.array([np.inf, 50.0, np.nan]), MAX_RANGE)
    assert np.all(far == math.log(MAX_RANGE))
    near = log_ranges(np.full(3, 1.0), MAX_RANGE)
    got = profile_agreement(far, np.stack([far, near]), sigma=0.2, max_shift=0)
    assert got[0] == pytest.approx(1.0) and got[1] < 0.05


def test_bad_shapes_and_settings_are_refused() -> None:
    q = np.zeros(5)
    with pytest.raises(ValueError, match="do not match"):
        profile_agreement(q, np.zeros((2, 4)), sigma=0.2, max_shift=1)
    with pytest.raises(ValueError, match="sigma"):
        profile_agreement(q, np.zeros((2, 5)), sigma=0.0, max_shift=1)
    with pytest.raises(ValueError, match="max_shift"):
        profile_agreement(q, np.zeros((2, 5)), sigma=0.2, max_shift=5)


SPOT = (1.2, 1.0)
"""Where B's spin images were taught, in the room ``WALLS``."""


def taught(**changes: object) -> TourRuntime:
    """The synthetic tour with ``depth_belief`` 2 (and ``changes``): B's four spin images taught
    on ``SPOT`` facing east, north, west, south; the edge A -> B's images along y = 1.5 facing
    east, 0.3 m apart from x = 0.5 (the last few beyond the room's wall see nothing: no
    matter, they are compared all the same)."""
    tp = replace(TopometricParams(), **{"depth_belief": 2.0, **changes})  # type: ignore[arg-type]
    rt = runtime(topometric=tp)
    for j, image in enumerate(rt.spin_images[B]):
        rt.taught_depth[int(image)] = room_profile(*SPOT, j * math.pi / 2, walls=WALLS)
    for k in range(rt.graph.edges[0].n_images):
        rt.taught_depth[rt.edge_image(0, k)] = room_profile(0.5 + 0.3 * k, 1.5, 0.0, walls=WALLS)
    return rt


def test_the_states_taught_where_the_robot_stands_weigh_most() -> None:
    rt = taught()
    g = rt.graph
    out = rt.depth_evidence(room_profile(SPOT[0] + 0.1, SPOT[1], math.pi / 2 + 0.04, walls=WALLS))
    assert out.shape == (g.n_fine,) and np.all((out > 0) & (out <= 1))
    # B (its spin image facing north agrees) above every image of the edge, and A, C (no
    # taught profile) weigh as the frame's median image
    first = g.n_locations + int(g.edge_offsets[0])
    edge = out[first : first + g.edges[0].n_images]
    assert out[B] > 0.9 and out[B] > edge.max()
    assert out[A] == out[C] < out[B]
    # on the edge, facing east at x = 1.7: the image taught there weighs most
    on = rt.depth_evidence(room_profile(1.7, 1.5, 0.0, walls=WALLS))
    assert int(np.argmax(on[first : first + g.edges[0].n_images])) == 4


def test_the_weight_is_exp_of_minus_depth_belief_times_the_disagreement() -> None:
    rt = taught(depth_belief=3.0)
    frame = room_profile(3.2, 0.5, 2.0, walls=WALLS)
    image = rt.edge_image(0, 2)
    agree = profile_agreement(
        log_ranges(frame, MAX_RANGE),
        log_ranges(rt.taught_depth[image], MAX_RANGE)[None, :],
        sigma=0.2,
        max_shift=3,
    )[0]
    out = rt.depth_evidence(frame)
    fine = rt.graph.n_locations + int(rt.graph.edge_offsets[0]) + 2
    assert out[fine] == pytest.approx(math.exp(-3.0 * (1.0 - agree)), rel=1e-5)


def test_off_without_depth_or_with_other_rays_it_has_no_word() -> None:
    frame = room_profile(0.5, 0.5, 0.0, walls=WALLS)
    ones = np.ones(taught().graph.n_fine)
    np.testing.assert_array_equal(taught(depth_belief=0.0).depth_evidence(frame), ones)
    np.testing.assert_array_equal(taught().depth_evidence(None), ones)
    np.testing.assert_array_equal(taught().depth_evidence(frame[:-3]), ones)
    np.testing.assert_array_equal(runtime().depth_evidence(frame), ones)  # nothing taught


def test_depth_belief_defaults_are_documented_numbers() -> None:
    p = TopometricParams()
    assert p.depth_belief == 0.0
    assert (p.depth_belief_sigma, p.depth_belief_shift) == (0.2, 3)
