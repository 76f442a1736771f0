"""Planar two-view geometry: the heading and the direction of the robot from a taught camera,
on synthetic scenes with known poses (a naive point projection is the reference)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from server.vision.relpose import CameraModel, relative_pose

CAMERA = CameraModel(pitch_deg=5.0)


def project(points: np.ndarray, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of world points ``(n, 3)`` (x, y on the floor, z up from the camera's height)
    seen from ``pose`` (x, y, heading) by :data:`CAMERA` (pitched up), and which are in view."""
    d = points[:, :2] - pose[:2]
    c, s = math.cos(pose[2]), math.sin(pose[2])
    fwd, left, up = c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], points[:, 2]
    p = math.radians(CAMERA.pitch_deg)
    # the camera pitched up: its forward axis rises by p
    z = fwd * math.cos(p) + up * math.sin(p)
    y = -up * math.cos(p) + fwd * math.sin(p)
    x = -left
    f = CAMERA.focal_px
    uv = np.stack([f * x / z + (CAMERA.width - 1) / 2, f * y / z + (CAMERA.height - 1) / 2], 1)
    seen = (z > 0.3) & (uv[:, 0] >= 0) & (uv[:, 0] < CAMERA.width)
    seen &= (uv[:, 1] >= 0) & (uv[:, 1] < CAMERA.height)
    return uv, seen


def scene(rng: np.random.Generator, n: int = 400) -> np.ndarray:
    return np.stack(
        [rng.uniform(1.5, 7.0, n), rng.uniform(-4, 4, n), rng.uniform(-0.45, 2.0, n)], axis=1
    )


@pytest.mark.parametrize("seed", range(8))
def test_heading_and_direction_against_the_truth(seed: int) -> None:
    rng = np.random.default_rng(seed)
    points = scene(rng)
    taught = np.zeros(3)
    here = np.array([rng.uniform(-1, 1), rng.uniform(-1.5, 1.5), rng.uniform(-0.5, 0.5)])
    ut, st = project(points, taught)
    uc, sc = project(points, here)
    both = st & sc
    noise = rng.normal(0, 0.5, (len(points), 2))
    fit = relative_pose(uc[both] + noise[both], ut[both], CAMERA)
    assert fit is not None and fit.inliers > 0.8 * both.sum()
    assert abs(fit.yaw - here[2]) < math.radians(1.0)
    assert fit.bearing is not None
    truth = math.atan2(here[1], here[0])
    error = (fit.bearing - truth + math.pi / 2) % math.pi - math.pi / 2
    assert abs(error) < math.radians(3.0)


def test_outliers_are_left_out_and_too_few_matches_give_nothing() -> None:
    rng = np.random.default_rng(1)
    points = scene(rng)
    here = np.array([0.4, 0.3, 0.2])
    ut, st = project(points, np.zeros(3))
    uc, sc = project(points, here)
    both = np.nonzero(st & sc)[0]
    cur, tau = uc[both].copy(), ut[both].copy()
    wrong = rng.choice(len(both), len(both) // 3, replace=False)
    cur[wrong] = rng.uniform([0, 0], [320, 240], (len(wrong), 2))  # a third mismatched
    fit = relative_pose(cur, tau, CAMERA)
    assert fit is not None and abs(fit.yaw - 0.2) < math.radians(1.5)
    assert relative_pose(cur[:5], tau[:5], CAMERA) is None


def test_standing_still_the_heading_is_told_and_the_direction_is_not() -> None:
    rng = np.random.default_rng(2)
    points = scene(rng)
    ut, st = project(points, np.zeros(3))
    uc, sc = project(points, np.array([0.0, 0.0, 0.3]))  # turned only
    both = st & sc
    fit = relative_pose(uc[both], ut[both], CAMERA)
    assert fit is not None and abs(fit.yaw - 0.3) < 1e-3
    assert fit.bearing is None and fit.parallax_px < 2.0
