"""The simulated robot: Protocols, determinism, walls that stop it, odometry, kidnapping."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import pytest

from robot_client.drivers.base import Camera, Clock, DepthSensor, Motors
from robot_client.sim.floorplan import FloorPlan, load_plan
from robot_client.sim.paths import follow, shortest_path, spin, turn_to
from robot_client.sim.robot import RobotParams, SimulatedRobot
from robot_client.sim.world import Pose, SimWorld


@pytest.fixture(scope="module")
def plan() -> FloorPlan:
    return load_plan()


@pytest.fixture(scope="module")
def world(plan: FloorPlan) -> Iterator[SimWorld]:
    with SimWorld(plan) as w:
        yield w


def _start(plan: FloorPlan, name: str = "living room") -> Pose:
    p = plan.place(name)
    return Pose(p.x, p.y, p.yaw)


def test_implements_the_driver_protocols(world: SimWorld, plan: FloorPlan) -> None:
    robot = SimulatedRobot(world, _start(plan))
    for proto in (Camera, Motors, DepthSensor, Clock):
        assert isinstance(robot, proto)
    frame = robot.read()
    assert frame is not None and frame.shape == (240, 320, 3) and frame.dtype == np.uint8
    assert robot.profile().dtype == np.float32
    robot.close()
    robot.close()
    assert robot.read() is None


def _drive(robot: SimulatedRobot, frames: bool) -> tuple[list[Pose], list[np.ndarray]]:
    poses: list[Pose] = []
    images: list[np.ndarray] = []
    for k in range(40):
        robot.command(0.4, 0.6 * math.sin(k / 5))
        robot.sleep(0.1)
        poses.append(robot.pose)
        if frames and k % 10 == 0:
            frame = robot.read()
            assert frame is not None
            images.append(frame)
    return poses, images


def test_same_seed_same_commands_same_poses_and_frames(world: SimWorld, plan: FloorPlan) -> None:
    a = SimulatedRobot(world, _start(plan), seed=5)
    b = SimulatedRobot(world, _start(plan), seed=5)
    pa, fa = _drive(a, frames=True)
    pb, fb = _drive(b, frames=True)
    assert pa == pb
    assert all(np.array_equal(x, y) for x, y in zip(fa, fb, strict=True))
    assert a.odometry() == b.odometry()
    c = SimulatedRobot(world, _start(plan), seed=6)
    pc, _ = _drive(c, frames=False)
    assert pc != pa  # the seed matters (actuation noise)


def test_reseeding_makes_what_follows_independent_of_what_came_before(
    world: SimWorld, plan: FloorPlan
) -> None:
    a = SimulatedRobot(world, _start(plan), seed=5)
    b = SimulatedRobot(world, _start(plan), seed=9)
    _drive(b, frames=False)  # b has a different past
    for r in (a, b):
        r.teleport(_start(plan))
        r.reseed(7)
    pa, fa = _drive(a, frames=True)
    pb, fb = _drive(b, frames=True)
    assert pa == pb
    assert all(np.array_equal(x, y) for x, y in zip(fa, fb, strict=True))


def test_full_speed_into_a_wall_never_crosses_it(world: SimWorld, plan: FloorPlan) -> None:
    params = RobotParams()
    # bedroom, heading straight west into the outer wall (inner surface x = 0.06), then
    # diagonally into the wall shared with the guest room (x = 3.0), in big and small steps
    for heading, dt in ((math.pi, 0.1), (0.3, 0.1), (0.3, 5.0), (-math.pi / 2 + 0.2, 0.5)):
        robot = SimulatedRobot(world, Pose(1.9, 6.5, heading), params=params)
        for _ in range(40):
            robot.command(params.max_v, 0.0)
            robot.sleep(dt)
            p = robot.pose
            assert not world.collides(p.x, p.y, params.radius_m - 1e-6)
            assert plan.room_at(p.x, p.y) is not None
            assert plan.room_at(p.x, p.y).name in ("bedroom", "corridor")  # type: ignore[union-attr]
        assert robot.blocked_time > 0


def test_blocked_robot_reports_no_forward_motion(world: SimWorld, plan: FloorPlan) -> None:
    robot = SimulatedRobot(world, Pose(1.5, 0.5, -math.pi / 2))  # 0.44 m from a wall, facing it
    robot.command(0.5, 0.0)
    robot.sleep(3.0)
    robot.odometry()
    robot.sleep(2.0)
    v, w = robot.odometry()
    assert abs(v) < 0.01 and abs(w) < 1e-9


def test_odometry_is_noisy_but_close(world: SimWorld, plan: FloorPlan) -> None:
    robot = SimulatedRobot(world, Pose(2.0, 4.75, 0.0), seed=3)
    vs = []
    for _ in range(20):
        robot.command(0.3, 0.0)
        robot.sleep(0.2)
        vs.append(robot.odometry()[0])
    assert np.mean(vs) == pytest.approx(0.3, rel=0.08)
    assert np.std(vs) > 0.001
    assert robot.odometer == pytest.approx(0.3 * 4.0, rel=0.1)
    assert robot.now() == pytest.approx(4.0)


def test_commands_are_clipped_to_the_limits(world: SimWorld, plan: FloorPlan) -> None:
    params = RobotParams(actuation_noise=0.0)
    robot = SimulatedRobot(world, Pose(2.0, 4.75, 0.0), params=params)
    robot.command(10.0, 0.0)
    robot.sleep(1.0)
    assert robot.pose.x == pytest.approx(2.0 + params.max_v)
    robot.command(0.0, -10.0)
    robot.sleep(0.5)
    assert robot.pose.theta == pytest.approx(-params.max_w * 0.5)


def test_teleport_kidnaps_without_odometry(world: SimWorld, plan: FloorPlan) -> None:
    robot = SimulatedRobot(world, _start(plan))
    robot.command(0.2, 0.0)
    robot.teleport(_start(plan, "office"))
    assert robot.pose == _start(plan, "office")
    robot.sleep(1.0)
    assert robot.pose == _start(plan, "office")  # motors were stopped
    assert robot.odometry() == (0.0, 0.0)
    with pytest.raises(ValueError, match="overlaps"):
        robot.teleport(Pose(3.0, 1.0, 0.0))
    with pytest.raises(ValueError, match="overlaps"):
        SimulatedRobot(world, Pose(-5.0, 0.0, 0.0))


def test_scripted_guide_follows_a_path_spins_and_turns(world: SimWorld, plan: FloorPlan) -> None:
    a, b = plan.place("bedroom"), plan.place("bathroom")
    robot = SimulatedRobot(world, Pose(a.x, a.y, a.yaw), seed=2)
    path = shortest_path(world, (a.x, a.y), (b.x, b.y))
    steps = list(follow(robot, path))
    assert steps[-1].done and not steps[-1].failed
    assert math.dist((robot.pose.x, robot.pose.y), (b.x, b.y)) < 0.1
    assert robot.blocked_time == 0.0
    spun = list(spin(robot, turns=1.0))
    assert spun[-1].done and sum(abs(s.w) * 0.1 for s in spun) == pytest.approx(2 * math.pi, 0.05)
    list(turn_to(robot, b.yaw))
    assert abs(math.remainder(robot.pose.theta - b.yaw, 2 * math.pi)) < 0.05
