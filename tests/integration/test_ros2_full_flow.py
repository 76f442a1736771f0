"""The whole flow on a ROS 2 robot: a tour taught by teleop over REST, then "go to" a place.

Every part is real and runs as it would with a robot: the simulated ROS 2 robot
(:class:`~robot_client.sim.ros2_robot.SimRos2Robot`: the simulator's frames, odometry and
scan with ROS 2's message types on loopback DDS, obeying ``cmd_vel``) stands in the two-room
home; the server (``teachrepeat serve``) and the robot agent (``teachrepeat robot run
--driver ros2``, its token in a file) are processes of their own, and the agent knows the robot
by its DDS topics only. This test is the person with a phone: logged into the household, it
starts teaching, names the place where the robot stands (the server spins the robot there),
drives it through the door to the other place with ``POST /robots/{robot}/teleop``, names that
place, drives back and names the first place again, finishes, then says "go to" the other
place and judges, against the simulator's truth, that the robot arrives within 0.5 m of it.

The person steers by looking at the robot: the test reads the simulator's true pose to choose
its teleop commands, as eyes would. The truth goes nowhere else: the server gets only what the
agent sends, and the agent gets only what the robot publishes.
"""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

from robot_client.client import ApiError, TeachRepeatClient
from robot_client.sim.floorplan import Place, load_plan
from robot_client.sim.ros2_robot import SimRos2Robot
from robot_client.sim.world import Pose
from robot_client.trial import SUCCESS_RADIUS_M
from server.process import ServerProcess, start_server

ROOT = Path(__file__).resolve().parents[2]
PLAN = ROOT / "tests" / "data" / "plans" / "two_rooms.json"
DOMAIN = 20 + (os.getpid() + 10) % 180
"""This run's ROS 2 domain (apart from test_ros2_loopback's five, and from other runs)."""
NUMBER = re.compile(r"[-+]?[0-9]+(?:\.[0-9]+)?")
ROBOT = "rover"
PASSWORD = "correct horse battery"
SETTINGS = {"TEACHREPEAT_SPIN_W": "1.2"}
"""A quicker spin at a new place than the default 0.6 rad/s (one turn in 5.2 s)."""
SPEED = 0.3  # m/s, driving by hand (the teleop limit; the scripted guide teaches at it)
TURN = 0.8  # rad/s at most, turning by hand
TELEOP_EVERY_S = 0.2  # the phone repeats the held command this often...
TELEOP_TTL_S = 0.5  # ...each living this long (a dead man's switch)
NAVIGATION_TIMEOUT_S = 180.0
"""Wall-clock seconds "go to" may take before the test gives up (about 30 s on a quiet
machine): generous, for a loaded one."""


@dataclass
class Agent:
    """``teachrepeat robot run --driver ros2`` in a process of its own."""

    proc: subprocess.Popen[bytes]
    log: Path

    def tail(self, lines: int = 15) -> str:
        text = self.log.read_text(errors="replace") if self.log.exists() else ""
        return "\n".join(text.splitlines()[-lines:])


@pytest.fixture()
def server(tmp_path: Path) -> Iterator[ServerProcess]:
    proc = start_server(tmp_path / "ros2flow.sqlite", extra_env=SETTINGS)
    yield proc
    proc.stop()


@pytest.fixture()
def sim() -> Iterator[SimRos2Robot]:
    """The ROS 2 robot, standing at the plan's first place."""
    with SimRos2Robot(load_plan(PLAN), domain_id=DOMAIN, seed=3) as robot:
        yield robot


@pytest.fixture()
def phone(server: ServerProcess) -> Iterator[TeachRepeatClient]:
    """The person's phone: logged into the household the robot belongs to."""
    admin = {"Authorization": f"Bearer {server.admin_token}"}
    r = httpx.put(f"{server.url}/households/1/password", json={"password": PASSWORD}, headers=admin)
    assert r.status_code in (200, 204), r.text
    r = httpx.post(f"{server.url}/auth/login", json={"household": "default", "password": PASSWORD})
    assert r.status_code == 200, r.text
    with TeachRepeatClient(server.url, r.json()["token"]) as client:
        yield client


@pytest.fixture()
def agent(server: ServerProcess, sim: SimRos2Robot, tmp_path: Path) -> Iterator[Agent]:
    """The robot agent on the ROS 2 robot, with its token in a file only its user reads."""
    token = tmp_path / "rover.token"
    token.touch(mode=0o600)
    token.write_text(server.register_robot(ROBOT) + "\n")
    log = tmp_path / "agent.log"
    argv = [
        *(sys.executable, "-m", "server.cli", "robot", "run"),
        *("--server", server.url, "--token-file", str(token), "--driver", "ros2"),
        *("--ros2-domain", str(DOMAIN), "--ros2-interface", "lo"),
    ]
    env = {k: v for k, v in os.environ.items() if k != "TEACHREPEAT_ROBOT_TOKEN"}
    with log.open("wb") as out:
        proc = subprocess.Popen(argv, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT, env=env)
    try:
        yield Agent(proc, log)
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


# -- the person: eyes on the robot, thumbs on the phone -------------------------------------------


def wrap(angle: float) -> float:
    return math.atan2(math.sin(angle), math.cos(angle))


class Person:
    """Drives the robot with teleop calls, looking at where it truly is."""

    def __init__(self, phone: TeachRepeatClient, sim: SimRos2Robot, agent: Agent) -> None:
        self.phone = phone
        self.sim = sim
        self.agent = agent
        self.started = time.monotonic()
        self.doing: list[tuple[float, str, Pose]] = []  # (s, behaviour: reason, true pose)

    def say(self, what: str) -> None:
        print(f"{time.monotonic() - self.started:6.1f} s  {what}", flush=True)

    def seen(self) -> str:
        """What the robot was doing and where it was, for a failure's message."""
        p = self.sim.true_pose
        where = f"the robot truly at ({p.x:.2f}, {p.y:.2f}) heading {p.theta:.2f} rad"
        try:
            s = self.phone.state(ROBOT)
            nav = s.navigation
            last = None if nav is None else nav.last_command
            doing = (
                f"mode {s.mode}; task {None if nav is None else nav.task}; last command "
                + ("none" if last is None else f"{last.behaviour} ({last.reason})")
                + f"; control {s.control}"
            )
        except (ApiError, httpx.HTTPError) as exc:
            doing = f"state unavailable ({exc})"
        alive = "running" if self.agent.proc.poll() is None else f"exited {self.agent.proc.poll()}"
        recent = "".join(
            f"\n  {t:6.1f} s {what} at ({q.x:.2f}, {q.y:.2f}, {q.theta:.2f})"
            for t, what, q in self.doing[-12:]
        )
        if recent:
            doing += "; what it did last while navigating:" + recent
        return f"{where}; {doing}\nagent {alive}, its last lines:\n{self.agent.tail()}"

    def wait_for(
        self, what: str, check: Callable[[], bool], timeout_s: float, every_s: float = 0.25
    ) -> None:
        deadline = time.monotonic() + timeout_s
        while not check():
            if time.monotonic() > deadline:
                raise AssertionError(f"no {what} after {timeout_s:g} s: {self.seen()}")
            time.sleep(every_s)

    def navigating_ended(self) -> bool:
        """Whether the task ended; what the robot does is noted whenever it changes."""
        state = self.phone.state(ROBOT)
        nav = state.navigation
        last = None if nav is None else nav.last_command
        if last is not None:
            doing = f"{last.behaviour}: {last.reason}"
            # a new line when what it does changes, not each time a figure in it does
            if not self.doing or NUMBER.sub("#", self.doing[-1][1]) != NUMBER.sub("#", doing):
                p = self.sim.true_pose
                self.doing.append((time.monotonic() - self.started, doing, p))
                self.say(f"  {doing} at ({p.x:.2f}, {p.y:.2f}, {p.theta:.2f})")
        return state.mode != "navigating"

    def hold(self, v: float, w: float) -> None:
        self.phone.teleop(ROBOT, v, w, ttl_s=TELEOP_TTL_S)
        time.sleep(TELEOP_EVERY_S)

    def release(self) -> None:
        self.phone.teleop(ROBOT, 0.0, 0.0)
        time.sleep(0.5)  # it stands: the next look sees where it stopped

    def turn_to(self, heading: float, tol: float = 0.08) -> None:
        deadline = time.monotonic() + 40.0
        while abs(err := wrap(heading - self.sim.true_pose.theta)) > tol:
            if time.monotonic() > deadline:
                raise AssertionError(f"could not turn to {heading:.2f} rad: {self.seen()}")
            self.hold(0.0, max(-TURN, min(TURN, 1.5 * err)))
        self.release()

    def drive_to(self, x: float, y: float, within: float = 0.1) -> None:
        """Turn toward ``(x, y)`` and drive there, steering on the way, slowing near it."""
        deadline = time.monotonic() + 90.0
        while True:
            p = self.sim.true_pose
            distance = math.hypot(x - p.x, y - p.y)
            if distance <= within:
                break
            if time.monotonic() > deadline:
                raise AssertionError(f"could not reach ({x}, {y}): {self.seen()}")
            err = wrap(math.atan2(y - p.y, x - p.x) - p.theta)
            if abs(err) > 0.35 and distance > 2 * within:
                self.hold(0.0, max(-TURN, min(TURN, 1.5 * err)))  # face it first
            else:
                v = min(SPEED, 0.05 + 0.6 * distance)
                self.hold(v, max(-TURN, min(TURN, 1.5 * err)))
        self.release()

    def go_to_place(self, place: Place) -> None:
        self.drive_to(place.x, place.y)
        self.turn_to(place.yaw)
        p = self.sim.true_pose
        self.say(f"at {place.name}: ({p.x:.2f}, {p.y:.2f}) heading {p.theta:.2f}")

    def name(self, place: Place, *, new: bool) -> None:
        marked = self.phone.mark_location(ROBOT, place.name)
        assert marked.created == new, marked
        if not new:
            return

        def spun() -> bool:
            control = self.phone.state(ROBOT).control
            spin = None if control is None else control.spin
            return spin is not None and spin.place == place.name and spin.state != "spinning"

        self.wait_for(f"end of the spin at {place.name}", spun, 60.0)
        control = self.phone.state(ROBOT).control
        assert control is not None and control.spin is not None
        assert control.spin.state == "done", f"the spin: {control.spin}; {self.seen()}"
        self.say(f"named {place.name}: spun, {control.spin.images} images")


@pytest.mark.slow
@pytest.mark.timeout(600)  # the steps' own timeouts say what failed well before this
def test_a_ros2_robot_taught_by_teleop_over_rest_then_sent_to_a_place_arrives(
    server: ServerProcess, sim: SimRos2Robot, phone: TeachRepeatClient, agent: Agent
) -> None:
    plan = load_plan(PLAN)
    first, second = plan.places[0], plan.places[1]
    person = Person(phone, sim, agent)

    def connected() -> bool:
        if agent.proc.poll() is not None:
            raise AssertionError(f"the agent exited {agent.proc.poll()}:\n{agent.tail()}")
        control = phone.state(ROBOT).control
        return control is not None and control.connected

    person.wait_for("frames from the agent", connected, 60.0)
    person.say("the agent streams")

    # teach: name the place where it stands, drive through the door, name, drive back, name
    tour = phone.create_tour("home")
    phone.start_teaching(ROBOT, tour.id)
    person.wait_for("teaching mode", lambda: phone.state(ROBOT).mode == "teaching", 10.0)
    person.name(first, new=True)  # where it stands
    person.go_to_place(second)
    person.name(second, new=True)
    person.go_to_place(first)
    person.name(first, new=False)
    phone.finish_teaching(ROBOT)
    graph = phone.tour(tour.id)
    person.say(
        "finished: places "
        + ", ".join(f"{loc.name} {loc.image_count} images" for loc in graph.locations)
        + "; paths "
        + ", ".join(f"{e.source_name}->{e.target_name} {e.image_count}" for e in graph.edges)
    )
    assert sorted(loc.name for loc in graph.locations) == sorted((first.name, second.name))
    assert len(graph.edges) == 2 and all(e.image_count >= 20 for e in graph.edges), graph.edges
    # one spin image every 10 degrees of turn (fewer when frames come late on a busy machine)
    assert all(loc.image_count >= 12 for loc in graph.locations), graph.locations
    # the server holds the agent's dead reckoning (its origin where the agent started, at the
    # first place), never the simulator's frame (that place is at (first.x, first.y) there)
    at_first = next(loc for loc in graph.locations if loc.name == first.name)
    assert at_first.poses is not None
    assert math.hypot(*at_first.poses[0][:2]) < 0.05, at_first.poses[0]

    # go to the other place from where it stands
    start: Pose = sim.true_pose
    task = phone.goto(ROBOT, second.name)
    person.say(f"go to {second.name}: task {task.id}")
    ended = f"end of the task to {second.name}"
    person.wait_for(ended, person.navigating_ended, NAVIGATION_TIMEOUT_S)
    state = phone.state(ROBOT)
    ended_task = None if state.navigation is None else state.navigation.task
    p = sim.true_pose
    off = math.hypot(p.x - second.x, p.y - second.y)
    person.say(f"task ended: {ended_task}; {off:.2f} m from {second.name}")
    assert ended_task is not None and ended_task.id == task.id, person.seen()
    assert ended_task.state == "arrived", (
        f"the task to {second.name} from ({start.x:.2f}, {start.y:.2f}) ended "
        f"{ended_task.state} ({ended_task.reason}): {person.seen()}"
    )
    assert off <= SUCCESS_RADIUS_M, (
        f"arrived {off:.2f} m from {second.name} ({second.x}, {second.y}), more than "
        f"{SUCCESS_RADIUS_M} m: {person.seen()}"
    )
    assert agent.proc.poll() is None, f"the agent exited:\n{agent.tail()}"
