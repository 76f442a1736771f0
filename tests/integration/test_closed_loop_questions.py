"""Questions end to end (issue 25 parts 1 and 5): a real server, the simulated apartment, the
robot client and the guide.

Part 1: the guide walks hall -> bathroom -> hall but does not say "hall" the second time; the
robot asks "are we at 'hall'?", the answer yes closes the loop. Part 5: a person drives the
navigating robot from the living room to the kitchen, two places taught apart with no path
between them; the robot proposes the way, yes adds it, and the plan to the kitchen takes it.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest

from robot_client.client import TeachRepeatClient
from robot_client.guide import (
    GuideParams,
    guided_tour_steps,
    recorded_steps,
    upload_tour,
    walk_to,
)
from robot_client.sim import SimulatedRobot, SimWorld, load_plan
from robot_client.sim.world import Pose
from server import schemas
from server.imaging import encode_jpeg
from server.process import ADMIN, ServerProcess, start_server

QUESTIONS_ON = json.dumps({"questions.teaching": True, "questions.exploration": True})


@pytest.fixture()
def server(tmp_path: Path) -> Iterator[ServerProcess]:
    proc = start_server(tmp_path / "ask.sqlite", extra_env={"TEACHREPEAT_NAVIGATION": QUESTIONS_ON})
    yield proc
    proc.stop()


def test_the_robot_asks_whether_it_is_back_in_the_hall_and_yes_closes_the_loop(
    server: ServerProcess,
) -> None:
    plan = load_plan()
    with TeachRepeatClient(server.url, ADMIN) as admin:
        token = admin.register_robot("sim").token
    with (
        TeachRepeatClient(server.url, token) as client,
        SimWorld(plan, condition="same", seed=3) as world,
    ):
        hall = plan.place("hall")
        robot = SimulatedRobot(world, Pose(hall.x, hall.y, hall.yaw), seed=3)
        tour = client.tour_named("loop", create=True).id
        client.start_teaching("sim", tour)
        steps = list(
            recorded_steps(robot, guided_tour_steps(robot, plan, ("hall", "bathroom", "hall")))
        )
        assert steps[-1].kind == "mark" and steps[-1].place == "hall"
        asked_early = []
        for item in steps[:-1]:  # everything but the second "this is the hall"
            if item.kind == "mark":
                client.mark_location("sim", item.place)
            elif item.kind == "spin":
                assert item.jpeg is not None
                client.upload_spin_image("sim", item.jpeg, timestamp=item.t, v=item.v, w=item.w)
            else:
                assert item.jpeg is not None
                client.upload_frame("sim", item.jpeg, timestamp=item.t, v=item.v, w=item.w)
                asked_early += client.questions("sim")
        # the robot stands in the hall: a few more frames of what it sees there
        t = steps[-2].t
        questions = client.questions("sim")
        for k in range(12):
            if questions:
                break
            image = robot.read()
            assert image is not None
            client.upload_frame("sim", encode_jpeg(image), timestamp=t + 0.1 * (k + 1))
            questions = client.questions("sim")
        (q,) = questions
        assert q.kind == "same_place" and q.location == "hall", q
        assert q.source_location == "bathroom"
        # the question came when the robot was back in the hall, not on the way there
        assert all(x.location == "hall" and x.id == q.id for x in asked_early), asked_early
        answered = client.answer("sim", q.id, "yes")
        assert answered.state == "yes" and answered.change is not None
        graph = client.finish_teaching("sim").tour
    assert [loc.name for loc in graph.locations] == ["hall", "bathroom"]
    assert sorted((e.source_name, e.target_name) for e in graph.edges) == [
        ("bathroom", "hall"),
        ("hall", "bathroom"),
    ]


def test_a_way_driven_from_the_living_room_to_the_kitchen_becomes_a_path_on_yes(
    server: ServerProcess,
) -> None:
    plan = load_plan()
    with TeachRepeatClient(server.url, ADMIN) as admin:
        token = admin.register_robot("sim").token
    with (
        TeachRepeatClient(server.url, token) as client,
        SimWorld(plan, condition="same", seed=4) as world,
    ):
        kitchen, living = plan.place("kitchen"), plan.place("living room")
        robot = SimulatedRobot(world, Pose(kitchen.x, kitchen.y, kitchen.yaw), seed=4)
        # two places taught apart (the robot was carried between them): no path at all
        for place in ("kitchen", "living room"):
            steps = recorded_steps(robot, guided_tour_steps(robot, plan, (place,)))
            graph = upload_tour(client, "sim", steps, tour="two rooms")
        assert len(graph.locations) == 2 and graph.edges == []
        client.goto("sim", "kitchen")
        t = robot.now()

        def send(v: float = 0.0, w: float = 0.0) -> schemas.NavigationFrameResult:
            image = robot.read()
            assert image is not None
            r = client.upload_frame("sim", encode_jpeg(image), timestamp=robot.now() - t, v=v, w=w)
            assert isinstance(r, schemas.NavigationFrameResult)
            return r

        for _ in range(6):  # standing in the living room
            send()
        # a person drives it through the door to the kitchen
        for step in walk_to(robot, kitchen.x, kitchen.y, kitchen.yaw, GuideParams()):
            send(step.v, step.w)
        questions = client.questions("sim")
        for _ in range(10):  # standing in the kitchen
            if questions:
                break
            send()
            questions = client.questions("sim")
        (q,) = questions
        assert q.kind == "new_path", q
        assert (q.source_location, q.location) == ("living room", "kitchen"), q
        assert q.frames >= 20
        assert client.answer("sim", q.id, "yes").state == "yes"
        (change,) = client.learned(graph.id)
        assert change.kind == "new_path" and change.edge is not None
        # carried back to the living room and sent to the kitchen: the plan takes the new path
        robot.teleport(Pose(living.x, living.y, living.yaw))
        client.goto("sim", "kitchen")
        t = robot.now() - 1000.0  # timestamps go on increasing
        commands = [send().command for _ in range(8)]
    assert any(c.edge == change.edge for c in commands), commands
