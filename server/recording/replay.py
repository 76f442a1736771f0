"""``teachrepeat replay FILE``: a recorded task's frames through the server's step again.

The recording's frames (the JPEG as the robot sent it, its timestamp, odometry and depth, and
the server's clock when it came) are sent, in order, to a :class:`NavigationService` on a
copy of the database, exactly as the API hands them on (``goto``, then ``frame`` after
``frame``): the code that answered the robot answers them again. The task starts as it did
(same goal, same tour, the recorded belief when it did not start from the prior), with the
navigation settings the server ran with (the ones it changed from the defaults) and any
``--set`` on top. Each answer is described as the recorder described it
(:func:`server.recording.messages.navigation_frame`) and compared with the recording, frame by
frame: where the belief, the votes, the command or the task's state now differ.

The database is copied first (a temporary file), so replay never writes to it. Replaying the
same file twice gives the same comparison (timings go to stderr, not into it).

What counts as a difference (:class:`Tolerance`): everything that decides behaviour is compared
exactly (the action, the edge, the target image, the behaviour, the reason, names, indices, the
task's state), the command's speeds to the robot's precision, and every other number (belief,
votes, similarities) within a relative tolerance. The same code on another CPU, or with another
BLAS kernel, sums float32 products in another order: the belief and votes then differ in the
seventh digit (docs/recording.md, "Tolerance"), and demanding nine equal digits failed a replay
on one machine that passed on the next.
"""

from __future__ import annotations

import json
import math
import sqlite3
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from server import schemas
from server.belief.tracker import BeliefError, TrackerMemory
from server.recording.mcapfile import encode
from server.recording.messages import navigation_frame, tour_fingerprint
from server.recording.reader import Recording, RecordingError
from server.services.navigation import NavigationObserver

if TYPE_CHECKING:
    from server.services.navigation import NavigationService
    from server.session import RobotSession, StepRecord
    from server.storage.repo import Repo

REPLAY_ROBOT = "replay"
"""The robot the frames are sent as, in the copy of the database (a fresh session)."""


@dataclass(frozen=True)
class Tolerance:
    """When two recorded numbers are equal.

    Attributes:
        relative (1e-4): floats ``a``, ``b`` are equal when ``|a - b| <= absolute + relative *
            max(|a|, |b|)``. Chosen from the drift measured between two OpenBLAS kernels
            (Haswell and SkylakeX) on this machine: at most 1.8e-6 relative (15 float32 units in
            the last place) over a 167-frame task, and 2.5e-7 absolute; 1e-4 leaves a margin of
            55x, and is still far below any change a setting makes.
        absolute (1e-9): for floats that are zero, or nearly, in one of the runs.
        command (1e-3): the command's ``v`` (m/s), ``w`` (rad/s) and ``ttl_s`` (s) are equal
            within this: a robot cannot tell 1 mm/s or 1 mrad/s apart.

    Integers (ids, indices, counts), strings, booleans and ``None`` are compared exactly.
    :meth:`strict` (``--tolerance 0``) demands every number equal to the last bit.
    """

    relative: float = 1e-4
    absolute: float = 1e-9
    command: float = 1e-3

    def __post_init__(self) -> None:
        if min(self.relative, self.absolute, self.command) < 0 or not all(
            math.isfinite(x) for x in (self.relative, self.absolute, self.command)
        ):
            raise ValueError("tolerances must be finite and >= 0")

    @classmethod
    def strict(cls) -> Tolerance:
        """Every number equal to the last bit."""
        return cls(relative=0.0, absolute=0.0, command=0.0)

    @classmethod
    def of(cls, relative: float) -> Tolerance:
        """The default tolerance with ``relative`` instead (0: :meth:`strict`)."""
        return cls.strict() if relative == 0 else cls(relative=relative)

    def equal(self, path: str, a: Any, b: Any) -> bool:
        """Whether recorded ``a`` and replayed ``b`` at ``path`` (``command.v``,
        ``belief.states[3]``) count as equal."""
        if not (_number(a) and _number(b)):
            return bool(a == b)
        if isinstance(a, int) and isinstance(b, int):
            return a == b
        x, y = float(a), float(b)
        if x == y:
            return True
        if not (math.isfinite(x) and math.isfinite(y)):
            return False
        if path in COMMAND_FLOATS:
            return abs(x - y) <= self.command
        return abs(x - y) <= self.absolute + self.relative * max(abs(x), abs(y))


COMMAND_FLOATS = frozenset({"command.v", "command.w", "command.ttl_s"})
"""The command's numbers the robot executes: equal to its precision (:attr:`Tolerance.command`)."""


@dataclass(frozen=True)
class Difference:
    """One value that differs: ``path`` in the frame's compared messages (``command.v``,
    ``belief.top[0].name``), the recorded value and the replayed one."""

    path: str
    recorded: Any
    replayed: Any

    def text(self) -> str:
        return f"{self.path} {_short(self.recorded)} -> {_short(self.replayed)}"


@dataclass(frozen=True)
class FrameDifference:
    """A frame whose replay differs from its recording."""

    index: int
    timestamp: float  # robot clock, s
    differences: tuple[Difference, ...]


@dataclass
class ReplayReport:
    """The comparison: deterministic (no timing in it)."""

    file: str
    robot: str
    goal: str
    tour: int  # the tour id the recording names
    tour_used: int  # the tour of the database replayed against (same fingerprint)
    settings: dict[str, Any]  # navigation settings changed from the defaults
    complete: bool
    frames_recorded: int
    frames_replayed: int
    differing: list[FrameDifference] = field(default_factory=list)
    task_recorded: str | None = None
    task_replayed: str | None = None

    def as_json(self) -> dict[str, Any]:
        return {
            "file": self.file,
            "robot": self.robot,
            "goal": self.goal,
            "tour": self.tour,
            "tour_used": self.tour_used,
            "settings": self.settings,
            "complete": self.complete,
            "frames_recorded": self.frames_recorded,
            "frames_replayed": self.frames_replayed,
            "frames_differing": len(self.differing),
            "first_difference": None if not self.differing else self.differing[0].index,
            "task_recorded": self.task_recorded,
            "task_replayed": self.task_replayed,
            "differences": [
                {
                    "frame": f.index,
                    "t": f.timestamp,
                    "fields": [
                        {"path": d.path, "recorded": d.recorded, "replayed": d.replayed}
                        for d in f.differences
                    ],
                }
                for f in self.differing
            ],
        }

    def lines(self, *, limit: int = 8) -> Iterator[str]:
        """The comparison as text: one line per differing frame, then a summary."""
        for f in self.differing:
            shown = "; ".join(d.text() for d in f.differences[:limit])
            more = len(f.differences) - limit
            yield f"frame {f.index} (t {f.timestamp:.2f} s): {shown}" + (
                f" (+{more} more)" if more > 0 else ""
            )
        where = f"tour {self.tour}" + (
            "" if self.tour_used == self.tour else f" (tour {self.tour_used} here)"
        )
        head = (
            f"{Path(self.file).name}: {self.frames_replayed} of {self.frames_recorded} frames "
            f"of {self.robot}'s task to {self.goal} on {where} replayed"
        )
        if self.settings:
            head += f" with {json.dumps(self.settings, sort_keys=True)}"
        if not self.differing:
            yield f"{head}: no differences"
        else:
            first = self.differing[0]
            yield (
                f"{head}: {len(self.differing)} frames differ, the first at frame {first.index} "
                f"(t {first.timestamp:.2f} s); task {self.task_recorded} -> {self.task_replayed}"
            )


@dataclass
class Timing:
    frames: int = 0
    seconds: float = 0.0  # the frames' replay, wall clock
    realtime_fps: float = 0.0  # frames per second of robot time when recorded

    @property
    def fps(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else math.inf

    def text(self) -> str:
        speed = self.fps / self.realtime_fps if self.realtime_fps > 0 else math.inf
        return (
            f"replayed {self.frames} frames in {self.seconds:.2f} s: {self.fps:.1f} frames/s, "
            f"{speed:.1f}x real time (recorded at {self.realtime_fps:.1f} frames/s)"
        )


class _Capture(NavigationObserver):
    """Describes every replayed step as the recorder does."""

    def __init__(self, depth_fov_deg: float) -> None:
        self.depth_fov_deg = depth_fov_deg
        self.frames: list[dict[str, Any]] = []

    def stepped(
        self,
        robot: str,
        session: RobotSession,
        step: StepRecord,
        result: schemas.NavigationFrameResult,
        meta: schemas.FrameMeta,
        wall: float,
    ) -> None:
        described = navigation_frame(
            step,
            result,
            session.runtime.graph,
            meta,
            index=len(self.frames),
            wall=wall,
            depth_fov_deg=self.depth_fov_deg,
        )
        self.frames.append(json.loads(encode(described.compared())))  # as read from a file


def replay(
    recording: Recording,
    db: Path,
    *,
    settings: dict[str, Any] | None = None,
    partial: bool = False,
    tolerance: Tolerance = Tolerance(),
) -> tuple[ReplayReport, Timing]:
    """Replay ``recording`` against the tour it was recorded on in database ``db`` (copied
    first); ``settings``: navigation settings to change on top of the recorded ones (dotted
    names, as ``--set``); ``partial``: replay the whole frames of a file that was cut short;
    ``tolerance``: when numbers are equal (:class:`Tolerance`).

    Raises :class:`RecordingError` (a teaching recording, a file cut short without
    ``partial``, a missing database, another tour, an unknown setting)."""
    _check(recording, partial=partial)
    if not Path(db).is_file():
        raise RecordingError(
            f"no database at {db}: replay needs the database the recording's tour is in "
            "(--db PATH; `bench navigate --record` keeps one beside its recordings)"
        )
    with tempfile.TemporaryDirectory(prefix="teachrepeat-replay-") as tmp:
        copy = Path(tmp) / "replay.sqlite"
        _copy_database(Path(db), copy)
        return _replay_on(recording, copy, settings or {}, tolerance)


def _check(recording: Recording, *, partial: bool) -> None:
    name = recording.path.name
    if recording.kind != "navigate":
        raise RecordingError(
            f"{name} records a teaching tour, not a navigation task: there is nothing to "
            "replay (open it on the dashboard's Timeline or in Foxglove)"
        )
    if not recording.complete and not partial:
        raise RecordingError(
            f"{name} is truncated: it ends at byte {recording.cut_at} of {recording.size_bytes} "
            f"without MCAP's footer (the server stopped mid-task, or the file was cut). Its "
            f"{len(recording.frames)} whole frames can be replayed with --partial"
        )
    if not recording.frames:
        raise RecordingError(f"{name} holds no whole frame: nothing to replay")


def _copy_database(src: Path, dst: Path) -> None:
    """A consistent copy of ``src`` (SQLite's online backup: safe while a server writes it)."""
    source = sqlite3.connect(str(src))
    target = sqlite3.connect(str(dst))
    try:
        source.backup(target)
    except sqlite3.DatabaseError as exc:
        raise RecordingError(f"{src} is not a teachrepeat database: {exc}") from None
    finally:
        target.close()
        source.close()


def _find_tour(repo: Repo, recording: Recording) -> int:
    """The tour of ``repo`` the recording was made on: the recorded id when its fingerprint
    matches, else any tour with the recorded fingerprint."""
    meta = recording.meta
    tour_id, fingerprint = int(meta["tour"]), meta["fingerprint"]
    tours = [t for t, *_ in repo.tours(None)]
    ordered = sorted(tours, key=lambda t: t.id != tour_id)
    for tour in ordered:
        if tour_fingerprint(repo.graph(tour.id)) == fingerprint:
            return tour.id
    here = next((t for t in tours if t.id == tour_id), None)
    recorded = recording.tour or {}
    what = (
        f"tour {tour_id} {meta.get('tour_name', '')!r} ({len(recorded.get('locations', []))} "
        f"places, {len(recorded.get('edges', []))} paths, fingerprint {fingerprint})"
    )
    there = (
        f"its tour {tour_id} is {here.name!r}, taught differently"
        if here is not None
        else f"it has no tour {tour_id}"
    )
    raise RecordingError(
        f"{recording.path.name} was recorded against {what}, and this database has no tour "
        f"with that fingerprint ({there}; a tour taught further since has another): replay "
        "with the database it was recorded with (--db PATH)"
    )


def _replay_on(
    recording: Recording, db: Path, settings: dict[str, Any], tolerance: Tolerance
) -> tuple[ReplayReport, Timing]:
    from server.imaging import ImageLimits
    from server.navigation import NavigationParams
    from server.security import hash_token, new_token
    from server.services.navigation import NavigationService
    from server.storage.repo import Repo
    from server.tuning import changed, tuned

    meta = recording.meta
    recorded = json.loads(meta.get("navigation_overrides") or "{}")
    try:
        params = tuned(NavigationParams(), {**recorded, **settings})
    except ValueError as exc:
        raise RecordingError(f"navigation setting: {exc}") from None
    repo = Repo(db)
    clock = _Clock(float(meta.get("started_at") or recording.frames[0].wall))
    service = NavigationService(repo, ImageLimits(max_bytes=1 << 31), params, clock=clock)
    capture = _Capture(params.motion.depth_fov_deg)
    service.observers.append(capture)
    timing = Timing(realtime_fps=recording.realtime_fps())
    try:
        tour_id = _find_tour(repo, recording)
        robot = _fresh_robot(repo, repo.tour(tour_id).household_id, hash_token(new_token()))
        goal = meta["goal"]
        service.goto(robot, schemas.GotoRequest(location=goal, tour=tour_id))
        _start_belief(service, robot, recording)
        started = time.perf_counter()
        for frame in recording.frames:
            clock.now = frame.wall
            frame_meta = schemas.FrameMeta(
                timestamp=frame.timestamp,
                v=frame.v,
                w=frame.w,
                depth=None if frame.depth is None else list(frame.depth),
            )
            service.frame(robot, frame.jpeg, frame_meta)
        timing.seconds = time.perf_counter() - started
        timing.frames = len(recording.frames)
        state = service.state(robot)
    finally:
        service.close()
        repo.close()
    report = ReplayReport(
        file=str(recording.path),
        robot=meta.get("robot", ""),
        goal=goal,
        tour=int(meta["tour"]),
        tour_used=tour_id,
        settings=changed(params, NavigationParams()),
        complete=recording.complete,
        frames_recorded=len(recording.frames),
        frames_replayed=len(capture.frames),
        task_recorded=recording.frames[-1].compared().get("task_state"),
        task_replayed=None if state is None or state.task is None else state.task.state,
    )
    for frame, again in zip(recording.frames, capture.frames, strict=True):
        found = tuple(differences(frame.compared(), again, tolerance=tolerance))
        if found:
            report.differing.append(FrameDifference(frame.index, frame.timestamp, found))
    return report, timing


class _Clock:
    """The server's clock during a replay: the recorded time of the frame being replayed."""

    def __init__(self, now: float) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


def _fresh_robot(repo: Repo, household: int, token_hash: str) -> str:
    """A robot name not used in the copy, registered in ``household``."""
    name, n = REPLAY_ROBOT, 0
    while repo.robot_exists(name):
        n += 1
        name = f"{REPLAY_ROBOT}-{n}"
    repo.add_robot(name, token_hash, household)
    return name


def _start_belief(service: NavigationService, robot: str, recording: Recording) -> None:
    """Start from the recorded belief when the task did not start from the prior."""
    blob = recording.start_belief
    session = service.session(robot)
    if blob is None or session is None:
        return
    belief = np.frombuffer(blob, dtype="<f8").astype(np.float64)
    if belief.shape != (session.runtime.model.n_fine,):
        raise RecordingError(
            f"{recording.path.name}'s starting belief has {belief.size} states, the tour "
            f"{session.runtime.model.n_fine}: it was recorded against another tour"
        )
    memory = recording.start_memory
    try:
        restored = None if memory is None else TrackerMemory.from_dict(memory)
    except BeliefError as exc:
        raise RecordingError(f"{recording.path.name}'s starting {exc}") from None
    session.tracker.set_belief(belief, restored)


def differences(
    recorded: Any, replayed: Any, *, tolerance: Tolerance, path: str = ""
) -> Iterator[Difference]:
    """Where two JSON values differ (:meth:`Tolerance.equal` decides for every leaf), as
    paths."""
    if isinstance(recorded, dict) and isinstance(replayed, dict):
        for key in sorted(set(recorded) | set(replayed)):
            sub = f"{path}.{key}" if path else str(key)
            if key not in recorded or key not in replayed:
                yield Difference(sub, recorded.get(key), replayed.get(key))
            else:
                yield from differences(recorded[key], replayed[key], tolerance=tolerance, path=sub)
    elif isinstance(recorded, list) and isinstance(replayed, list):
        if len(recorded) != len(replayed):
            yield Difference(f"{path} (length)", len(recorded), len(replayed))
        for k, (a, b) in enumerate(zip(recorded, replayed, strict=False)):
            yield from differences(a, b, tolerance=tolerance, path=f"{path}[{k}]")
    elif not tolerance.equal(path, recorded, replayed):
        yield Difference(path, recorded, replayed)


def _number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool)


def _short(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    text = json.dumps(value) if not isinstance(value, str) else repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
