"""The product end to end: a real server, the simulated home, the robot client and the guide.

Teach three places, send the robot to one, and check with the simulator's ground truth that it
says "arrived" where the place really is.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import pytest

from robot_client.client import TeachRepeatClient
from robot_client.guide import teach_route
from robot_client.sim import SimulatedRobot, SimWorld, load_plan
from robot_client.sim.world import Pose
from robot_client.trial import SUCCESS_RADIUS_M, run_trial
from server.process import ADMIN, ServerProcess, start_server


@pytest.fixture()
def server(tmp_path: Path) -> Iterator[ServerProcess]:
    proc = start_server(tmp_path / "loop.sqlite")
    yield proc
    proc.stop()


def test_teach_three_places_then_go_to_one(server: ServerProcess) -> None:
    plan = load_plan()
    with TeachRepeatClient(server.url, ADMIN) as admin:
        token = admin.register_robot("sim").token
    with (
        TeachRepeatClient(server.url, token) as client,
        SimWorld(plan, condition="same", seed=1) as world,
    ):
        robot = SimulatedRobot(world, Pose(6.8, 4.75, 0.0), seed=1)
        graph = teach_route(
            client, "sim", robot, plan, tour="three", route=("hall", "bathroom", "hall", "office")
        )
        assert [loc.name for loc in graph.locations] == ["hall", "bathroom", "office"]
        assert len(graph.edges) == 3
        # the robot is carried back into the corridor, facing away from the office
        robot.teleport(Pose(6.0, 4.75, math.pi))
        result = run_trial(client, "sim", robot, plan, "office", max_steps=900)
    assert result.state == "arrived", result
    assert result.distance_m <= SUCCESS_RADIUS_M, result
    assert not result.wrong_arrival
