"""Taught paths as geometry: dead reckoning, pose algebra, projection onto a path."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from server.domain import Edge
from server.navigation.geometry import (
    STAND_M,
    EdgePath,
    compose,
    dead_reckon,
    inverse,
    relative,
    wrap,
)

poses = st.tuples(st.floats(-10, 10), st.floats(-10, 10), st.floats(-math.pi, math.pi)).map(
    lambda p: np.array(p)
)


def naive_dead_reckon(t: list[float], v: list[float], w: list[float]) -> np.ndarray:
    """Euler integration in 1000 sub-steps per interval: the reference."""
    x = y = th = 0.0
    out = [(0.0, 0.0, 0.0)]
    for k in range(1, len(t)):
        dt = max(t[k] - t[k - 1], 0.0) / 1000
        for _ in range(1000):
            x += v[k] * dt * math.cos(th + w[k] * dt / 2)
            y += v[k] * dt * math.sin(th + w[k] * dt / 2)
            th += w[k] * dt
        out.append((x, y, math.atan2(math.sin(th), math.cos(th))))
    return np.array(out)


@given(
    st.lists(
        st.tuples(st.floats(0.01, 0.3), st.floats(-0.5, 0.5), st.floats(-1.5, 1.5)),
        min_size=1,
        max_size=12,
    )
)
def test_dead_reckoning_matches_a_fine_euler_integration(
    steps: list[tuple[float, float, float]],
) -> None:
    t = [0.0]
    for dt, _, _ in steps:
        t.append(t[-1] + dt)
    v = [0.0] + [s[1] for s in steps]
    w = [0.0] + [s[2] for s in steps]
    got = dead_reckon(t, v, w)
    want = naive_dead_reckon(t, v, w)
    np.testing.assert_allclose(got[:, :2], want[:, :2], atol=1e-4)
    np.testing.assert_allclose(wrap(got[:, 2] - want[:, 2]), 0.0, atol=1e-6)


def test_dead_reckoning_ignores_the_first_motion_and_backward_timestamps() -> None:
    got = dead_reckon([0.0, 1.0, 0.5, 1.5], [9.0, 0.2, 5.0, 0.2], [9.0, 0.0, 5.0, 0.0])
    np.testing.assert_allclose(got[:, 0], [0.0, 0.2, 0.2, 0.4])
    assert np.allclose(got[:, 1:], 0.0)


@given(poses, poses)
def test_relative_then_compose_gives_the_pose_back(a: np.ndarray, b: np.ndarray) -> None:
    back = compose(a, relative(a, b))
    np.testing.assert_allclose(back[:2], b[:2], atol=1e-9)
    assert abs(float(wrap(back[2] - b[2]))) < 1e-9
    identity = compose(a, inverse(a))
    np.testing.assert_allclose(identity, 0.0, atol=1e-9)


def straight(n: int = 21, speed: float = 0.25, turn: float = 0.0) -> EdgePath:
    t = np.arange(n) * 0.2
    return EdgePath.of(Edge(0, 1, tuple(range(n)), t, np.full(n, speed), np.full(n, turn)))


def test_projection_gives_along_and_signed_lateral_offsets() -> None:
    path = straight()  # 1 m straight along +x
    assert math.isclose(path.length, 1.0, abs_tol=1e-9)
    s, lat = path.project([0.4, 0.3])
    assert math.isclose(s, 0.4, abs_tol=1e-9) and math.isclose(lat, 0.3, abs_tol=1e-9)
    s, lat = path.project([0.7, -0.2])
    assert math.isclose(s, 0.7, abs_tol=1e-9) and math.isclose(lat, -0.2, abs_tol=1e-9)
    s, _ = path.project([2.0, 0.0])
    assert math.isclose(s, 1.0, abs_tol=1e-9)  # clamped to the end
    np.testing.assert_allclose(path.point_at(0.5), [0.5, 0.0], atol=1e-9)
    assert path.image_at(0.5) == 10 and path.heading_at(0.5) == 0.0


def test_a_turn_on_the_spot_has_no_length_and_images_there_share_a_place() -> None:
    # 5 images turning on the spot, then 10 driving forward
    n = 15
    t = np.arange(n) * 0.2
    v = np.array([0.0] * 5 + [0.25] * 10)
    w = np.array([0.0] + [1.0] * 4 + [0.0] * 10)
    path = EdgePath.of(Edge(0, 1, tuple(range(n)), t, v, w))
    assert np.allclose(path.along[:5], 0.0)
    _, _, idx = path.polyline
    assert idx[0] == 0 and idx[1] == 5  # the turn collapses to one point
    assert path.image_at(0.0) == 0  # the first image of the stretch
    # with a heading: the image of the turn taught facing nearest it (0, 0.2, .. 0.8 rad)
    assert [path.image_at(0.0, h) for h in (-1.0, 0.25, 0.5, 0.75, 3.0)] == [0, 1, 2, 4, 4]
    assert path.image_at(0.0, -2 * math.pi + 0.62) == 3  # angles wrap
    # driving: the nearest image, whatever the heading
    assert path.image_at(0.2, 3.0) == path.image_at(0.2) == 8
    assert math.isclose(path.heading_at(0.1), 0.8, abs_tol=1e-6)  # the way it then drove


def test_a_stretch_is_the_images_within_stand_m_along_as_a_naive_scan_finds_them() -> None:
    rng = np.random.default_rng(4)
    for _ in range(50):
        n = int(rng.integers(2, 80))
        t = np.arange(n) * 0.1
        # standing, creeping and driving; 0.2 m/s over 0.1 s lands on STAND_M exactly
        v = np.where(rng.random(n) < 0.3, 0.0, rng.choice([0.01, 0.1, 0.2, 0.25], n))
        path = EdgePath.of(Edge(0, 1, tuple(range(n)), t, v, rng.uniform(-1, 1, n)))
        for k in range(n):
            naive = [j for j in range(n) if abs(path.along[j] - path.along[k]) < STAND_M]
            assert path.stretch(k).tolist() == naive
