"""Learning from a repeat run end to end (issue 25 parts 3, 4 and 6): a real server with
``learning.collect`` on, the simulated apartment, the robot client and the guide.

The guide teaches three places; the robot is carried into the corridor and sent to the office
(as in test_closed_loop.py); after it arrived, ``POST /robots/{robot}/learn`` keeps what the run
taught: its images as experiences of the images they matched and its motion as learned
transitions. Both are listed, a second learn finds nothing more to keep (the task's frames were
taken), and removing them leaves the tour as it was taught.

(A second trial from the same spot is not part of this test: on this tour it arrives at the
wrong place 5 m off with or without what was learned, while spinning in the hall; see
docs/learning.md, "Experiences".)
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path

import pytest

from robot_client.client import ApiError, TeachRepeatClient
from robot_client.guide import teach_route
from robot_client.sim import SimulatedRobot, SimWorld, load_plan
from robot_client.sim.world import Pose
from robot_client.trial import SUCCESS_RADIUS_M, run_trial
from server import schemas
from server.process import ADMIN, ServerProcess, start_server

COLLECT = json.dumps({"learning.collect": True})


@pytest.fixture()
def server(tmp_path: Path) -> Iterator[ServerProcess]:
    proc = start_server(tmp_path / "learn.sqlite", extra_env={"TEACHREPEAT_NAVIGATION": COLLECT})
    yield proc
    proc.stop()


def test_a_run_that_arrived_is_kept_as_experiences_and_transitions_and_can_be_undone(
    server: ServerProcess,
) -> None:
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
        taught = _structure(client.tour(graph.id))
        robot.teleport(Pose(6.0, 4.75, math.pi))
        first = run_trial(client, "sim", robot, plan, "office", max_steps=900)
        assert first.state == "arrived" and first.distance_m <= SUCCESS_RADIUS_M, first

        changes = client.learn("sim")
        kinds = sorted(c.kind for c in changes)
        assert kinds == ["experience", "transitions"], changes
        experience = next(c for c in changes if c.kind == "experience")
        assert experience.images > 0 and experience.tour == graph.id
        assert sorted(c.id for c in client.learned(graph.id)) == sorted(c.id for c in changes)

        assert all(c.source and c.summary for c in changes)
        with pytest.raises(ApiError) as nothing_left:  # the task's frames were taken
            client.learn("sim")
        assert nothing_left.value.status == 409
        assert len(client.learned(graph.id)) == 2

        for change in changes:
            client.unlearn(graph.id, change.id)
        assert client.learned(graph.id) == []
        assert _structure(client.tour(graph.id)) == taught


def _structure(tour: schemas.TourGraphPublic) -> tuple[object, ...]:
    """The tour as taught: places with their images, edges with their ends and images (not the
    distinctiveness, which the server fills in the background after teaching)."""
    return (
        [(loc.id, loc.name, loc.image_ids) for loc in tour.locations],
        [(e.id, e.source, e.target, e.image_count, e.first_image_id) for e in tour.edges],
    )
