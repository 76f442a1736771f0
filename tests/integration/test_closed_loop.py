"""The product end to end: a real server, the simulated home, the robot client and the guide.

Teach three places, send the robot to one, and check with the simulator's ground truth that it
says "arrived" where the place really is.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from robot_client.client import TeachRepeatClient
from robot_client.guide import teach_route
from robot_client.sim import SimulatedRobot, SimWorld, load_plan
from robot_client.sim.floorplan import FloorPlan
from robot_client.sim.world import Pose
from robot_client.trial import SUCCESS_RADIUS_M, run_trial
from server import schemas
from server.process import ADMIN, ServerProcess, start_server

CARRIED_TO = Pose(6.0, 4.75, math.pi)
"""Where the robot is carried after teaching: the corridor, facing away from the office."""
STEPS = 1500
"""Frames the robot is given to arrive: 150 s of robot time, as ``bench navigate`` gives a trial."""


@pytest.fixture()
def server(tmp_path: Path) -> Iterator[ServerProcess]:
    proc = start_server(tmp_path / "loop.sqlite")
    yield proc
    proc.stop()


@contextmanager
def three_places_taught(
    server: ServerProcess,
) -> Iterator[tuple[TeachRepeatClient, SimulatedRobot, FloorPlan, schemas.TourGraphPublic]]:
    """The guide teaches hall -> bathroom -> hall -> office in the simulated apartment; the
    robot's client, the robot, the plan and the taught graph."""
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
        yield client, robot, plan, graph


def test_teach_three_places_and_go_to_one(server: ServerProcess) -> None:
    """Teach three places, carry the robot into the corridor facing away from the office, and
    send it there: it arrives within 0.5 m, at the office, and the tour is as it was taught."""
    with three_places_taught(server) as (client, robot, plan, graph):
        taught = _structure(client.tour(graph.id))
        robot.teleport(CARRIED_TO)
        first = run_trial(client, "sim", robot, plan, "office", max_steps=STEPS)
        assert first.state == "arrived" and first.distance_m <= SUCCESS_RADIUS_M, first
        assert not first.wrong_arrival
        assert client.learned(graph.id) == []  # nothing learned without a person's answer
        assert _structure(client.tour(graph.id)) == taught


def _structure(tour: schemas.TourGraphPublic) -> tuple[object, ...]:
    """The tour as taught: places with their images, edges with their ends and images (not the
    distinctiveness, which the server fills in the background after teaching)."""
    return (
        [(loc.id, loc.name, loc.image_ids) for loc in tour.locations],
        [(e.id, e.source, e.target, e.image_count, e.first_image_id) for e in tour.edges],
    )
