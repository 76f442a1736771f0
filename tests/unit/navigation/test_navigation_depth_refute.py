"""The depth profile refuting the path tracker's estimate (``TopometricParams.depth_refute``,
:func:`server.navigation.scanmatch.further_share`): rays that see past a taught surface say the
robot is not where the estimate puts it; the tracker widens and its word in the belief turns
round."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from navigation_testkit import (
    FOV,
    NO_FEATURES,
    RAYS,
    depth_tracker,
    path_estimate,
    room_profile,
    taught_edge,
)

from server.belief.model import Action
from server.navigation.geometry import compose
from server.navigation.pathtrack import PathEstimate, TopometricParams, path_likelihood
from server.navigation.scanmatch import ScanParams, expected_ranges, further_share, profile_points
from server.policy.voting import Decision

CORRIDOR = [  # a corridor 1.6 m wide along +x, a door on its left at x 3.0-3.9, its end at 7 m
    (-1.0, -0.8, 7.0, -0.8),
    (-1.0, 0.8, 3.0, 0.8),
    (3.9, 0.8, 7.0, 0.8),
    (3.0, 0.8, 3.0, 1.8),
    (3.9, 0.8, 3.9, 1.8),
    (3.0, 1.8, 3.9, 1.8),
    (7.0, -0.8, 7.0, 0.8),
]


def surfaces(taught: np.ndarray) -> list[tuple[float, float, float, float]]:
    """The taught points joined where they lie on one surface, as walls for the ray caster."""
    pts = profile_points(taught, FOV)
    gap = ScanParams().surface_gap_m
    return [
        (float(a[0]), float(a[1]), float(b[0]), float(b[1]))
        for a, b in itertools.pairwise(pts)
        if np.linalg.norm(b - a) < gap
    ]


def cast(
    x: float, y: float, th: float, walls: list[tuple[float, float, float, float]]
) -> np.ndarray:
    """Ray by ray, wall by wall: the nearest crossing (a wall's ends included, within 1e-9:
    the taught surfaces meet end to end), else inf."""
    half = math.radians(FOV) / 2
    out = np.full(RAYS, np.inf)
    for i, a in enumerate(np.linspace(half, -half, RAYS)):
        d = (math.cos(th + a), math.sin(th + a))
        for x0, y0, x1, y1 in walls:
            e = (x1 - x0, y1 - y0)
            det = d[0] * -e[1] - d[1] * -e[0]
            if abs(det) < 1e-12:
                continue
            rx, ry = x0 - x, y0 - y
            t = (rx * -e[1] - ry * -e[0]) / det
            u = (d[0] * ry - d[1] * rx) / det
            if t > 0 and -1e-9 <= u <= 1 + 1e-9:
                out[i] = min(out[i], t)
    return out


@settings(max_examples=60, deadline=None)
@given(
    x=st.floats(-1.0, 1.0),
    y=st.floats(-0.5, 0.5),
    th=st.floats(-0.6, 0.6),
    seen_from=st.floats(0.0, 3.0),
)
def test_expected_ranges_equal_the_ray_caster_on_the_taught_surfaces(
    x: float, y: float, th: float, seen_from: float
) -> None:
    taught = room_profile(seen_from, 0.0, 0.0, walls=CORRIDOR)
    got = expected_ranges(taught, [x, y, th], RAYS, FOV)
    want = cast(x, y, th, surfaces(taught))
    np.testing.assert_allclose(np.nan_to_num(got, nan=np.inf), want, rtol=1e-9, atol=1e-9)


def share(robot_x: float, estimate_x: float, lateral: float = 0.0) -> float | None:
    """Rays of a robot at ``robot_x`` seeing past what was taught at ``estimate_x`` (the
    robot placed there by its estimate)."""
    taught = room_profile(estimate_x, 0.0, 0.0, walls=CORRIDOR)
    now = room_profile(robot_x, lateral, 0.0, walls=CORRIDOR)
    return further_share(now, taught, [0.0, 0.0, 0.0], fov_deg=FOV, further_m=0.5)


def test_a_robot_where_its_estimate_is_sees_no_surface_vanish() -> None:
    for x in (0.0, 1.5, 3.0, 4.5):
        assert share(x, x) == 0.0


def test_a_robot_away_from_its_estimate_sees_past_the_taught_walls() -> None:
    # the estimate 2.5 m ahead, where the corridor's end was taught within reach: the robot
    # sees nothing there
    share_far = share(1.5, 4.0)
    assert share_far is not None and share_far >= 0.3
    # the robot near the door, the estimate 1 m before, where a wall was taught on the left:
    # the door's rays see past it
    share_door = share(2.0, 1.0)
    assert share_door is not None and share_door > 0.1
    # the robot 1.5 m ahead of its estimate sees nothing vanish here: it cannot tell
    assert share(3.0, 1.5) == 0.0


def test_a_ray_that_sees_nothing_sees_past_any_surface() -> None:
    taught = room_profile(3.0, 0.0, 0.0, walls=CORRIDOR)
    blind = np.full(RAYS, np.inf)
    assert further_share(blind, taught, [0, 0, 0], fov_deg=FOV, further_m=0.5) == 1.0
    assert (
        further_share(taught, np.full(RAYS, np.inf), [0, 0, 0], fov_deg=FOV, further_m=0.5) is None
    )


def held(params: TopometricParams, truth_k: int, estimate_k: int) -> list[PathEstimate]:
    """A robot standing at image ``truth_k`` of a path taught down the corridor, its tracker
    locked (sd 0.03 m) at image ``estimate_k``; its estimate after each of 30 frames."""
    path, depths = taught_edge(np.array([0.0, 0.0, 0.0]), 120, walls=CORRIDOR)
    tracker = depth_tracker(path, depths, params)
    decision = Decision(Action.navigate(0), 1, {}, 0)
    tracker._start(0, decision, estimate_k)
    tracker.mean = path.poses[estimate_k].copy()
    tracker.cov = np.diag([0.03**2, 0.02**2, 0.01**2])
    tracker.fixed_frames, tracker.last_fix = 10, 0.0
    tracker.estimate = tracker._estimate(0.0, 1)
    assert tracker.estimate.locked
    truth = compose(np.zeros(3), path.poses[truth_k])
    rng = np.random.default_rng(0)
    out = []
    for step in range(1, 31):
        depth = room_profile(*truth, walls=CORRIDOR) + rng.normal(0, 0.01, RAYS)
        est = tracker.step(
            NO_FEATURES,
            t=0.1 * step,
            v=0.0,
            w=0.0,
            dt=0.1,
            decision=decision,
            along_belief=None,
            depth=depth,
        )
        assert est is not None
        out.append(est)
    return out


def test_a_tracker_locked_at_the_wrong_point_along_a_corridor_is_refuted_after_a_window() -> None:
    # the robot at 1.5 m (image 30), the estimate 2.5 m ahead of it (image 80), where the
    # corridor's end was taught within reach: the walls align anywhere, and without the
    # comparison the estimate stays locked there
    off = held(TopometricParams(), truth_k=30, estimate_k=80)
    assert all(e.locked and not e.refuted and abs(e.along_m - 4.0) < 0.3 for e in off)
    params = replace(TopometricParams(), depth_refute=True)
    on = held(params, truth_k=30, estimate_k=80)
    first = next(k for k, e in enumerate(on) if e.refuted)
    assert first == params.depth_refute_frames - 1  # the tenth frame, not before
    assert not on[first].locked and on[first].sigma_along >= params.init_along_m * 0.9
    # it stays refuted while the depth disagrees (the belief's word turned round)
    assert all(e.refuted for e in on[first:])


def test_a_tracker_where_the_robot_is_is_never_refuted() -> None:
    params = replace(TopometricParams(), depth_refute=True)
    for k in (10, 30, 60, 100):
        assert not any(e.refuted for e in held(params, truth_k=k, estimate_k=k))


def naive_refuted(est: PathEstimate, first: int, along: np.ndarray, n_fine: int, ratio: float):
    """One state at a time: the tracked edge's images 1 / ratio at the estimate, rising as a
    Gaussian in metres (sd at least 0.3 m) to 1 away from it; every other state 1."""
    sigma = max(est.sigma_along, 0.3)
    out = []
    for s in range(n_fine):
        if first <= s < first + len(along):
            near = math.exp(-0.5 * ((along[s - first] - est.along_m) / sigma) ** 2)
            out.append(1.0 - (1.0 - 1.0 / ratio) * near)
        else:
            out.append(1.0)
    return out


@given(
    n_images=st.integers(1, 40),
    before=st.integers(0, 30),
    after=st.integers(0, 30),
    along_m=st.floats(-1.0, 6.0),
    sigma=st.floats(0.0, 2.0),
    ratio=st.floats(1.01, 50.0),
    locked=st.booleans(),
)
def test_a_refuted_estimate_weighs_its_own_images_less_against_the_naive_reference(
    n_images: int,
    before: int,
    after: int,
    along_m: float,
    sigma: float,
    ratio: float,
    locked: bool,
) -> None:
    along = np.linspace(0.0, 5.0, n_images)
    n_fine = before + n_images + after
    est = replace(path_estimate(along=along_m, sigma_along=sigma, locked=locked), refuted=True)
    out = path_likelihood(est, before, along, n_fine, ratio)
    assert out is not None and out.shape == (n_fine,)
    np.testing.assert_allclose(out, naive_refuted(est, before, along, n_fine, ratio), rtol=1e-12)
    assert out.max() / out.min() <= ratio * (1 + 1e-12)
    nearest = before + int(np.argmin(np.abs(along - along_m)))
    assert out[nearest] == out.min()
    assert path_likelihood(est, before, along, n_fine, 1.0) is None


def test_depth_refute_defaults_are_documented_numbers() -> None:
    p = TopometricParams()
    assert not p.depth_refute
    assert (p.depth_refute_frames, p.depth_refute_share, p.depth_further_m) == (10, 0.15, 0.5)
