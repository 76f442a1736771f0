"""The ``sim`` driver: a plan's simulated home behind the agent's interface."""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import pytest

from robot_client.drivers import DRIVERS, DriverError
from robot_client.drivers import sim as sim_driver
from robot_client.sim import load_plan
from robot_client.sim.robot import SimulatedRobot
from robot_client.sim.world import PlanGeometry, Pose

PLAN = Path(__file__).resolve().parents[2] / "data" / "plans" / "two_rooms.json"


def options(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    sim_driver.add_arguments(parser)
    return parser.parse_args(["--sim-plan", str(PLAN), *argv])


def test_it_is_registered_and_its_options_carry_its_name() -> None:
    assert DRIVERS["sim"] == "robot_client.drivers.sim"
    parser = argparse.ArgumentParser()
    sim_driver.add_arguments(parser)
    flags = [a.option_strings[0] for a in parser._actions if a.option_strings[0] != "-h"]
    assert flags and all(f.startswith("--sim-") for f in flags), flags


def test_it_opens_the_home_with_the_robot_at_a_place_facing_its_way() -> None:
    io = sim_driver.open_robot(options("--sim-start", "sofa"))
    try:
        robot = io.camera
        assert isinstance(robot, SimulatedRobot) and io.motors is robot and io.depth is robot
        assert io.simulated and isinstance(io.clock, sim_driver.SimClock)
        sofa = load_plan(PLAN).place("sofa")
        assert robot.pose == Pose(sofa.x, sofa.y, sofa.yaw)
        frame = robot.read()
        assert frame is not None and frame.shape == (240, 320, 3)
        assert len(io.depth.profile()) > 8  # type: ignore[union-attr]
    finally:
        io.close()
    assert robot.read() is None  # closed


def test_the_start_is_the_first_place_or_a_pose() -> None:
    first = load_plan(PLAN).places[0]
    io = sim_driver.open_robot(options())
    try:
        assert io.camera.pose == Pose(first.x, first.y, first.yaw)  # type: ignore[attr-defined]
    finally:
        io.close()
    io = sim_driver.open_robot(options("--sim-pose", "2.5", "1.0", "0.5"))
    try:
        assert io.camera.pose == Pose(2.5, 1.0, 0.5)  # type: ignore[attr-defined]
    finally:
        io.close()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (("--sim-start", "attic"), "--sim-start: no place 'attic'; places are: desk, sofa"),
        (("--sim-pose", "0.1", "0.1", "0"), "--sim-pose: pose (0.10, 0.10) overlaps a wall"),
        (("--sim-speed", "-1"), "--sim-speed -1.0: give 0 or more"),
    ],
)
def test_a_bad_start_says_what_to_fix(argv: tuple[str, ...], message: str) -> None:
    with pytest.raises(DriverError) as caught:
        sim_driver.open_robot(options(*argv))
    assert str(caught.value).startswith(message), caught.value


def test_a_missing_plan_says_so(tmp_path: Path) -> None:
    args = options()
    args.sim_plan = tmp_path / "nowhere.json"
    with pytest.raises(DriverError, match=r"--sim-plan: floor plan .*nowhere.json not found"):
        sim_driver.open_robot(args)


def robot() -> SimulatedRobot:
    plan = load_plan(PLAN)
    desk = plan.place("desk")
    return SimulatedRobot(PlanGeometry(plan), Pose(desk.x, desk.y, desk.yaw))


def test_its_clock_runs_the_simulation_paced_to_the_wall_clock() -> None:
    bot = robot()
    clock = sim_driver.SimClock(bot, speed=2.0)
    bot.command(0.0, 1.0)
    started = time.monotonic()
    for _ in range(5):
        clock.sleep(0.1)
    wall = time.monotonic() - started
    assert clock.now() == pytest.approx(0.5)
    assert bot.pose.theta == pytest.approx(desk_yaw() + 0.5 - 2 * math.pi, abs=0.05)
    # 0.5 simulated seconds at twice real time take at least 0.2 s (the first step is free);
    # the upper bound is loose: a loaded machine may be slower than the pace, never faster
    assert 0.2 <= wall <= 2.0, wall


def desk_yaw() -> float:
    return load_plan(PLAN).place("desk").yaw


def test_as_fast_as_possible_and_no_catching_up_after_a_stall() -> None:
    bot = robot()
    fast = sim_driver.SimClock(bot, speed=0.0)
    started = time.monotonic()
    for _ in range(100):
        fast.sleep(0.1)
    assert time.monotonic() - started < 1.0 and bot.now() == pytest.approx(10.0)
    paced = sim_driver.SimClock(bot, speed=1.0)
    paced.sleep(0.1)
    time.sleep(0.5)  # held up (e.g. the server was away)
    started = time.monotonic()
    for _ in range(3):
        paced.sleep(0.1)
    assert time.monotonic() - started >= 0.15  # carries on at real time, not in a burst
