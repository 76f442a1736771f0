"""Junctions end to end (docs/learning.md, "Junctions"): a real server, the simulated apartment,
the robot client and the guide. Two paths leave the living room through the same door
(to the bathroom and to the office), the search finds their shared prefix and applies it, and
the robot sent to the office, whose path is the one whose shared images were mapped, still
arrives, passing the junction. About 50 s."""

from __future__ import annotations

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
    proc = start_server(tmp_path / "junction.sqlite")
    yield proc
    proc.stop()


@pytest.mark.slow
def test_a_robot_still_arrives_through_a_learned_junction(server: ServerProcess) -> None:
    plan = load_plan()
    start = next(p for p in plan.places if p.name == "living room")
    with TeachRepeatClient(server.url, ADMIN) as admin:
        token = admin.register_robot("sim").token
    with (
        TeachRepeatClient(server.url, token) as client,
        SimWorld(plan, condition="same", seed=1) as world,
    ):
        robot = SimulatedRobot(world, Pose(start.x, start.y, start.yaw), seed=1)
        route = ("living room", "bathroom", "living room", "office")
        graph = teach_route(client, "sim", robot, plan, tour="fork", route=route)
        found = client.junctions(graph.id)
        (junction,) = found.junctions
        assert (junction.source, junction.kept_target, junction.other_target) == (
            "living room",
            "bathroom",
            "office",
        )
        assert junction.kept_shared >= 20 and junction.change is not None
        assert [c.kind for c in client.learned(graph.id)] == ["junction"]
        robot.teleport(Pose(start.x, start.y, start.yaw))
        result = run_trial(client, "sim", robot, plan, "office", max_steps=900)
    assert result.state == "arrived", result
    assert result.distance_m <= SUCCESS_RADIUS_M, result
    assert not result.wrong_arrival
