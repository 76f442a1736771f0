"""The pose relative to a taught image against the simulator's truth, on rendered views beside
the taught path: offsets 0 to 1.5 m, headings up to 30 degrees (0.5 rad) off, in the two-room
home.

The depth profiles fix the pose (:mod:`server.navigation.scanmatch`, from a guess on the path:
the robot is joining it); the camera fixes the heading (:mod:`server.vision.relpose`)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from robot_client.sim import SimWorld, load_plan
from robot_client.sim.world import Pose
from server.navigation.geometry import relative
from server.navigation.scanmatch import match_profiles_robust
from server.vision.features import extract
from server.vision.homing import HomingParams, match_features
from server.vision.relpose import CameraModel, relative_pose

PLAN = Path(__file__).resolve().parents[1] / "data" / "plans" / "two_rooms.json"


@pytest.mark.slow
def test_relative_pose_beside_the_taught_path_against_the_truth() -> None:
    plan = load_plan(PLAN)
    rng = np.random.default_rng(0)
    camera = CameraModel(pitch_deg=5.0)
    pose_err: dict[float, list[float]] = {}
    yaw_err: list[float] = []
    fits: dict[float, int] = {}
    tried: dict[float, int] = {}
    with SimWorld(plan, condition="same", seed=0) as world:
        taught_poses = [Pose(1.2 + 0.5 * k, 1.2, 0.0) for k in range(5)]
        for taught in taught_poses:
            t_img = extract(world.render(taught))
            t_depth = world.depth_profile(taught)
            for offset in (0.0, 0.5, 1.0, 1.5):
                for turn in (-0.5, 0.0, 0.5):  # radians: up to ~30 degrees
                    side = rng.choice([-1.0, 1.0])
                    x = taught.x - 0.3
                    y = taught.y + side * offset
                    if world.collides(x, y, 0.2):
                        continue
                    here = Pose(x, y, taught.theta + turn)
                    truth = relative(
                        np.array([taught.x, taught.y, taught.theta]),
                        np.array([here.x, here.y, here.theta]),
                    )
                    tried[offset] = tried.get(offset, 0) + 1
                    depth = world.depth_profile(here) + rng.normal(0, 0.01, 31)
                    fit = match_profiles_robust(t_depth, depth, np.zeros(3), fov_deg=90.0)
                    if fit is not None:
                        fits[offset] = fits.get(offset, 0) + 1
                        pose_err.setdefault(offset, []).append(
                            float(np.hypot(*(fit.pose[:2] - truth[:2])))
                        )
                    src, dst = match_features(
                        extract(world.render(here)), t_img, params=HomingParams()
                    )
                    rel = relative_pose(src, dst, camera)
                    if rel is not None:
                        yaw_err.append(abs(rel.yaw - truth[2]))
    print("scan fits", {o: f"{fits.get(o, 0)}/{n}" for o, n in tried.items()})
    print("scan error p50 (m)", {o: round(float(np.median(e)), 3) for o, e in pose_err.items()})
    print("yaw error p50 / p90 (deg)", np.degrees(np.percentile(yaw_err, [50, 90])))
    # within half a metre of the taught path most views fit, to a few centimetres (on
    # 2026-12-02: 9/12 and 9/13, p50 0.018 m; at 1.0 m 3/5 at 0.23 m, at 1.5 m 6/8 at 1.4 m:
    # joining from further off rests on the filter's gate and the camera, docs/navigation.md)
    for offset in (0.0, 0.5):
        assert fits.get(offset, 0) >= 0.6 * tried[offset], (offset, fits, tried)
        assert np.median(pose_err[offset]) < 0.05, (offset, pose_err[offset])
    assert math.degrees(float(np.median(yaw_err))) < 3.0
