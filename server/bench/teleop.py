"""``teachrepeat bench teleop``: how fast a person's command reaches the wheels, and how fast
the robot stops when its server disappears.

Everything on this machine, over loopback, as a deployment would run it: the real server
(``teachrepeat serve`` with its dashboard) in its own process, the robot agent in this one.

* **REST teleop latency**: the agent drives the simulated robot (``--driver sim``, the shipped
  apartment unless ``--plan``) at 10 frames/s; ``POST /robots/{robot}/teleop`` alternates a
  left and a right turn; the latency is from just before the call to the moment the agent
  gives the wheels the new command (``Motors.command``). The robot's next frame carries the
  command, so about half a frame period (50 ms) is waiting for it.
* **Key press latency** (with Chromium): the dashboard in headless Chromium; an arrow key is
  pressed (and released) with Playwright; from the key-down to the wheels turning, and from
  the key-up to the wheels stopping.
* **Stop when the server disappears**: a wall-clock robot (:class:`FakeBase`: hardware we do
  not have, behind the same interfaces, its motors guarded by the agent's watchdog) is driven
  by teleop; the server is killed (SIGKILL: its sockets close) or frozen (SIGSTOP: a hung
  server or a dead link, nothing answers and nothing closes); from the signal to the wheels'
  stop. Targets: within the commands' time-to-live (0.3 s).

Target: teleop p50 <= 100 ms on loopback.
"""

from __future__ import annotations

import argparse
import contextlib
import random
import signal
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from server.bench.common import stats, write_json

if TYPE_CHECKING:
    from robot_client.agent import Agent
    from robot_client.drivers.base import Motors, RobotIO


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--trials", type=int, default=40, help="teleop calls timed (40)")
    parser.add_argument("--keys", type=int, default=20, help="key presses timed (20)")
    parser.add_argument(
        "--gone-trials", type=int, default=5, help="server kills and freezes, each (5)"
    )
    parser.add_argument(
        "--plan", type=Path, default=None, help="home of the sim robot (default: the apartment)"
    )
    parser.add_argument("--chromium", default=None, help="Chromium executable (key presses)")
    parser.add_argument("--no-browser", action="store_true", help="no key press latency")
    parser.add_argument("--json", type=Path, default=None, help="write the results here")


# --- robots ------------------------------------------------------------------------------------


@dataclass
class Change:
    """The wheels were given a new command: when (monotonic s) and what."""

    at: float
    v: float
    w: float


@dataclass
class RecordingMotors:
    """``Motors`` that note every change of command (monotonic time) before passing it on."""

    motors: Motors
    changes: list[Change] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)
    now: tuple[float, float] = (0.0, 0.0)

    def _note(self, v: float, w: float) -> None:
        with self.lock:
            if (v, w) != self.now:
                self.changes.append(Change(time.monotonic(), v, w))
                self.now = (v, w)

    def command(self, v: float, w: float) -> None:
        self._note(v, w)
        self.motors.command(v, w)

    def stop(self) -> None:
        self._note(0.0, 0.0)
        self.motors.stop()

    def odometry(self) -> tuple[float, float]:
        return self.motors.odometry()

    def wait(self, check: Callable[[Change], bool], after: int, timeout_s: float) -> Change:
        """The first change from index ``after`` on that passes ``check``."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                found = next((c for c in self.changes[after:] if check(c)), None)
            if found is not None:
                return found
            time.sleep(0.001)
        raise TimeoutError("the wheels were not given the command in time")


class WallClock:
    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(max(0.0, seconds))


class FakeBase:
    """A wall-clock robot for what we do not have here (a camera, a motor controller): a
    fixed textured frame, motors that keep what they are told (odometry reports it). Behind
    the driver Protocols, so the agent treats it as hardware: its watchdog guards it."""

    def __init__(self, seed: int = 0) -> None:
        rng = np.random.default_rng(seed)
        small = rng.integers(0, 255, (30, 40, 3), dtype=np.uint8)
        self.image = np.repeat(np.repeat(small, 8, axis=0), 8, axis=1)
        self.v = self.w = 0.0

    def read(self) -> np.ndarray:
        return self.image

    def close(self) -> None:
        pass

    def command(self, v: float, w: float) -> None:
        self.v, self.w = v, w

    def stop(self) -> None:
        self.v = self.w = 0.0

    def odometry(self) -> tuple[float, float]:
        return self.v, self.w

    def io(self) -> tuple[RobotIO, RecordingMotors]:
        from robot_client.drivers.base import RobotIO

        motors = RecordingMotors(self)
        return RobotIO(camera=self, motors=motors, clock=WallClock(), simulated=False), motors


@contextlib.contextmanager
def running_agent(
    url: str, token: str, open_io: Callable[[], tuple[RobotIO, RecordingMotors]]
) -> Iterator[tuple[Agent, RecordingMotors, list[str]]]:
    """The robot agent in a thread (its devices opened in it: a simulator's OpenGL context
    belongs to the thread that made it); stopped on exit."""
    from robot_client.agent import AgentParams, run_agent

    ready: dict[str, Any] = {}
    lines: list[str] = []
    started = threading.Event()
    stopping = threading.Event()

    def run() -> None:
        io, motors = open_io()
        ready["motors"] = motors

        def hold(agent: Agent) -> None:
            ready["agent"] = agent
            started.set()

        try:
            run_agent(
                url, token, io, AgentParams(), log=lines.append, ready=hold, stopping=stopping
            )
        finally:
            started.set()
            io.close()

    thread = threading.Thread(target=run, name="robot-agent", daemon=True)
    thread.start()
    if not started.wait(60) or "agent" not in ready:
        raise RuntimeError(f"the agent did not start: {lines}")
    try:
        yield ready["agent"], ready["motors"], lines
    finally:
        stopping.set()
        thread.join(timeout=15)


def sim_io(plan: Path | None) -> tuple[RobotIO, RecordingMotors]:
    from robot_client.drivers import sim as sim_driver

    args = argparse.Namespace(
        sim_plan=plan, sim_condition="same", sim_seed=0, sim_start=None, sim_pose=None, sim_speed=1
    )
    io = sim_driver.open_robot(args)
    motors = RecordingMotors(io.motors)
    io.motors = motors
    return io, motors


def wait_connected(url: str, token: str, robot: str = "rover", timeout_s: float = 30.0) -> None:
    from robot_client.client import TeachRepeatClient

    deadline = time.monotonic() + timeout_s
    with TeachRepeatClient(url, token) as client:
        while time.monotonic() < deadline:
            control = client.state(robot).control
            if control is not None and control.connected:
                return
            time.sleep(0.1)
    raise RuntimeError("the agent never connected")


# --- measurements ----------------------------------------------------------------------------


def turning_at(w: float) -> Callable[[Change], bool]:
    """A change that turns at exactly ``w`` rad/s."""
    return lambda c: c.w == w


def turning_toward(sign: float) -> Callable[[Change], bool]:
    """A change that turns the way of ``sign`` (left positive)."""
    return lambda c: c.w * sign > 0


def rest_latency(url: str, token: str, motors: RecordingMotors, trials: int) -> list[float]:
    """Seconds from a teleop call to the wheels' new command, turning left and right."""
    from robot_client.client import TeachRepeatClient

    rng = random.Random(0)
    out: list[float] = []
    with TeachRepeatClient(url, token) as client:
        for k in range(trials):
            w = 0.5 if k % 2 == 0 else -0.5
            after = len(motors.changes)
            sent = time.monotonic()
            client.teleop("rover", 0.0, w, ttl_s=2.0)
            change = motors.wait(turning_at(w), after, 5.0)
            out.append(change.at - sent)
            time.sleep(rng.uniform(0.1, 0.3))  # at a random moment of the frame period
        client.teleop("rover", 0.0, 0.0)
    return out


def key_latency(
    dashboard: str, motors: RecordingMotors, presses: int, chromium: str
) -> tuple[list[float], list[float]]:
    """Seconds from a key-down to the wheels turning and from the key-up to their stop."""
    from web.bench import headless_browser

    rng = random.Random(1)
    down: list[float] = []
    up: list[float] = []
    with headless_browser(dashboard, executable=chromium) as page:
        page.get_by_role("button", name="◀ Left").wait_for(timeout=60_000)
        time.sleep(1.0)
        for k in range(presses):
            key, sign = ("ArrowLeft", 1.0) if k % 2 == 0 else ("ArrowRight", -1.0)
            after = len(motors.changes)
            pressed = time.monotonic()
            page.keyboard.down(key)
            change = motors.wait(turning_toward(sign), after, 5.0)
            down.append(change.at - pressed)
            time.sleep(rng.uniform(0.3, 0.6))
            after = len(motors.changes)
            released = time.monotonic()
            page.keyboard.up(key)
            change = motors.wait(lambda c: c.w == 0.0 and c.v == 0.0, after, 5.0)
            up.append(change.at - released)
            time.sleep(rng.uniform(0.2, 0.4))
    return down, up


def stop_when_gone(kind: str, *, db: Path) -> dict[str, float]:
    """Drive a wall-clock robot by teleop, then kill (``"kill"``) or freeze (``"stop"``) its
    server: seconds from the signal to the wheels' stop, and how long the last command had
    left when the server went."""
    from robot_client.client import TeachRepeatClient
    from server.process import start_server

    server = start_server(db)
    try:
        token = server.register_robot("rover")
        with running_agent(server.url, token, FakeBase().io) as (agent, motors, _):
            wait_connected(server.url, token)
            with TeachRepeatClient(server.url, token) as client:
                client.teleop("rover", 0.2, 0.0, ttl_s=2.0)
                motors.wait(lambda c: c.v == 0.2, 0, 5.0)
                time.sleep(random.Random(len(kind)).uniform(0.3, 0.6))
                client.teleop("rover", 0.2, 0.0, ttl_s=2.0)  # it keeps driving
            time.sleep(0.25)
            after = len(motors.changes)
            gone = time.monotonic()
            if kind == "kill":
                server.kill()
            else:
                server.proc.send_signal(signal.SIGSTOP)
            stopped = motors.wait(lambda c: c.v == 0.0, after, 5.0)
            return {"stop_s": stopped.at - gone, "unreachable": agent.stats.unreachable}
    finally:
        with contextlib.suppress(ProcessLookupError):
            server.proc.send_signal(signal.SIGCONT)
        server.stop()


def run(args: argparse.Namespace) -> int:
    from server.process import start_server
    from web.bench import CHROMIUM

    plan = args.plan
    result: dict[str, Any] = {"plan": str(plan or "apartment (shipped)"), "rate_hz": 10.0}
    with tempfile.TemporaryDirectory() as tmp:
        server = start_server(Path(tmp) / "teleop.sqlite", dashboard=not args.no_browser)
        try:
            token = server.register_robot("rover")
            with running_agent(server.url, token, lambda: sim_io(plan)) as (agent, motors, _):
                wait_connected(server.url, token)
                rest = rest_latency(server.url, token, motors, args.trials)
                result["rest_latency_ms"] = stats([x * 1000 for x in rest])
                print(f"REST teleop -> wheels: {fmt(result['rest_latency_ms'])}")
                chromium = args.chromium or CHROMIUM
                if not args.no_browser and server.dashboard_url and Path(chromium).exists():
                    down, up = key_latency(server.dashboard_url, motors, args.keys, chromium)
                    result["key_down_latency_ms"] = stats([x * 1000 for x in down])
                    result["key_up_latency_ms"] = stats([x * 1000 for x in up])
                    print(f"key down -> wheels turn: {fmt(result['key_down_latency_ms'])}")
                    print(f"key up -> wheels stop: {fmt(result['key_up_latency_ms'])}")
                result["late_answers"] = agent.stats.late
        finally:
            server.stop()
        for kind in ("kill", "stop"):
            runs = [
                stop_when_gone(kind, db=Path(tmp) / f"{kind}{k}.sqlite")
                for k in range(args.gone_trials)
            ]
            stops = [r["stop_s"] * 1000 for r in runs]
            name = {"kill": "SIGKILL", "stop": "SIGSTOP"}[kind]
            result[f"stop_after_{kind}_ms"] = {**stats(stops), "max": max(stops, default=0.0)}
            print(f"server {name} -> wheels stop: {fmt(result[f'stop_after_{kind}_ms'])}")
    result["targets"] = {
        "rest_p50_ms<=100": result["rest_latency_ms"]["p50"] <= 100,
        "key_down_p50_ms<=100": result.get("key_down_latency_ms", {}).get("p50", 1e9) <= 100,
        "killed_stop_within_ttl_300ms": result["stop_after_kill_ms"]["max"] <= 300,
        # a frozen server: at the deadline of the last answered command, sent before the freeze
        "frozen_stop_within_ttl_300ms": result["stop_after_stop_ms"]["max"] <= 300,
    }
    write_json(args.json, result)
    return 0


def fmt(s: dict[str, float]) -> str:
    extra = f", max {s['max']:.0f}" if "max" in s else ""
    return f"p50 {s['p50']:.0f} ms, p95 {s['p95']:.0f} ms{extra} (n={s['n']})"
