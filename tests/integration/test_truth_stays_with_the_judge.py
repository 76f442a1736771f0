"""The simulator's truth reaches only the judge: the teaching guide and a navigation trial
send the server what a real robot could (frames, timestamps, odometry, depth), never the true
pose. A real server, the simulated home, the robot client."""

from __future__ import annotations

import math
import sqlite3
from pathlib import Path
from typing import Any

import pytest

from robot_client.client import TeachRepeatClient
from robot_client.guide import teach_route
from robot_client.sim import SimulatedRobot, SimWorld, load_plan
from robot_client.sim.world import Pose
from robot_client.trial import run_trial
from server.process import ADMIN, start_server

PLAN = Path(__file__).resolve().parents[1] / "data" / "plans" / "two_rooms.json"


class SpyClient(TeachRepeatClient):
    """The real client, remembering every frame and spin image it sends."""

    sent: list[dict[str, Any]]

    def upload_frame(self, robot: str, jpeg: bytes, **kw: Any) -> Any:  # type: ignore[override]
        self.sent.append({"kind": "frame", **kw})
        return super().upload_frame(robot, jpeg, **kw)

    def upload_spin_image(self, robot: str, jpeg: bytes, **kw: Any) -> Any:  # type: ignore[override]
        self.sent.append({"kind": "spin", **kw})
        return super().upload_spin_image(robot, jpeg, **kw)


@pytest.mark.slow
def test_no_true_pose_reaches_the_server(tmp_path: Path) -> None:
    server = start_server(tmp_path / "s.sqlite")
    plan = load_plan(PLAN)
    try:
        with TeachRepeatClient(server.url, ADMIN) as admin:
            token = admin.register_robot("sim").token
        with SpyClient(server.url, token) as client, SimWorld(plan, seed=1) as world:
            client.sent = []
            robot = SimulatedRobot(world, Pose(1.8, 1.75, math.pi), seed=1)
            tour = teach_route(client, "sim", robot, plan, tour="two rooms")
            taught = list(client.sent)
            robot.teleport(Pose(5.0, 1.2, math.pi / 2))
            run_trial(client, "sim", robot, plan, "desk", tour=tour, max_steps=20)
            navigated = client.sent[len(taught) :]
    finally:
        server.stop()
    assert taught and navigated
    assert all(item.get("pose") is None for item in taught + navigated)
    # the odometry sent is the robot's measured speeds (noisy: nearly all distinct), not the
    # guide's commands (a handful of values); every path frame brings its depth profile
    frames = [item for item in taught if item["kind"] == "frame"]
    assert len({round(item["v"], 9) for item in frames}) > 0.8 * len(frames)
    assert all(item.get("depth") for item in frames)
    with sqlite3.connect(tmp_path / "s.sqlite") as db:
        rows = db.execute("SELECT pose_x, pose_y, pose_theta, depth FROM images").fetchall()
    assert rows and all(r[:3] == (None, None, None) for r in rows)
    assert sum(r[3] is not None for r in rows) >= len(frames) - 1
