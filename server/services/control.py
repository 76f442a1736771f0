"""What a streaming robot is told outside navigation: stand, drive as a person says, or spin.

The robot agent (``teachrepeat robot run``) streams frames whatever happens and obeys the
command each answer carries; the server decides the mode:

* **idle** (neither teaching nor navigating): stand, or drive as a person commands (teleop:
  the dashboard's arrows and keys, or ``POST /robots/{robot}/teleop`` from a phone or a
  gamepad script);
* **teaching**: the same, and the frames taken while the person drives it are kept on the open
  path; when a new place is named, the server spins the robot once there and keeps the spin's
  frames (one every ``spin_step_deg`` of turn, by the robot's odometry) as the place's images,
  as ``POST /robots/{robot}/teach/spin`` does for a client that spins by itself;
* **navigating**: navigation's command, as before (teleop is refused; halt first).

A teleop command stays in force for its own short time-to-live (a dead man's switch: the sender
repeats it while a key is held, and the robot stops by itself once the sender goes quiet); each
answer's command carries a time-to-live of at most ``ttl_s`` and never beyond the teleop
command's end, so a robot whose server disappears stops within that time.

A frame sent with ``stream`` false (a client that decides itself, like ``robot teach`` or the
scripted guide) is handled exactly as before, with a command added to its answer.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from server import schemas
from server.errors import Conflict, DomainError
from server.imaging import ImageLimits, decode_jpeg
from server.services.navigation import NavigationService
from server.services.teaching import TeachingObserver, TeachingService
from server.storage.repo import Repo

log = logging.getLogger(__name__)

FULL_TURN = 2.0 * math.pi


@dataclass(frozen=True)
class ControlParams:
    """How the server drives a streaming robot outside navigation.

    * ``ttl_s`` (0.3 s): time-to-live of the commands answered outside navigation (stand,
      teleop, spin): a robot that hears nothing newer stops this long after its frame was sent.
    * ``max_v`` (0.3 m/s) and ``max_w`` (1.0 rad/s): the teleop speed limit; faster commands
      are clamped to it (the scripted guide teaches at these speeds). Deployment settings
      ``teleop_max_v`` and ``teleop_max_w``.
    * ``spin_w`` (0.6 rad/s): how fast the robot turns at a new place (one turn in 10.5 s, as
      the scripted guide spins); setting ``spin_w``.
    * ``spin_step_deg`` (10 degrees): one spin image per this much turn (about 36 per place).
    * ``spin_timeout`` (2.5): a spin that has not turned a full turn after this many times the
      time one takes at ``spin_w`` ends anyway ("timeout": blocked, or no odometry).
    * ``connected_s`` (2 s): a robot whose last streamed frame is older is not connected;
      teleop is refused for it (nobody would obey) and no spin is started.
    """

    ttl_s: float = 0.3
    max_v: float = 0.3
    max_w: float = 1.0
    spin_w: float = 0.6
    spin_step_deg: float = 10.0
    spin_timeout: float = 2.5
    connected_s: float = 2.0

    def __post_init__(self) -> None:
        for name in ("ttl_s", "max_v", "max_w", "spin_w", "spin_step_deg", "connected_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"ControlParams.{name} must be positive")
        if not self.spin_timeout >= 1.0:
            raise ValueError("ControlParams.spin_timeout must be at least 1")


@dataclass
class _Teleop:
    v: float
    w: float
    ttl_s: float
    expires: float  # monotonic seconds
    clamped: bool
    by: str


@dataclass
class _Spin:
    place: str
    started_wall: float
    started_t: float | None = None  # robot time of its first frame
    last_t: float | None = None
    turned: float = 0.0  # radians, from the robot's odometry
    kept_at: float = -math.inf  # ``turned`` when the last image was kept
    images: int = 0
    state: str = "spinning"


@dataclass(frozen=True)
class LiveFrame:
    """A robot's latest frame and what it was told (for the dashboard's camera)."""

    jpeg: bytes
    timestamp: float  # robot clock, s
    wall: float  # monotonic seconds when it came
    mode: str  # idle | teaching | navigating
    command: schemas.MotionCommand
    kept: bool  # stored on the open path or as a spin image


@dataclass
class _Robot:
    lock: threading.Lock = field(default_factory=threading.Lock)
    teleop: _Teleop | None = None
    spin: _Spin | None = None
    last: LiveFrame | None = None
    last_stream: float | None = None  # monotonic seconds of the last streamed frame
    moving: bool = False  # the last answer told it to drive by hand (until the next frame)


class ControlService(TeachingObserver):
    """The robots' modes outside navigation, and the frames endpoint for every mode.

    ``clock``: monotonic seconds (teleop expiry, connection); tests pass their own."""

    def __init__(
        self,
        repo: Repo,
        teaching: TeachingService,
        navigation: NavigationService,
        limits: ImageLimits,
        params: ControlParams | None = None,
        *,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.repo = repo
        self.teaching = teaching
        self.navigation = navigation
        self.limits = limits
        self.params = params if params is not None else ControlParams()
        self.clock = clock
        self._robots: dict[str, _Robot] = {}
        self._lock = threading.Lock()

    def _robot(self, robot: str) -> _Robot:
        with self._lock:
            state = self._robots.get(robot)
            if state is None:
                state = self._robots[robot] = _Robot()
            return state

    # --- commands -------------------------------------------------------------------------

    def stand(self, reason: str | None = None) -> schemas.MotionCommand:
        return schemas.MotionCommand(
            v=0.0,
            w=0.0,
            ttl_s=self.params.ttl_s,
            action="do_nothing",
            behaviour="stand",
            reason=reason,
        )

    def _teleop_now(self, state: _Robot, now: float) -> _Teleop | None:
        """The teleop command in force (under ``state.lock``); an expired one is dropped."""
        t = state.teleop
        if t is not None and now >= t.expires:
            state.teleop = t = None
        return t

    def _by_hand(self, state: _Robot, now: float, idle: str) -> schemas.MotionCommand:
        """The teleop command in force, or stand (``idle``: why), under ``state.lock``."""
        t = self._teleop_now(state, now)
        if t is None:
            return self.stand(idle)
        return schemas.MotionCommand(
            v=t.v,
            w=t.w,
            ttl_s=round(min(self.params.ttl_s, t.expires - now), 3),
            action="do_nothing",
            behaviour="teleop",
            reason=f"driven by hand ({t.by})",
        )

    def _spin_command(self) -> schemas.MotionCommand:
        return schemas.MotionCommand(
            v=0.0,
            w=self.params.spin_w,
            ttl_s=self.params.ttl_s,
            action="do_nothing",
            behaviour="spin",
            reason="turning once at a new place to photograph it",
        )

    # --- frames ---------------------------------------------------------------------------

    def frame(self, robot: str, data: bytes, meta: schemas.FrameMeta) -> schemas.AnyFrameResult:
        """A robot's frame, in whatever mode the robot is: kept while teaching, stepped while
        navigating, and answered with the command to obey in every mode."""
        state = self._robot(robot)
        now = self.clock()
        if meta.stream:
            with state.lock:
                state.last_stream = now
        result: schemas.AnyFrameResult
        if self.repo.teaching(robot) is not None:
            result = self._teaching_frame(robot, state, data, meta, now)
            mode, command, kept = "teaching", result.command, result.image is not None
        elif self.navigation.session(robot) is not None:
            result = self._navigation_frame(robot, state, data, meta, now)
            underway = result.task is not None and result.task.state == "underway"
            mode, command, kept = ("navigating" if underway else "idle"), result.command, False
        else:
            decode_jpeg(data, self.limits)  # refuse what is not a usable image (4xx)
            with state.lock:
                command = self._by_hand(state, now, "idle: nothing to do")
            result = schemas.IdleFrameResult(mode="idle", command=command)
            mode, kept = "idle", False
        assert command is not None  # every branch sets one
        with state.lock:
            state.moving = command.behaviour == "teleop" and (command.v != 0 or command.w != 0)
            state.last = LiveFrame(data, meta.timestamp, now, mode, command, kept)
        return result

    def _navigation_frame(
        self, robot: str, state: _Robot, data: bytes, meta: schemas.FrameMeta, now: float
    ) -> schemas.NavigationFrameResult:
        """Navigation's answer; after a task ended (the belief still tracks), a person may
        drive the robot by hand and the teleop command replaces navigation's stand."""
        result = self.navigation.frame(robot, data, meta)
        underway = result.task is not None and result.task.state == "underway"
        with state.lock:
            if underway:
                state.teleop = None
                return result
            t = self._teleop_now(state, now)
            if t is None:
                return result
            command = self._by_hand(state, now, "")
        return result.model_copy(update={"command": command})

    def _teaching_frame(
        self, robot: str, state: _Robot, data: bytes, meta: schemas.FrameMeta, now: float
    ) -> schemas.FrameResult:
        if not meta.stream:  # a client that decides itself: every frame on the open path
            result = self.teaching.frame(robot, data, meta)
            with state.lock:
                command = self._by_hand(state, now, "teaching")
            return result.model_copy(update={"command": command})
        with state.lock:
            spinning = state.spin is not None and state.spin.state == "spinning"
            moving = state.moving
        if spinning:
            return self._spin_frame(robot, state, data, meta)
        teaching = self.teaching.state(robot)
        if teaching is not None and moving and teaching.current_location is not None:
            # the robot drove by hand since its last frame: this frame shows the path
            result = self.teaching.frame(robot, data, meta)
        else:
            decode_jpeg(data, self.limits)  # standing still, or no place named yet: not kept
            pending = 0 if teaching is None else teaching.open_path_images
            result = schemas.FrameResult(mode="teaching", image=None, open_path_images=pending)
        idle = "teaching: drive the robot, or name the place where it stands"
        if teaching is not None and teaching.current_location is None:
            idle = "teaching: name the place where the robot stands to begin"
        with state.lock:
            command = self._by_hand(state, now, idle)
        return result.model_copy(update={"command": command})

    def _spin_frame(
        self, robot: str, state: _Robot, data: bytes, meta: schemas.FrameMeta
    ) -> schemas.FrameResult:
        """One frame of the spin at a new place: turned further by the robot's odometry,
        kept as a spin image every ``spin_step_deg``, done after one full turn."""
        p = self.params
        step = math.radians(p.spin_step_deg)
        with state.lock:
            spin = state.spin
            if spin is None or spin.state != "spinning":  # halted meanwhile
                return self._teaching_frame(robot, state, data, meta, self.clock())
            if spin.last_t is None:
                spin.started_t = meta.timestamp
            else:
                spin.turned += abs(meta.w) * max(0.0, meta.timestamp - spin.last_t)
            spin.last_t = meta.timestamp
            done = spin.turned >= FULL_TURN - step / 2
            keep = not done and spin.turned - spin.kept_at >= step - 1e-9
            elapsed = meta.timestamp - (spin.started_t or meta.timestamp)
            timeout = not done and elapsed > p.spin_timeout * FULL_TURN / p.spin_w
        stored = None
        if keep:
            try:
                stored = self.teaching.spin_image(robot, data, meta)
            except DomainError as exc:
                log.warning("spin image of %r at %r not kept: %s", robot, spin.place, exc.message)
        else:
            decode_jpeg(data, self.limits)
        with state.lock:
            if stored is not None:
                spin.images += 1
                spin.kept_at = spin.turned
            if done or timeout:
                spin.state = "done" if done else "timeout"
                log.info("%r spun at %r: %s, %d images", robot, spin.place, spin.state, spin.images)
            if spin.state == "spinning":
                command = self._spin_command()
            else:
                command = self.stand(f"spun at {spin.place}: {spin.images} images")
            images = spin.images
        teaching = self.teaching.state(robot)
        pending = 0 if teaching is None else teaching.open_path_images
        return schemas.FrameResult(
            mode="teaching",
            image=stored,
            open_path_images=pending,
            command=command,
            spin_images=images,
        )

    # --- teaching observer: a new place is spun at ----------------------------------------

    def teaching_marked(self, robot: str, tour_id: int, result: schemas.MarkResult) -> None:
        """A new place named while the robot streams: spin there (its frames become the
        place's images). A known place, or a robot that does not stream, is not spun at."""
        if not result.created:
            return
        state = self._robot(robot)
        now = self.clock()
        with state.lock:
            if not self._connected(state, now):
                return
            state.teleop = None
            state.moving = False
            state.spin = _Spin(place=result.location.name, started_wall=now)

    def teaching_ended(
        self, robot: str, tour_id: int, ended: schemas.TeachingEnded, *, finished: bool
    ) -> None:
        state = self._robot(robot)
        with state.lock:
            if state.spin is not None and state.spin.state == "spinning":
                state.spin.state = "stopped"

    # --- requests -------------------------------------------------------------------------

    def _connected(self, state: _Robot, now: float) -> bool:
        return state.last_stream is not None and now - state.last_stream <= self.params.connected_s

    def teleop(
        self,
        robot: str,
        body: schemas.TeleopCommand,
        *,
        actor: str,
        address: str | None = None,
    ) -> schemas.TeleopState:
        """Drive ``robot`` by hand for ``body.ttl_s`` (clamped to the speed limit); a zero
        command stops it at once. Refused (409) while it navigates or spins, or when it is not
        connected. The start of a drive is written to the audit log (``actor``, ``address``);
        the repeats that keep it going are not."""
        p = self.params
        if self.navigation.is_navigating(robot):
            raise Conflict(
                f"robot {robot!r} is navigating; stop it first (POST /robots/{robot}/stop or "
                f"POST /robots/{robot}/halt), then drive it by hand"
            )
        teaching = self.repo.teaching(robot) is not None
        v = max(-p.max_v, min(p.max_v, body.v))
        w = max(-p.max_w, min(p.max_w, body.w))
        clamped = (v, w) != (body.v, body.w)
        state = self._robot(robot)
        now = self.clock()
        with state.lock:
            spin = state.spin
            if spin is not None and spin.state == "spinning":
                left = max(0.0, (FULL_TURN - spin.turned) / p.spin_w)
                raise Conflict(
                    f"robot {robot!r} is turning once at {spin.place!r} to photograph it "
                    f"({spin.images} images so far, about {left:.0f} s left); wait for the turn "
                    f"to end, or halt it (POST /robots/{robot}/halt)"
                )
            if not self._connected(state, now):
                ago = "has never sent a frame"
                if state.last_stream is not None:
                    ago = f"sent its last frame {now - state.last_stream:.0f} s ago"
                raise Conflict(
                    f"robot {robot!r} is not connected: it {ago}. Start its agent "
                    "(`teachrepeat robot run`) before driving it"
                )
            before = self._teleop_now(state, now)
            started = before is None and (v != 0 or w != 0)
            if v == 0 and w == 0:
                state.teleop = None
            else:
                state.teleop = _Teleop(v, w, body.ttl_s, now + body.ttl_s, clamped, actor)
        if started:
            try:
                self.repo.add_audit(
                    actor=actor,
                    action="teleop start",
                    target=f"/robots/{robot}/teleop",
                    status=200,
                    address=address,
                )
            except DomainError as exc:  # a read-only or full disk: the command stands
                log.warning("audit entry for teleop of %r not written: %s", robot, exc.message)
        return schemas.TeleopState(
            robot=robot,
            v=v,
            w=w,
            clamped=clamped,
            max_v=p.max_v,
            max_w=p.max_w,
            ttl_s=body.ttl_s,
            mode="teaching" if teaching else "idle",
        )

    def halt(self, robot: str) -> list[str]:
        """Stop whatever ``robot`` does: a person driving it, a spin, a navigation task.
        Returns what was stopped, in words (empty: it was standing already)."""
        stopped: list[str] = []
        state = self._robot(robot)
        now = self.clock()
        with state.lock:
            if self._teleop_now(state, now) is not None:
                stopped.append("driving by hand")
            state.teleop = None
            state.moving = False
            if state.spin is not None and state.spin.state == "spinning":
                state.spin.state = "stopped"
                stopped.append(f"the spin at {state.spin.place}")
        if self.navigation.is_navigating(robot):
            try:
                task = self.navigation.stop(robot)
                stopped.append(f"task {task.id} to {task.goal} ({task.state})")
            except Conflict:  # it ended meanwhile
                pass
        return stopped

    # --- what it is doing -----------------------------------------------------------------

    def public(self, robot: str) -> schemas.RobotControlPublic | None:
        """What the robot is told outside navigation; ``None`` for a robot that never sent a
        frame since the server started."""
        with self._lock:
            state = self._robots.get(robot)
        if state is None:
            return None
        now = self.clock()
        p = self.params
        with state.lock:
            t = self._teleop_now(state, now)
            teleop = None
            if t is not None:
                mode = "teaching" if self.repo.teaching(robot) is not None else "idle"
                teleop = schemas.TeleopState(
                    robot=robot,
                    v=t.v,
                    w=t.w,
                    clamped=t.clamped,
                    max_v=p.max_v,
                    max_w=p.max_w,
                    ttl_s=t.ttl_s,
                    mode=mode,  # type: ignore[arg-type]
                )
            spin = None
            if state.spin is not None:
                s = state.spin
                spin = schemas.SpinPublic(
                    place=s.place,
                    images=s.images,
                    turned_deg=round(math.degrees(s.turned), 1),
                    state=s.state,  # type: ignore[arg-type]
                )
            last = state.last
            age = None if last is None else round(now - last.wall, 3)
            return schemas.RobotControlPublic(
                connected=self._connected(state, now),
                last_frame_age_s=age,
                teleop=teleop,
                spin=spin,
            )

    def live(self, robot: str) -> LiveFrame | None:
        """The robot's latest frame and the command it got (read without waiting on a step)."""
        with self._lock:
            state = self._robots.get(robot)
        return None if state is None else state.last
