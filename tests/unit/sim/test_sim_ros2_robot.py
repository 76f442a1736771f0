"""The simulated ROS 2 robot: its own odometry frame, cmd_vel with a timeout, the judge's
view, frames only for readers, and what happens when it cannot start."""

from __future__ import annotations

import math
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from robot_client.drivers import ros2_dds as m
from robot_client.sim.floorplan import load_plan
from robot_client.sim.ros2_robot import SimRos2Params, SimRos2Robot
from robot_client.sim.world import Pose

PLAN = Path(__file__).resolve().parents[2] / "data" / "plans" / "two_rooms.json"
DOMAIN = 20 + (os.getpid() + 97) % 180


@pytest.fixture(scope="module")
def sim() -> Iterator[SimRos2Robot]:
    with SimRos2Robot(load_plan(PLAN), domain_id=DOMAIN, params=SimRos2Params()) as robot:
        yield robot


@pytest.fixture(scope="module")
def node(sim: SimRos2Robot) -> Iterator[m.DdsNode]:
    n = m.DdsNode(DOMAIN, interface="lo")
    yield n
    n.close()


def wait_for(condition: Any, timeout_s: float = 5.0) -> Any:
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError("timed out")
        time.sleep(0.02)


def test_it_starts_where_the_plan_says_and_publishes_no_frame_nobody_reads(
    sim: SimRos2Robot,
) -> None:
    first = load_plan(PLAN).places[0]
    pose = sim.true_pose
    assert (pose.x, pose.y) == pytest.approx((first.x, first.y))
    assert sim.running
    wait_for(lambda: sim.odometry > 3 and sim.scans > 3)
    assert sim.frames == 0  # no camera reader yet: nothing rendered


def test_odometry_is_its_own_dead_reckoning_from_the_origin_not_the_true_pose(
    sim: SimRos2Robot, node: m.DdsNode
) -> None:
    reader = node.reader("rt/odom", m.Odometry, depth=1)
    msg = wait_for(lambda: reader.take(N=1))[0]
    assert msg.header.frame_id == "odom" and msg.child_frame_id == "base_link"
    position = msg.pose.pose.position
    true = sim.true_pose
    assert math.hypot(position.x, position.y) < 0.05  # it has not moved in its own frame...
    assert math.hypot(true.x, true.y) > 1.0  # ...which is not the home's
    assert msg.header.stamp.seconds() == pytest.approx(time.time(), abs=5.0)


def test_cmd_vel_drives_it_until_the_commands_stop_coming(
    sim: SimRos2Robot, node: m.DdsNode
) -> None:
    writer = node.writer("rt/cmd_vel", m.Twist)
    before = sim.commands
    start = sim.true_pose
    writer.write(m.Twist(linear=m.Vector3(x=0.2), angular=m.Vector3(z=0.0)))  # once only
    wait_for(lambda: sim.commands > before)
    time.sleep(1.0)  # 0.5 s of driving (cmd_timeout_s), then standing
    moved = sim.true_pose
    travelled = math.hypot(moved.x - start.x, moved.y - start.y)
    assert 0.06 < travelled < 0.14  # 0.2 m/s for 0.5 s: 0.1 m
    time.sleep(0.3)
    assert sim.true_pose == moved


def test_a_teleport_moves_the_truth_but_not_the_odometry(
    sim: SimRos2Robot, node: m.DdsNode
) -> None:
    reader = node.reader("rt/odom", m.Odometry, depth=1)
    before = wait_for(lambda: reader.take(N=1))[0].pose.pose.position
    target = Pose(6.2, 1.75, 0.0)
    sim.teleport(target)
    wait_for(lambda: sim.true_pose == target)
    time.sleep(0.2)
    after = wait_for(lambda: reader.take(N=1))[0].pose.pose.position
    assert math.hypot(after.x - before.x, after.y - before.y) < 0.02


def test_a_failure_to_start_is_raised_by_start() -> None:
    robot = SimRos2Robot(load_plan(PLAN), domain_id=DOMAIN + 1, interface="no-such-interface0")
    with pytest.raises(Exception, match=r"cyclonedds\.domain\.Domain"):  # no such interface
        robot.start()
    assert not robot.running
