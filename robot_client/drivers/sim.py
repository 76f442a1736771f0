"""The ``sim`` driver: a simulated robot in a simulated home, behind the agent's interface.

``teachrepeat robot run --driver sim`` opens a plan's home (``--sim-plan FILE``, default the
shipped apartment) in MuJoCo and puts a :class:`~robot_client.sim.robot.SimulatedRobot` at a
place of it (``--sim-start PLACE``, default the plan's first place) or at a pose
(``--sim-pose X Y THETA``), so the whole flow (teach by driving from the dashboard, then go)
can be tried without hardware. The server sees what it would see from a real robot: frames,
odometry and ranges; the simulator's truth stays here.

The robot's clock is simulated (:class:`SimClock`): time stands still while the agent waits
for an answer, so a slow server never makes it drive further on a command than its
time-to-live (kept in simulated time by the agent, ``RobotIO.simulated``). Its steps are paced
to the wall clock (``--sim-speed``, default 1: real time) so that a person driving it from the
dashboard sees it move as a real robot would.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import TYPE_CHECKING

from robot_client.drivers import DriverError
from robot_client.drivers.base import RobotIO

if TYPE_CHECKING:
    from robot_client.sim.robot import SimulatedRobot

CATCH_UP_S = 0.25
"""A simulated clock this far behind the wall clock (the loop was held up, e.g. while the
server was away) stops trying to catch up: it carries on from now, never in a burst."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from robot_client.sim.floorplan import CONDITIONS

    group = parser.add_argument_group(
        "sim driver (--driver sim)", "a simulated robot in a simulated home (MuJoCo, OSMesa)"
    )
    group.add_argument(
        "--sim-plan",
        type=Path,
        default=None,
        metavar="FILE",
        help="floor plan JSON of the home (default: the shipped apartment)",
    )
    group.add_argument(
        "--sim-condition",
        choices=CONDITIONS,
        default="same",
        help="the home as planned, with other lighting, or with furniture moved",
    )
    group.add_argument("--sim-seed", type=int, default=0, help="seed of the robot's noise")
    group.add_argument(
        "--sim-start",
        metavar="PLACE",
        default=None,
        help="start at this place of the plan, facing its way (default: the first place)",
    )
    group.add_argument(
        "--sim-pose",
        nargs=3,
        type=float,
        default=None,
        metavar=("X", "Y", "THETA"),
        help="start at this pose instead: metres, metres, radians",
    )
    group.add_argument(
        "--sim-speed",
        type=float,
        default=1.0,
        metavar="FACTOR",
        help="simulated seconds per wall-clock second (default 1: real time; 0: as fast as "
        "the loop runs)",
    )


class SimClock:
    """The simulated robot's clock, paced to the wall clock.

    :meth:`sleep` advances the simulation (the robot executes its current command), then waits
    until the wall clock has caught up with ``speed`` simulated seconds per second (no wait
    with ``speed`` 0)."""

    def __init__(self, robot: SimulatedRobot, *, speed: float = 1.0) -> None:
        if speed < 0:
            raise ValueError("speed must be >= 0")
        self.robot = robot
        self.speed = speed
        self._anchor: tuple[float, float] | None = None  # (simulated, wall) seconds

    def now(self) -> float:
        return self.robot.now()

    def sleep(self, seconds: float) -> None:
        if self._anchor is None:
            self._anchor = (self.robot.now(), time.monotonic())
        self.robot.sleep(seconds)
        if self.speed <= 0:
            return
        sim0, wall0 = self._anchor
        due = wall0 + (self.robot.now() - sim0) / self.speed
        late = time.monotonic() - due
        if late > CATCH_UP_S:  # held up: carry on from now
            self._anchor = (self.robot.now(), time.monotonic())
        elif late < 0:
            time.sleep(-late)


def open_robot(args: argparse.Namespace) -> RobotIO:
    """The simulated home and the robot in it, at its start."""
    from robot_client.sim.floorplan import PlanError, load_plan
    from robot_client.sim.robot import SimulatedRobot
    from robot_client.sim.world import Pose, SimWorld

    if args.sim_speed < 0:
        raise DriverError(f"--sim-speed {args.sim_speed}: give 0 or more (1 = real time)")
    try:
        plan = load_plan(args.sim_plan)
    except PlanError as exc:
        raise DriverError(f"--sim-plan: {exc}") from None
    if args.sim_pose is not None:
        pose = Pose(*args.sim_pose)
    else:
        try:
            place = plan.place(args.sim_start) if args.sim_start else plan.places[0]
        except KeyError as exc:
            raise DriverError(f"--sim-start: {exc.args[0]}") from None
        pose = Pose(place.x, place.y, place.yaw)
    world = SimWorld(plan, condition=args.sim_condition, seed=args.sim_seed)
    try:
        robot = SimulatedRobot(world, pose, seed=args.sim_seed)
    except ValueError as exc:
        world.close()
        raise DriverError(f"--sim-pose: {exc}") from None
    return RobotIO(
        camera=robot,
        motors=robot,
        clock=SimClock(robot, speed=args.sim_speed),
        depth=robot,
        closers=[world.close, robot.close],
        simulated=True,
    )
