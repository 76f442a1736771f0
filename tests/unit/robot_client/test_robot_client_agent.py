"""The robot agent's loop against a scripted server (httpx's mock transport) and fake devices.

Fakes stand for the hardware only (camera, motors, clock), behind the driver Protocols; the
server's answers are real wire schemas. A simulated clock makes the time-to-live checks exact;
the wall-clock path (the motor watchdog) is checked in real time with short deadlines.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import httpx
import numpy as np
import pytest

from robot_client.agent import Agent, AgentError, AgentParams
from robot_client.client import TeachRepeatClient
from robot_client.drivers.base import RobotIO
from server import schemas


@dataclass
class FakeClock:
    """A simulated clock: ``sleep`` advances it at once."""

    t: float = 0.0

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += max(0.0, seconds)


class WallClock:
    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(max(0.0, seconds))


@dataclass
class FakeMotors:
    """Records when its speed changes, with the clock's time; odometry says what it drove."""

    clock: Any
    log: list[tuple[float, float, float]] = field(default_factory=list)  # (t, v, w) changes
    v: float = 0.0
    w: float = 0.0

    def _set(self, v: float, w: float) -> None:
        if (v, w) != (self.v, self.w):
            self.log.append((self.clock.now(), v, w))
        self.v, self.w = v, w

    def command(self, v: float, w: float) -> None:
        self._set(v, w)

    def stop(self) -> None:
        self._set(0.0, 0.0)

    def odometry(self) -> tuple[float, float]:
        return self.v, self.w


@dataclass
class FakeCamera:
    frames: int = 10**9
    fail: bool = False

    def read(self) -> np.ndarray | None:
        if self.fail:
            raise OSError("VIDIOC_DQBUF: no such device")
        if self.frames <= 0:
            return None
        self.frames -= 1
        return np.full((48, 64, 3), 128, np.uint8)

    def close(self) -> None:
        pass


def command(v: float = 0.0, w: float = 0.0, ttl: float = 0.3, behaviour: str = "teleop") -> Any:
    return schemas.MotionCommand(
        v=v, w=w, ttl_s=ttl, action="do_nothing", behaviour=behaviour
    ).model_dump()


def idle(cmd: Any) -> dict[str, Any]:
    return {"mode": "idle", "command": cmd}


Answer = Callable[[httpx.Request], httpx.Response | dict[str, Any]]


class Server:
    """A scripted server: ``answer(request)`` per frame (a JSON body, or a response)."""

    def __init__(self, answer: Answer) -> None:
        self.answer = answer
        self.frames: list[httpx.Request] = []

    def __call__(self, request: httpx.Request) -> httpx.Response:
        if request.url.path == "/whoami":
            return httpx.Response(200, json={"kind": "robot", "robot": "rover"})
        assert request.url.path == "/robots/rover/frames", request.url
        self.frames.append(request)
        found = self.answer(request)
        return found if isinstance(found, httpx.Response) else httpx.Response(200, json=found)


def agent_for(
    server: Server,
    *,
    simulated: bool = True,
    camera: FakeCamera | None = None,
    params: AgentParams | None = None,
) -> tuple[Agent, FakeMotors, list[str]]:
    clock: Any = FakeClock() if simulated else WallClock()
    motors = FakeMotors(clock)
    io = RobotIO(camera=camera or FakeCamera(), motors=motors, clock=clock, simulated=simulated)
    client = TeachRepeatClient(
        "http://robot.test", "robot-token", transport=httpx.MockTransport(server)
    )
    lines: list[str] = []
    agent = Agent(client, "rover", io, params or AgentParams(), log=lines.append)
    return agent, motors, lines


def test_it_drives_as_told_streams_with_odometry_and_stands_when_told_to() -> None:
    answers = [idle(command(v=0.2)), idle(command(v=0.2)), idle(command(behaviour="stand"))]
    server = Server(lambda request: answers[len(server.frames) - 1])
    agent, motors, _ = agent_for(server)
    agent.run(max_frames=3)
    assert motors.log == [(0.0, 0.2, 0.0), pytest.approx((0.2, 0.0, 0.0))]
    sent = [dict(r.url.params.multi_items()) for r in server.frames]
    assert [s["stream"] for s in sent] == ["true"] * 3
    assert [float(s["timestamp"]) for s in sent] == pytest.approx([0.0, 0.1, 0.2])
    assert [float(s["v"]) for s in sent] == [0.0, 0.2, 0.2]  # odometry of the last interval
    # the pose it sends is dead-reckoned from its odometry: 0.1 s at 0.2 m/s
    poses = [[float(x) for x in r.url.params.get_list("pose")] for r in server.frames]
    assert poses[1] == pytest.approx([0.02, 0.0, 0.0])
    assert poses[2] == pytest.approx([0.04, 0.0, 0.0])
    assert agent.stats.frames == 3 and agent.stats.commands == {"teleop": 2, "stand": 1}


def test_a_command_shorter_than_the_frame_period_stops_at_its_time_to_live() -> None:
    server = Server(lambda request: idle(command(v=0.3, ttl=0.04)))
    agent, motors, _ = agent_for(server)
    agent.run(max_frames=2)
    # driven at t=0 for 0.04 s, stopped, driven again at t=0.1 (the next answer), stopped
    assert motors.log == [
        (0.0, 0.3, 0.0),
        pytest.approx((0.04, 0.0, 0.0)),
        pytest.approx((0.1, 0.3, 0.0)),
        pytest.approx((0.14, 0.0, 0.0)),
    ]


def test_a_simulated_robot_waits_for_a_slow_answer_in_its_own_time() -> None:
    def slow(request: httpx.Request) -> dict[str, Any]:
        time.sleep(0.05)  # wall time: the simulated clock stands still meanwhile
        return idle(command(v=0.3, ttl=0.3))

    agent, motors, _ = agent_for(Server(slow))
    agent.run(max_frames=1)
    assert agent.stats.late == 0 and motors.log == [(0.0, 0.3, 0.0), (0.1, 0.0, 0.0)]


def test_a_late_answer_is_not_obeyed() -> None:
    def late(request: httpx.Request) -> dict[str, Any]:
        time.sleep(0.12)  # longer than the command's time-to-live
        return idle(command(v=0.3, ttl=0.1))

    agent, motors, lines = agent_for(Server(late), simulated=False)
    agent.run(max_frames=2)
    assert agent.stats.late == 2
    assert motors.log == [], motors.log  # never drove
    assert sum("later than their time-to-live" in line for line in lines) == 1  # said once


def test_a_wall_clock_robot_stops_at_the_deadline_when_the_next_answer_hangs() -> None:
    """The watchdog, not the loop, stops the base: the loop is stuck in the request."""
    hang = threading.Event()

    def answer(request: httpx.Request) -> dict[str, Any]:
        if hang.is_set():
            time.sleep(0.6)
        hang.set()
        return idle(command(v=0.3, ttl=0.2))

    params = AgentParams(rate_hz=10.0, answer_timeout_s=1.0)
    agent, motors, _ = agent_for(Server(answer), simulated=False, params=params)
    agent.run(max_frames=2)
    (start, v, _), (stop, after, _) = motors.log[:2]
    # stopped 0.2 s after the frame was sent (a little less after the command came)
    assert v == 0.3 and after == 0.0 and 0.1 <= stop - start <= 0.2 + 0.03, motors.log


def test_when_the_server_is_gone_it_stops_at_once_says_so_once_and_says_when_it_is_back() -> None:
    gone = {"n": 0}

    def answer(request: httpx.Request) -> dict[str, Any]:
        if 2 <= len(server.frames) <= 4:
            gone["n"] += 1
            raise httpx.ConnectError("[Errno 111] Connection refused")
        return idle(command(v=0.2, ttl=0.3))

    server = Server(answer)
    agent, motors, lines = agent_for(server)
    agent.run(max_frames=2)
    assert gone["n"] == 3 and agent.stats.unreachable == 3
    # driving after the first answer, stopped at the first failure, driving again after
    drives = [(round(t, 2), v) for t, v, _ in motors.log]
    assert drives[:3] == [(0.0, 0.2), (0.1, 0.0), (3.6, 0.2)], drives
    said = [line for line in lines if "server" in line]
    assert len(said) == 2 and said[0].startswith("server unreachable (ConnectError")
    assert said[1].startswith("server back after")
    # it waited 0.5, 1 then 2 s between tries (the backoff), standing
    times = [float(dict(r.url.params.multi_items())["timestamp"]) for r in server.frames]
    assert np.diff(times) == pytest.approx([0.1, 0.5, 1.0, 2.0])


def test_a_refused_token_ends_the_agent_saying_what_to_do() -> None:
    refused = httpx.Response(401, json={"detail": "the bearer token is not valid", "code": "x"})
    agent, motors, _ = agent_for(Server(lambda request: refused))
    with pytest.raises(AgentError, match=r"refused the token \(401.*--token-file"):
        agent.run()
    assert motors.log == []


def test_another_robots_name_ends_the_agent() -> None:
    refused = httpx.Response(403, json={"detail": "this token belongs to robot 'scout'"})
    agent, _, _ = agent_for(Server(lambda request: refused))
    with pytest.raises(AgentError, match="that robot's own token"):
        agent.run()


def test_a_refused_frame_stands_says_why_once_and_goes_on() -> None:
    def answer(request: httpx.Request) -> httpx.Response | dict[str, Any]:
        if len(server.frames) < 3:
            return httpx.Response(409, json={"detail": "busy", "code": "conflict"})
        return idle(command(v=0.1))

    server = Server(answer)
    agent, motors, lines = agent_for(server)
    agent.run(max_frames=1)
    assert agent.stats.refused == 2 and motors.log[0] == pytest.approx((0.2, 0.1, 0.0))
    assert [line for line in lines if "refused" in line] == [
        "frame refused (409: busy); the robot stands"
    ]


def test_timestamps_move_on_after_those_the_server_holds() -> None:
    """A restarted robot's clock starts again; the server refuses going back in time."""

    def answer(request: httpx.Request) -> httpx.Response | dict[str, Any]:
        t = float(dict(request.url.params.multi_items())["timestamp"])
        if t < 500.0:
            detail = f"timestamp {t} goes backwards: the previous frame was at 500.25. Send..."
            return httpx.Response(422, json={"detail": detail, "code": "invalid"})
        return idle(command())

    server = Server(answer)
    agent, _, lines = agent_for(server)
    agent.run(max_frames=2)
    times = [float(dict(r.url.params.multi_items())["timestamp"]) for r in server.frames]
    assert times[0] == 0.0 and times[1] == pytest.approx(500.35) and times[2] > times[1]
    assert any("timestamps moved on" in line for line in lines)


def test_a_failing_camera_stops_the_robot_and_ends_the_agent_after_a_while() -> None:
    camera = FakeCamera(fail=True)
    agent, motors, lines = agent_for(
        Server(lambda request: idle(command(v=0.2))),
        camera=camera,
        params=AgentParams(camera_failures=5),
    )
    with pytest.raises(AgentError, match=r"no frame 5 times in a row.*VIDIOC_DQBUF"):
        agent.run()
    assert agent.stats.camera_failures == 5 and motors.log == []
    assert lines == ["camera: OSError: VIDIOC_DQBUF: no such device; the robot stands until it "
                     "gives frames again"]  # fmt: skip


def test_it_says_when_the_mode_changes() -> None:
    task = {"id": 7, "tour": 1, "goal": "there", "started_at": 0.0, "steps": 1}
    belief = {"top": [], "entropy": 0.0, "localised": False}
    nav = {"mode": "navigating", "belief": belief, "votes": {}}
    answers = [
        idle(command(behaviour="stand")),
        {"mode": "teaching", "open_path_images": 0, "command": command(behaviour="stand")},
        {**nav, "command": command(v=0.2), "task": {**task, "state": "underway"}},
        {**nav, "command": command(v=0.2), "task": {**task, "state": "underway"}},
        {**nav, "command": command(), "task": {**task, "state": "arrived"}},
    ]
    server = Server(lambda request: answers[len(server.frames) - 1])
    agent, _, lines = agent_for(server)
    agent.run(max_frames=5)
    assert lines == [
        "mode: idle",
        "mode: teaching",
        "navigating to 'there' (task 7)",
        "task 7 to 'there': arrived",
        "mode: idle",
    ]
