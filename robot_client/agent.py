"""``teachrepeat robot run``: the robot agent, one long-running loop on the robot.

It streams frames (with odometry, and ranges where the robot has a depth sensor) to the server
and obeys each answer's command within its time-to-live. It decides nothing itself: the server
decides what happens (idle, teaching, navigating), and a person runs everything from the
dashboard or the REST API. Any robot with a driver (``--driver``, :data:`DRIVERS`) runs it.

Safety (docs/robot.md, "The robot agent"):

* a command is obeyed only until the time it was asked for (the frame's request) plus its
  ``ttl_s``: an answer that comes later is dropped and the robot stands;
* a wall-clock robot's motors are guarded by a
  :class:`~robot_client.drivers.watchdog.MotorWatchdog`, which stops them at that deadline
  whatever the loop is doing (a request hanging on a dead link); a simulated robot keeps the
  deadline in its own simulated time (``RobotIO.simulated``);
* the robot stops at once when the server cannot be reached or refuses a frame, when the
  camera gives no frame, and when it is told to stand; the agent retries the server (backing
  off to ``max_retry_s``) and says once when it is gone and when it is back;
* a token the server refuses (401), a robot it does not know (404) or a certificate that is
  not the pinned one end the agent with a message saying what to fix (exit 1).
"""

from __future__ import annotations

import argparse
import importlib
import math
import re
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import httpx

from robot_client.client import ApiError, TeachRepeatClient
from robot_client.credentials import add_pinning_arguments, add_token_arguments, read_token
from robot_client.drivers import DRIVERS, DriverError
from robot_client.drivers.base import Image, RobotIO
from robot_client.drivers.watchdog import MotorWatchdog
from robot_client.pinning import UntrustedServerError
from server import schemas
from server.imaging import encode_jpeg

if TYPE_CHECKING:
    from robot_client.drivers.base import Motors


@dataclass(frozen=True)
class AgentParams:
    """The agent's loop.

    * ``rate_hz`` (10): frames per second.
    * ``jpeg_quality`` (85).
    * ``answer_timeout_s`` (2 s): how long a frame's answer is waited for; after that the
      server counts as gone (a command in force has stopped long before: its time-to-live).
    * ``retry_s`` (0.5 s, doubling to ``max_retry_s`` 2 s): the wait before trying an
      unreachable server again (the robot stands meanwhile).
    * ``camera_failures`` (50): frames in a row the camera may fail to give before the agent
      gives up (exit 1); the robot stands from the first.
    * ``watchdog_poll_s`` (0.01 s): how often a wall-clock robot's watchdog looks at the
      deadline.
    """

    rate_hz: float = 10.0
    jpeg_quality: int = 85
    answer_timeout_s: float = 2.0
    retry_s: float = 0.5
    max_retry_s: float = 2.0
    camera_failures: int = 50
    watchdog_poll_s: float = 0.01

    def __post_init__(self) -> None:
        if not self.rate_hz > 0 or not self.answer_timeout_s > 0:
            raise ValueError("rate_hz and answer_timeout_s must be positive")
        if not 1 <= self.jpeg_quality <= 100:
            raise ValueError("jpeg_quality must be within 1..100")

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz


class AgentError(RuntimeError):
    """The agent cannot go on (a refused token, an unknown robot, a dead camera): the message
    says what to fix."""


@dataclass
class AgentStats:
    """What the loop did (for logs, tests and benchmarks)."""

    frames: int = 0  # frames answered
    late: int = 0  # answers that came after their command's time-to-live
    unreachable: int = 0  # frames the server did not answer (gone, hung, refused)
    refused: int = 0  # frames the server answered with an error
    camera_failures: int = 0  # frames the camera did not give
    mode: str | None = None  # as the last answer said: idle | teaching | navigating
    commands: dict[str, int] = field(default_factory=dict)  # answers per behaviour


class Wheels:
    """The motors as the agent commands them: drive ``(v, w)`` for at most ``ttl`` seconds of
    the robot's clock, let time pass, stop.

    A wall-clock robot's motors are guarded by a :class:`MotorWatchdog` (its own thread
    stops them at the deadline, whatever the loop does); a simulated robot's clock stands still
    between steps, so the deadline is kept in its time by :meth:`wait`."""

    def __init__(self, io: RobotIO, *, poll_s: float = 0.01) -> None:
        self.io = io
        self.simulated = io.simulated
        self.expired = 0  # commands that ran out before a newer one came
        self._guard: MotorWatchdog | None = None
        if not self.simulated:
            self._guard = MotorWatchdog(io.motors, poll_s=poll_s, on_expire=self._expired)
        self._deadline: float | None = None  # simulated robots only

    def _expired(self, late_s: float) -> None:
        self.expired += 1

    @property
    def motors(self) -> Motors:
        return self.io.motors

    def drive(self, v: float, w: float, ttl_s: float) -> None:
        """Drive at ``v`` m/s and ``w`` rad/s for at most ``ttl_s`` seconds from now."""
        if ttl_s <= 0 or (v == 0 and w == 0):
            self.stop()
            return
        if self._guard is not None:
            self._guard.command(v, w, ttl_s)
            return
        self.io.motors.command(v, w)
        self._deadline = self.io.clock.now() + ttl_s

    def stop(self) -> None:
        self._deadline = None
        if self._guard is not None:
            self._guard.stop()
        else:
            self.io.motors.stop()

    def wait(self, seconds: float) -> None:
        """Let ``seconds`` of the robot's clock pass; a simulated robot stops at its
        command's deadline on the way."""
        clock = self.io.clock
        if seconds <= 0:
            return
        if self._deadline is not None:
            run = self._deadline - clock.now()
            if run < seconds:
                clock.sleep(max(0.0, run))
                self.io.motors.stop()
                self._deadline = None
                self.expired += 1
                seconds -= max(0.0, run)
        clock.sleep(seconds)

    def close(self) -> None:
        if self._guard is not None:
            self._guard.close()
        else:
            self.stop()


Log = Callable[[str], None]


def _stderr(line: str) -> None:
    print(f"{time.strftime('%H:%M:%S')} {line}", file=sys.stderr, flush=True)


BACKWARDS = re.compile(
    r"goes backwards: the previous (?:frame|image) was (?:taken )?at "
    r"([0-9]+(?:\.[0-9]+)?(?:[eE][+-]?[0-9]+)?)"
)
"""The server's refusal of a frame older than one it holds (an earlier run's frames)."""


class Agent:
    """One robot's loop: frame out, command in, obeyed within its time-to-live.

    Args:
        client: the robot's connection (its own token).
        robot: the robot's name (:meth:`TeachRepeatClient.whoami` says it).
        io: the robot's devices (a driver's ``open_robot``); not closed by the agent.
        params: the loop's parameters.
        log: where the agent says what happens (one line each; never the token).
    """

    def __init__(
        self,
        client: TeachRepeatClient,
        robot: str,
        io: RobotIO,
        params: AgentParams = AgentParams(),
        *,
        log: Log = _stderr,
    ) -> None:
        self.client = client
        self.robot = robot
        self.io = io
        self.params = params
        self.log = log
        self.stats = AgentStats()
        self.wheels = Wheels(io, poll_s=params.watchdog_poll_s)
        self.stopping = threading.Event()
        # timestamps are the robot's clock; after a restart of the robot (its clock starts
        # again) the server refuses them as going back, and they are moved on after the last
        # one it holds (_refused)
        self._offset = 0.0
        self._pose = [0.0, 0.0, 0.0]  # dead-reckoned from the odometry: x, y (m), heading (rad)
        self._last_t: float | None = None
        self._gone_since: float | None = None  # monotonic seconds
        self._retry = params.retry_s
        self._camera_failed = 0
        self._said: str | None = None  # the last refusal said (said once, not every frame)
        self._task: tuple[int, str] | None = None
        self._next_at: float | None = None

    # --- the loop -------------------------------------------------------------------------

    def run(self, *, max_frames: int | None = None) -> None:
        """Run until :meth:`stop` (or ``max_frames`` answered); the robot stands at the end.

        Raises:
            AgentError: the agent cannot go on (the message says why).
        """
        # odometry counts since its last reading: what the wheels did before (a push by hand)
        # is not this run's first motion
        self.io.motors.odometry()
        try:
            while not self.stopping.is_set():
                if max_frames is not None and self.stats.frames >= max_frames:
                    break
                self.step()
        finally:
            self.wheels.close()

    def stop(self) -> None:
        """End :meth:`run` after the frame under way (thread-safe)."""
        self.stopping.set()

    def step(self) -> schemas.MotionCommand | None:
        """One frame: read the devices, send, obey the answer, wait for the next frame's time.
        Returns the command obeyed (``None`` when there was none to obey)."""
        clock = self.io.clock
        period = self.params.period_s
        if self._next_at is None:
            self._next_at = clock.now()
        command = self._exchange()
        # the next frame's time; a loop that fell behind carries on from now, never in a burst
        self._next_at += period
        if command is None and self._gone_since is not None:
            self._next_at = clock.now() + self._retry
            self._retry = min(self._retry * 2, self.params.max_retry_s)
        self.wheels.wait(self._next_at - clock.now())
        if clock.now() - self._next_at > period:
            self._next_at = clock.now()
        return command

    def _exchange(self) -> schemas.MotionCommand | None:
        """Send one frame and obey its answer; stop when there is none to obey."""
        clock = self.io.clock
        image = self._read_camera()
        if image is None:
            return None
        t = clock.now()
        v, w = self.io.motors.odometry()
        self._dead_reckon(t, v, w)
        ranges = None if self.io.depth is None else [float(r) for r in self.io.depth.profile()]
        jpeg = encode_jpeg(image, self.params.jpeg_quality)
        try:
            result = self.client.upload_frame(
                self.robot,
                jpeg,
                timestamp=self._offset + t,
                v=v,
                w=w,
                depth=ranges,
                pose=self._pose_to_send(),
                stream=True,
                timeout=self.params.answer_timeout_s,
            )
        except UntrustedServerError as exc:
            self.wheels.stop()
            raise AgentError(str(exc)) from None
        except httpx.TransportError as exc:
            self.wheels.stop()  # never drive blind while the server is away
            self._unreachable(exc)
            return None
        except ApiError as exc:
            self.wheels.stop()
            self._refused(exc)
            return None
        self._back()
        command = result.command
        if command is None:  # pragma: no cover - every answer of this server has one
            self.wheels.stop()
            return None
        left = command.ttl_s - (clock.now() - t)
        if left <= 0:
            self.stats.late += 1
            self.wheels.stop()
            self._say(
                f"answers come later than their time-to-live ({command.ttl_s:g} s): the robot "
                "stands until they come in time"
            )
        else:
            self._said = None
            self.wheels.drive(command.v, command.w, left)
        self.stats.frames += 1
        self.stats.commands[command.behaviour] = self.stats.commands.get(command.behaviour, 0) + 1
        self._follow_mode(result)
        return command

    # --- devices --------------------------------------------------------------------------

    def _read_camera(self) -> Image | None:
        try:
            image = self.io.camera.read()
            error = "it gave no frame"
        except Exception as exc:  # a driver's failure, whatever it is: stand, say it
            image, error = None, f"{type(exc).__name__}: {exc}"
        if image is not None:
            self._camera_failed = 0
            return image
        self.wheels.stop()
        self._camera_failed += 1
        self.stats.camera_failures += 1
        if self._camera_failed == 1:
            self.log(f"camera: {error}; the robot stands until it gives frames again")
        if self._camera_failed >= self.params.camera_failures:
            raise AgentError(
                f"the camera gave no frame {self._camera_failed} times in a row ({error}); "
                "check that it is connected and not used by another program"
            )
        return None

    def _dead_reckon(self, t: float, v: float, w: float) -> None:
        """Integrate the odometry into the pose sent with each frame (what a real robot
        knows of where it is, never a simulator's truth)."""
        if self._last_t is not None:
            dt = max(0.0, t - self._last_t)
            x, y, th = self._pose
            mid = th + w * dt / 2
            x += v * dt * math.cos(mid)
            y += v * dt * math.sin(mid)
            th = math.atan2(math.sin(th + w * dt), math.cos(th + w * dt))
            self._pose = [x, y, th]
        self._last_t = t

    def _pose_to_send(self) -> list[float] | None:
        if max(abs(self._pose[0]), abs(self._pose[1])) >= schemas.MAX_POSE:
            return None
        return [round(x, 4) for x in self._pose]

    # --- what it says -----------------------------------------------------------------------

    def _say(self, line: str) -> None:
        """Say ``line`` once, not again while it is the same."""
        if line != self._said:
            self._said = line
            self.log(line)

    def _unreachable(self, exc: Exception) -> None:
        self.stats.unreachable += 1
        if self._gone_since is None:
            self._gone_since = time.monotonic()
            self._retry = self.params.retry_s
            what = (
                f"no answer within {self.params.answer_timeout_s:g} s"
                if isinstance(exc, httpx.TimeoutException)
                else f"{type(exc).__name__}: {exc}"
            )
            self.log(
                f"server unreachable ({what}): motors stopped; trying again every "
                f"{self.params.retry_s:g} to {self.params.max_retry_s:g} s"
            )

    def _back(self) -> None:
        if self._gone_since is not None:
            self.log(f"server back after {time.monotonic() - self._gone_since:.1f} s")
            self._gone_since = None
            self._retry = self.params.retry_s

    def _refused(self, exc: ApiError) -> None:
        self.stats.refused += 1
        if exc.status == 401:
            raise AgentError(
                f"the server refused the token (401: {exc.detail}). Give the robot's current "
                "token (--token-file FILE or TEACHREPEAT_ROBOT_TOKEN); a household login "
                "issues a new one with POST /robots/{robot}/token"
            )
        if exc.status in (403, 404):
            raise AgentError(
                f"the server refused robot {self.robot!r} ({exc.status}: {exc.detail}); "
                "run the agent with that robot's own token"
            )
        found = BACKWARDS.search(exc.detail) if exc.status == 422 else None
        if found is not None:  # the server saw later frames (an earlier run): carry on after
            # the next frame, a period from now, comes a period after the last one it holds
            self._offset = float(found.group(1)) - self.io.clock.now()
            self.log("the server holds later frames of this robot: timestamps moved on after them")
            return
        self._say(f"frame refused ({exc.status}: {exc.detail}); the robot stands")

    def _follow_mode(self, result: schemas.AnyFrameResult) -> None:
        """Say when the mode changes (idle, teaching, navigating to a place, arrived)."""
        mode: str = result.mode
        if isinstance(result, schemas.NavigationFrameResult):
            task = result.task
            underway = task is not None and task.state == "underway"
            mode = "navigating" if underway else "idle"  # a task that ended: tracking only
            if task is not None:
                if underway and self._task != (task.id, "underway"):
                    self.log(f"navigating to {task.goal!r} (task {task.id})")
                elif not underway and self._task == (task.id, "underway"):
                    why = f" ({task.reason})" if task.reason else ""
                    self.log(f"task {task.id} to {task.goal!r}: {task.state}{why}")
                self._task = (task.id, task.state)
        if mode != self.stats.mode:
            if mode != "navigating":
                self.log(f"mode: {mode}")
            self.stats.mode = mode


# --- the command ------------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--server", required=True, help="server URL, e.g. http://127.0.0.1:8000")
    add_token_arguments(parser)
    add_pinning_arguments(parser)
    parser.add_argument(
        "--driver",
        required=True,
        choices=sorted(DRIVERS),
        help="the robot's hardware (sim: a simulated robot in a simulated home)",
    )
    parser.add_argument("--rate", type=float, default=10.0, help="frames per second (10)")
    parser.add_argument("--jpeg-quality", type=int, default=85, help="JPEG quality (85)")
    for name in sorted(DRIVERS):
        importlib.import_module(DRIVERS[name]).add_arguments(parser)


def connect(
    url: str,
    token: str,
    *,
    params: AgentParams,
    ca_cert: Path | None = None,
    fingerprint: str | None = None,
    log: Log = _stderr,
    stopping: threading.Event | None = None,
) -> tuple[TeachRepeatClient, str]:
    """A client for the robot's token and the robot's name, waiting (and saying so once)
    while the server cannot be reached. Raises :class:`AgentError` for a token the server
    refuses or that is not a robot's, and for a certificate that is not the pinned one."""
    client = TeachRepeatClient(
        url,
        token,
        timeout_s=params.answer_timeout_s,
        max_wait_s=1.0,
        ca_cert=ca_cert,
        fingerprint=fingerprint,
    )
    waiting = stopping if stopping is not None else threading.Event()
    said = False
    try:
        while True:
            try:
                me = client.whoami()
                break
            except UntrustedServerError as exc:
                raise AgentError(str(exc)) from None
            except httpx.TransportError as exc:
                if not said:
                    log(f"waiting for the server at {url} ({type(exc).__name__}: {exc})")
                    said = True
                if waiting.wait(params.max_retry_s):
                    raise AgentError("stopped before the server answered") from None
            except ApiError as exc:
                if exc.status == 401:
                    raise AgentError(
                        f"the server refused the token (401: {exc.detail}). Give the robot's "
                        "current token (--token-file FILE or TEACHREPEAT_ROBOT_TOKEN)"
                    ) from None
                raise AgentError(f"the server refused: {exc}") from None
        if me.kind != "robot" or me.robot is None:
            whose = "the admin" if me.kind == "admin" else "a household login"
            raise AgentError(
                f"this token belongs to {whose}, not to a robot: give the robot's own token "
                "(POST /robots answered it when the robot was registered)"
            )
        return client, me.robot
    except BaseException:
        client.close()
        raise


def run(args: argparse.Namespace) -> int:
    from robot_client.pinning import parse_fingerprint

    try:
        token = read_token(args)
        if args.fingerprint is not None:
            parse_fingerprint(args.fingerprint)
        params = AgentParams(rate_hz=args.rate, jpeg_quality=args.jpeg_quality)
    except ValueError as exc:
        print(f"teachrepeat robot run: {exc}", file=sys.stderr)
        return 2
    driver = importlib.import_module(DRIVERS[args.driver])
    try:
        io = driver.open_robot(args)
    except DriverError as exc:
        print(f"teachrepeat robot run: driver {args.driver}: {exc}", file=sys.stderr)
        return 2
    try:
        return run_agent(
            args.server,
            token,
            io,
            params,
            ca_cert=args.ca_cert,
            fingerprint=args.fingerprint,
            driver=args.driver,
        )
    finally:
        io.close()


def run_agent(
    url: str,
    token: str,
    io: RobotIO,
    params: AgentParams = AgentParams(),
    *,
    ca_cert: Path | None = None,
    fingerprint: str | None = None,
    driver: str = "",
    log: Log = _stderr,
    ready: Callable[[Agent], None] | None = None,
    stopping: threading.Event | None = None,
) -> int:
    """Connect and run the agent until Ctrl-C or SIGTERM (or ``stopping`` is set); 0 on a
    clean stop, 1 when it cannot go on (said on ``log``). ``ready(agent)`` is called once
    the agent is connected (tests and benchmarks hold it)."""
    try:
        client, robot = connect(
            url,
            token,
            params=params,
            ca_cert=ca_cert,
            fingerprint=fingerprint,
            log=log,
            stopping=stopping,
        )
    except AgentError as exc:
        log(f"teachrepeat robot run: {exc}")
        return 1
    with client:
        agent = Agent(client, robot, io, params, log=log)
        if stopping is not None:
            agent.stopping = stopping
        via = f" (driver {driver})" if driver else ""
        log(f"robot {robot!r} on {url}{via}: {params.rate_hz:g} frames/s; Ctrl-C stops it")
        if ready is not None:
            ready(agent)
        try:
            agent.run()
        except AgentError as exc:
            log(f"teachrepeat robot run: {exc}")
            return 1
        except KeyboardInterrupt:
            log("stopped (Ctrl-C); the robot stands")
            return 0
        except SystemExit:  # SIGTERM (the command line turns it into SystemExit)
            log("stopped (SIGTERM); the robot stands")
            raise
        s = agent.stats
        log(f"stopped after {s.frames} frames ({s.late} late, {s.unreachable} unanswered)")
        return 0
