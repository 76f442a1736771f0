"""Scan matching two depth profiles: synthetic rooms with known motion, against a naive
grid-search reference."""

from __future__ import annotations

import math

import numpy as np
import pytest
from navigation_testkit import FOV, RAYS, WALLS, room_profile

from server.navigation.scanmatch import (
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
