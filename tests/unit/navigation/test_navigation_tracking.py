"""The path tracking filter's maths: prediction by odometry and the measurement updates."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from server.navigation.tracking import (
    OdometryNoise,
    bearing_of,
    initial_cov,
    move,
    path_frame_cov,
    predict,
    update_along,
    update_bearing,
    update_heading,
    update_pose,
)


@given(st.floats(-0.5, 0.5), st.floats(-1.5, 1.5), st.floats(0.0, 0.5), st.floats(-3.0, 3.0))
def test_prediction_moves_by_the_odometry_and_never_grows_surer(
    v: float, w: float, dt: float, heading: float
) -> None:
    mean = np.array([1.0, -2.0, heading])
    cov = initial_cov(heading, 0.1, 0.1, 0.05)
    out, P = predict(mean, cov, v, w, dt)
    np.testing.assert_allclose(out, move(mean, v, w, dt))
    assert np.allclose(P, P.T) and np.linalg.eigvalsh(P).min() > 0
    # the motion shears the covariance (volume-preserving) and the odometry's noise adds to it
    assert np.linalg.det(P) >= np.linalg.det(cov) * (1 - 1e-9)


def test_prediction_matches_sampled_poses_for_a_straight_drive() -> None:
    rng = np.random.default_rng(0)
    mean = np.zeros(3)
    cov = np.diag([0.01**2, 0.01**2, 0.05**2])
    quiet = OdometryNoise(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    _, P = predict(mean, cov, 0.5, 0.0, 2.0, quiet)  # 1 m ahead, no noise of its own
    samples = rng.multivariate_normal(mean, cov, size=20000)
    moved = np.array([move(s, 0.5, 0.0, 2.0) for s in samples[:4000]])
    # the heading's spread turns into a sideways spread of ~1 m x 0.05 rad
    assert math.isclose(np.std(moved[:, 1]), math.sqrt(P[1, 1]), rel_tol=0.15)


def test_a_heading_measurement_pulls_the_heading_and_is_gated_when_implausible() -> None:
    mean, cov = np.zeros(3), np.diag([0.1, 0.1, 0.2**2])
    up = update_heading(mean, cov, 0.1, 0.05)
    assert up.used and 0.0 < up.mean[2] < 0.1 and up.cov[2, 2] < cov[2, 2]
    far = update_heading(mean, cov, 2.0, 0.05)
    assert not far.used and np.array_equal(far.mean, mean)
    # wraps: -3.1 and 3.1 rad are close
    near = update_heading(np.array([0.0, 0.0, 3.1]), cov, -3.1, 0.05)
    assert near.used and abs(near.innovation) < 0.1


def test_a_bearing_from_a_taught_camera_corrects_the_lateral_offset() -> None:
    taught = np.array([2.0, 0.0, 0.0])  # ahead, facing +x
    truth = np.array([0.0, 0.3, 0.0])  # 0.3 m to the left, 2 m behind it
    measured, _, _ = bearing_of(truth, taught)
    mean = np.array([0.0, 0.0, 0.0])
    cov = np.diag([0.01, 0.2**2, 0.01])
    for _ in range(20):
        up = update_bearing(mean, cov, taught, measured, 0.02)
        mean, cov = up.mean, up.cov
    assert abs(mean[1] - 0.3) < 0.02
    # the Jacobian against finite differences
    _, _, H = bearing_of(mean, taught)
    eps = 1e-6
    for i in range(2):
        d = np.zeros(3)
        d[i] = eps
        numeric = (bearing_of(mean + d, taught)[0] - bearing_of(mean - d, taught)[0]) / (2 * eps)
        assert math.isclose(H[i], numeric, rel_tol=1e-4, abs_tol=1e-6)


def test_along_and_pose_measurements() -> None:
    mean, cov = np.array([1.0, 0.2, 0.0]), np.diag([0.3**2, 0.1**2, 0.05**2])
    up = update_along(mean, cov, [1.5, 0.0], 0.0, 0.05)
    assert up.used and 1.4 < up.mean[0] < 1.5 and abs(up.mean[1] - 0.2) < 1e-9
    pose = update_pose(mean, cov, [1.2, 0.0, 0.02], np.diag([0.01**2, 0.01**2, 0.01**2]))
    assert pose.used and np.allclose(pose.mean, [1.2, 0.0, 0.02], atol=0.02)
    wrong = update_pose(mean, cov, [5.0, 3.0, 2.0], np.diag([0.01**2] * 3))
    assert not wrong.used


def test_the_covariance_in_the_path_frame() -> None:
    P = initial_cov(math.pi / 2, 0.5, 0.1, 0.2)  # along +y
    pc = path_frame_cov(P, math.pi / 2)
    np.testing.assert_allclose(np.sqrt(np.diag(pc)), [0.5, 0.1], atol=1e-9)
