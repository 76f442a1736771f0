"""Motion commands: homing with the taught motion, spinning, exploring, obstacle blending."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from server.motion import (
    MotionParams,
    avoid_obstacles,
    avoid_side,
    explore_command,
    navigate_command,
    ray_angles,
    rotate_command,
)
from server.navigation.runtime import next_moving as _next_moving

P = MotionParams()


def test_no_features_replays_the_taught_motion() -> None:
    assert navigate_command(None, taught_v=0.3, taught_w=0.2, params=P) == (0.3, 0.2)


def test_features_to_the_right_turn_the_robot_left() -> None:
    v, w = navigate_command(0.1, taught_v=0.3, taught_w=0.0, params=P)
    assert v == 0.3 and w == pytest.approx(P.homing_gain * 0.1)
    _, w = navigate_command(-0.1, taught_v=0.3, taught_w=0.0, params=P)
    assert w < 0


def test_a_taught_turn_on_the_spot_is_repeated() -> None:
    assert navigate_command(None, taught_v=0.0, taught_w=0.8, params=P) == (0.0, 0.8)


def test_slow_taught_speeds_are_raised_to_the_minimum() -> None:
    v, _ = navigate_command(None, taught_v=0.02, taught_w=0.0, params=P)
    assert v == P.min_v


@given(
    offset=st.one_of(st.none(), st.floats(-1, 1)),
    taught_v=st.floats(-1, 2),
    taught_w=st.floats(-5, 5),
)
def test_commands_stay_within_limits(
    offset: float | None, taught_v: float, taught_w: float
) -> None:
    v, w = navigate_command(offset, taught_v=taught_v, taught_w=taught_w, params=P)
    assert 0.0 <= v <= P.max_v
    assert abs(w) <= P.max_w


def test_rotate_turns_toward_the_sought_view() -> None:
    assert rotate_command(P) == (0.0, P.spin_w)
    assert rotate_command(P, toward=-0.5) == (0.0, -P.spin_w)
    v, w = rotate_command(P, toward=0.01)
    assert v == 0.0 and 0 < w < P.spin_w


def test_ray_angles_run_left_to_right() -> None:
    a = ray_angles(5, 90.0)
    assert a[0] == pytest.approx(np.pi / 4) and a[-1] == pytest.approx(-np.pi / 4)
    assert np.all(np.diff(a) < 0)


def test_explore_heads_for_open_space() -> None:
    left_open = np.array([4.0] * 10 + [0.8] * 21)
    _, w = explore_command(left_open, P)
    assert w > 0
    _, w = explore_command(left_open[::-1], P)
    assert w < 0
    v, w = explore_command(np.full(31, 0.3), P)  # boxed in
    assert v == 0.0 and w != 0.0
    assert explore_command(None, P)[0] > 0  # no depth sensor: creep and turn


def test_obstacles_far_away_change_nothing() -> None:
    assert avoid_obstacles(0.3, 0.1, np.full(31, 3.0), P) == (0.3, 0.1)
    assert avoid_obstacles(0.3, 0.1, None, P) == (0.3, 0.1)


def test_an_obstacle_close_on_the_right_steers_left_and_slows() -> None:
    ranges = np.full(31, 3.0)
    ranges[25:] = 0.3  # right side
    v, w = avoid_obstacles(0.3, 0.0, ranges, P)
    assert v < 0.3 and w > 0
    ranges[25:] = P.avoid_full_m / 2  # immediate: avoidance dominates
    v, w = avoid_obstacles(0.3, -0.5, ranges, P)
    assert v == 0.0 and w == pytest.approx(P.max_w)


def test_turning_on_the_spot_is_never_blended() -> None:
    assert avoid_obstacles(0.0, -0.4, np.full(31, 0.1), P) == (0.0, -0.4)


def test_next_moving_matches_a_naive_loop() -> None:
    rng = np.random.default_rng(0)
    for _ in range(50):
        n = int(rng.integers(1, 30))
        v = np.where(rng.random(n) < 0.5, 0.0, rng.random(n))
        w = np.where(rng.random(n) < 0.5, 0.0, rng.random(n))
        expect = []
        for i in range(n):
            nxt = next((j for j in range(i, n) if abs(v[j]) > 1e-3 or abs(w[j]) > 1e-3), -1)
            expect.append(nxt)
        np.testing.assert_array_equal(_next_moving(v, w), expect)


def test_facing_a_wall_beside_a_doorway_turns_toward_the_doorway() -> None:
    # the wall is nearest slightly right of centre, the doorway opens further right
    angles = ray_angles(31, P.depth_fov_deg)
    ranges = 0.2 / np.cos(angles + 0.05)
    ranges[25:] = 4.0  # through the door
    v, w = avoid_obstacles(0.3, 0.0, ranges, P)
    assert v == 0.0 and w == pytest.approx(-P.max_w)
    # mirrored: the doorway on the left
    v, w = avoid_obstacles(0.3, 0.0, ranges[::-1], P)
    assert w == pytest.approx(P.max_w)


def test_avoidance_keeps_turning_the_way_it_chose() -> None:
    """Facing an obstacle head-on, the more open side flips with every small turn; turning
    toward it each frame would swing the robot back and forth in front of the obstacle."""
    angles = ray_angles(31, P.depth_fov_deg)
    ahead = 0.3 / np.cos(angles)  # a wall square ahead
    leans_left = np.where(angles > 0, ahead + 0.1, ahead)
    leans_right = leans_left[::-1]
    assert avoid_side(leans_left, P) == 1 and avoid_side(leans_right, P) == -1
    side = avoid_side(leans_left, P)
    for profile in [leans_right, leans_left, leans_right]:
        side = avoid_side(profile, P, side)
        assert side == 1
        _, w = avoid_obstacles(0.3, 0.0, profile, P, side=side)
        assert w > 0
    # a side much more open than the one chosen wins; nothing near forgets the choice
    door_right = np.where(angles < 0, 3.0, ahead)
    assert avoid_side(door_right, P, previous=1) == -1
    assert avoid_side(np.full(31, 3.0), P, previous=1) == 0
    assert avoid_side(None, P, previous=-1) == 0


def test_open_heading_is_straight_on_in_the_open_and_toward_the_gap_otherwise() -> None:
    from server.motion import open_heading

    p = MotionParams()
    assert open_heading(None, p) is None
    bearing, far = open_heading([np.inf] * 31, p)
    assert bearing == 0.0 and far == pytest.approx(p.open_m)
    left_open = [3.0] * 10 + [0.3] * 21
    bearing, far = open_heading(left_open, p)
    assert bearing > np.radians(20) and far == pytest.approx(p.open_m)
    bearing, _ = open_heading(left_open[::-1], p)
    assert bearing < -np.radians(20)
