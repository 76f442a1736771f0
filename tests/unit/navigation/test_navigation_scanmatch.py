"""Scan matching two depth profiles: synthetic rooms with known motion, against a naive
grid-search reference."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from navigation_testkit import FOV, RAYS, WALLS, room_profile

from server.navigation.scanmatch import (
    _seen_from,
    along_offset,
    match_profiles,
    match_profiles_robust,
    profile_points,
    surface_normals,
)


def relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    c, s = math.cos(a[2]), math.sin(a[2])
    d = b[:2] - a[:2]
    th = math.atan2(math.sin(b[2] - a[2]), math.cos(b[2] - a[2]))
    return np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1], th])


@pytest.mark.parametrize(
    ("dx", "dy", "dth"), [(0.0, 0.0, 0.0), (0.2, 0.3, 0.1), (-0.3, -0.25, -0.2), (0.1, 0.4, 0.3)]
)
def test_the_motion_between_two_profiles_is_recovered(dx: float, dy: float, dth: float) -> None:
    taught = np.array([1.0, 1.2, 0.3])
    current = taught + np.array([dx, dy, dth])
    t_prof = room_profile(*taught, walls=WALLS)
    c_prof = room_profile(*current, walls=WALLS)
    truth = relative(taught, current)
    fit = match_profiles(t_prof, c_prof, truth + np.array([0.1, -0.1, 0.05]), fov_deg=FOV)
    assert fit is not None
    np.testing.assert_allclose(fit.pose, truth, atol=0.01)
    assert fit.pairs >= 10 and fit.rms_m < 0.03
    assert np.all(np.linalg.eigvalsh(fit.cov) > 0)


def test_several_starts_find_a_pose_one_wrong_start_misses() -> None:
    taught = np.array([1.0, 1.2, 0.3])
    current = taught + np.array([0.1, 0.9, 0.0])  # 0.9 m to the side
    t_prof, c_prof = room_profile(*taught, walls=WALLS), room_profile(*current, walls=WALLS)
    truth = relative(taught, current)
    fit = match_profiles_robust(t_prof, c_prof, np.zeros(3), fov_deg=FOV)
    assert fit is not None
    np.testing.assert_allclose(fit.pose, truth, atol=0.02)


def test_too_few_points_give_no_fit() -> None:
    empty = np.full(RAYS, np.inf)
    assert match_profiles(empty, empty, np.zeros(3), fov_deg=FOV) is None


def test_a_corridor_cannot_tell_how_far_along_and_says_so() -> None:
    corridor = [(-5, 0, 10, 0), (-5, 1.2, 10, 1.2)]
    a = np.array([0.0, 0.6, 0.0])
    b = np.array([0.3, 0.5, 0.05])
    fit = match_profiles(
        room_profile(*a, walls=corridor),
        room_profile(*b, walls=corridor),
        relative(a, b),
        fov_deg=FOV,
    )
    assert fit is not None
    # across the corridor it is sure, along it it cannot tell
    assert math.sqrt(fit.cov[1, 1]) < 0.05 and math.sqrt(fit.cov[0, 0]) > 10
    assert abs(fit.pose[1] - relative(a, b)[1]) < 0.01


def test_points_and_normals_of_a_wall() -> None:
    prof = room_profile(1.0, 1.5, 0.0, walls=[(3, -5, 3, 5)])  # a wall 2 m ahead
    pts = profile_points(prof, FOV)
    assert np.allclose(pts[:, 0], 2.0)
    n, ok = surface_normals(pts)
    assert ok.all() and np.allclose(np.abs(n[:, 0]), 1.0)


# -- how far along, from two profiles facing the same way (docking) ----------------------------


@pytest.mark.parametrize("ahead", [-1.0, -0.4, -0.1, 0.0, 0.2, 0.6])
@pytest.mark.parametrize("side", [0.0, 0.15])
def test_how_far_ahead_of_the_taught_spot_from_the_depth(ahead: float, side: float) -> None:
    taught = np.array([1.2, 1.4, 0.1])
    c, s = math.cos(taught[2]), math.sin(taught[2])
    current = taught + np.array([c * ahead - s * side, s * ahead + c * side, 0.02])
    est = along_offset(
        room_profile(*taught, walls=WALLS), room_profile(*current, walls=WALLS), fov_deg=FOV
    )
    assert est is not None and abs(est - ahead) <= 0.15


def test_a_corridor_cannot_tell_how_far_along_by_the_depth_either() -> None:
    corridor = [(-5, 0, 10, 0), (-5, 1.2, 10, 1.2)]
    taught = room_profile(0.0, 0.6, 0.0, walls=corridor)
    for ahead in (-1.0, 0.0, 0.7):
        current = room_profile(ahead, 0.6, 0.0, walls=corridor)
        assert along_offset(taught, current, fov_deg=FOV) is None


def test_an_object_between_the_robot_and_the_spot_is_seen_through_by_the_taught_profile() -> None:
    # from 1.2 m behind, a box the taught robot stood beside and a wall ahead: the estimate
    # is where both profiles agree, never "there"
    walls = [(4, -3, 4, 3), (-3, 1.0, 4, 1.0), (-3, -1.0, 4, -1.0), (-0.9, -0.3, -0.9, 0.3)]
    taught = room_profile(0.0, 0.0, 0.0, walls=walls)
    current = room_profile(-1.2, 0.0, 0.0, walls=walls)
    est = along_offset(taught, current, fov_deg=FOV)
    assert est is None or abs(est + 1.2) <= 0.1


def _seen_from_naively(
    points: np.ndarray,
    shifts: np.ndarray,
    ranges: np.ndarray,
    fov_deg: float,
    agree_m: float,
    max_range_m: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One shift, one point at a time: the rays beside the point's bearing (those in the fan)."""
    n = len(ranges)
    half = math.radians(fov_deg) / 2
    explained, closeness, passed = [], [], []
    for sx, sy in shifts:
        e = c = p = 0.0
        for px, py in points:
            x, y = px + sx, py + sy
            bearing, rho = math.atan2(y, x), math.hypot(x, y)
            if x <= 0 or abs(bearing) > half or rho >= max_range_m - agree_m:
                continue
            k = int(np.clip(np.rint((half - bearing) / (2 * half) * (n - 1)), 0, n - 1))
            seen = []
            for j in (k - 1, k, k + 1):
                if 0 <= j < n:
                    r = ranges[j]
                    seen.append(min(r if np.isfinite(r) and r > 0.05 else np.inf, max_range_m))
            miss = min(abs(r - rho) for r in seen)
            if miss <= agree_m:
                e += 1
                c += 1 - miss / agree_m
            p += rho < min(seen) - agree_m
        explained.append(e)
        closeness.append(c)
        passed.append(p)
    return np.array(explained), np.array(closeness), np.array(passed)


@settings(max_examples=30, deadline=None)
@given(
    x=st.floats(0.3, 2.5),
    y=st.floats(0.3, 2.7),
    th=st.floats(-math.pi, math.pi),
    shift=st.tuples(st.floats(-1.5, 1.5), st.floats(-0.5, 0.5)),
)
def test_seen_from_equals_the_count_made_one_point_at_a_time(
    x: float, y: float, th: float, shift: tuple[float, float]
) -> None:
    a = room_profile(x, y, th, walls=WALLS)
    b = room_profile(min(x + 0.4, 3.7), y, th, walls=WALLS)
    points = profile_points(b, FOV)
    shifts = np.array([[0.0, 0.0], shift, [-0.4, 0.1]])
    fast = _seen_from(points, shifts, a, FOV, 0.1, 3.9)
    slow = _seen_from_naively(points, shifts, a, FOV, 0.1, 3.9)
    for f, s in zip(fast, slow, strict=True):
        np.testing.assert_allclose(f, s, atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(x=st.floats(0.3, 2.5), y=st.floats(0.3, 2.7), th=st.floats(-math.pi, math.pi))
def test_a_profile_stands_where_it_was_taught(x: float, y: float, th: float) -> None:
    prof = room_profile(x, y, th, walls=WALLS)
    est = along_offset(prof, prof, fov_deg=FOV)
    assert est is None or abs(est) <= 0.05
