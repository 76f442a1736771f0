"""The recorder: an observer of the teaching and navigation services that writes MCAP files.

It is told of every task and step by :class:`~server.services.navigation.NavigationService` and
:class:`~server.services.teaching.TeachingService` (their observer protocols), turns what it is
told into messages (:mod:`server.recording.messages`) in the robot's request thread, and hands
them to one writer thread, which does all the file work (JSON, base64, writing, flushing), so a
robot's step never waits for the disk. If the disk cannot keep up, frames are dropped (counted,
and said in the file's log), never queued without bound.

Which tasks are recorded: each task's own ``record`` (``POST .../goto``, ``.../teach/start``),
else the server's setting (``serve --record DIR``). A task resumed after a restart, or teaching
carried on after one, follows the server's setting (a task's own choice is not persisted).
Secrets never reach a file: what is written is the robot's name, the tour, the frames and what
the server made of them; no token, no password, no request header.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from server import schemas
from server.navigation import NavigationParams
from server.recording import topics
from server.recording.mcapfile import FORMAT_VERSION, McapFile
from server.recording.messages import (
    Message,
    Scene,
    log_message,
    navigation_frame,
    teaching_frame,
    tour_message,
)
from server.recording.store import RecordingFile, RecordingStore
from server.services.navigation import NavigationObserver
from server.services.teaching import TeachingObserver
from server.tuning import changed

if TYPE_CHECKING:
    from server.session import RobotSession, StepRecord
    from server.storage.repo import Repo

log = logging.getLogger(__name__)

QUEUE_ITEMS = 512
"""Writer jobs waiting at most (about 50 s of one robot at 10 frames/s); more are dropped."""


@dataclass
class _Recording:
    """One recording being made (request threads own everything but ``file``)."""

    robot: str
    path: Path
    task: int | None  # None: teaching
    tour: int
    index: int = 0  # frames handed to the writer
    behaviour: str | None = None  # of the last frame (a change is logged)
    dropped: int = 0
    full: bool = False
    scene: Scene | None = None
    file: McapFile | None = field(default=None, repr=False)  # the writer thread's


class Recorder(NavigationObserver, TeachingObserver):
    """Records teaching tours and navigation tasks into ``store`` (see the module docstring).

    ``record_all``: the server's setting. ``params``: the navigation settings the server runs
    with; a recording keeps the ones that differ from the defaults, for replay. ``clock``: wall
    clock, s."""

    def __init__(
        self,
        store: RecordingStore,
        repo: Repo,
        *,
        record_all: bool = False,
        params: NavigationParams | None = None,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.store = store
        self.repo = repo
        self.record_all = record_all
        self.params = params if params is not None else NavigationParams()
        self.overrides = changed(self.params, NavigationParams())
        self.clock = clock
        self._open: dict[str, _Recording] = {}
        self._closing: set[Path] = set()  # ended, not yet finished by the writer
        self._lock = threading.Lock()
        self._jobs: queue.Queue[Callable[[], None] | None] = queue.Queue(QUEUE_ITEMS)
        self._thread = threading.Thread(target=self._write_forever, name="recorder", daemon=True)
        self._thread.start()
        self._closed = False
        self.writer_cpu_s = 0.0  # CPU time the writer thread spent on jobs (for the benchmark)

    # --- what the API and the dashboard ask -----------------------------------------------

    def open_paths(self) -> set[Path]:
        """The files being written now (or ended and not yet finished)."""
        with self._lock:
            return {r.path for r in self._open.values()} | self._closing

    def recordings(self, robot: str) -> list[schemas.RecordingPublic]:
        """The robot's recordings (in its household's folder), newest first."""
        household = self._household(robot)
        opened = self.open_paths()
        return [
            r.public(open_now=r.path in opened) for r in self.store.files(household, robot=robot)
        ]

    def file(self, robot: str, name: str) -> RecordingFile:
        """The robot's recording ``name`` (404 for any other robot's or household's)."""
        return self.store.find(self._household(robot), robot, name)

    def wait_idle(self, timeout_s: float = 10.0) -> bool:
        """Wait until the writer has written everything handed to it so far."""
        done = threading.Event()
        self._put(done.set, essential=True)
        return done.wait(timeout_s)

    def close(self) -> None:
        """Finish every open recording (summary and footer) and stop the writer."""
        if self._closed:
            return
        with self._lock:
            robots = list(self._open)
        for robot in robots:
            self._finish(robot, "the server stopped")
        self._closed = True
        self._jobs.put(None)
        self._thread.join(timeout=30)

    # --- navigation -----------------------------------------------------------------------

    def task_started(
        self, robot: str, session: RobotSession, tour_id: int, *, record: bool | None, resumed: bool
    ) -> None:
        self._finish(robot, "a new task started")
        task = session.task
        if task is None or not (record if record is not None else self.record_all):
            return
        wall = self.clock()
        graph = session.runtime.graph
        tour = tour_message(graph, tour_id, self.repo.tour(tour_id).name)
        fresh = self.params.fresh_belief and not resumed
        meta = {
            "kind": "navigate",
            "task": str(task.id),
            "goal": task.goal_name,
            "resumed": json.dumps(resumed),
            "fresh": json.dumps(fresh),
        }
        rec = self._start(robot, tour_id, task.id, tour, meta, wall)
        rec.scene = Scene(graph)
        belief = None if fresh else session.tracker.belief.astype("<f8").tobytes()
        memory = None if fresh else session.tracker.memory().to_dict()
        public = schemas.TaskPublic(
            id=task.id,
            tour=tour_id,
            goal=task.goal_name,
            state=task.state.value,
            reason=task.reason,
            started_at=task.started_at,
            ended_at=task.ended_at,
            steps=task.steps,
        )
        first: list[Message] = [
            (topics.TOUR, tour),
            (topics.SCENE, rec.scene.tour(wall)),
            (
                topics.START,
                {"resumed": resumed, "fresh": fresh, "belief": belief, "memory": memory},
            ),
            (topics.TASK, public.model_dump()),
            log_message(
                wall,
                robot,
                f"task {task.id} to {task.goal_name} "
                + ("resumed after a restart" if resumed else "started"),
            ),
        ]
        self._write(rec, first, wall, frame=False)

    def stepped(
        self,
        robot: str,
        session: RobotSession,
        step: StepRecord,
        result: schemas.NavigationFrameResult,
        meta: schemas.FrameMeta,
        wall: float,
    ) -> None:
        rec = self._current(robot)
        if rec is None or result.task is None or rec.task != result.task.id:
            return
        if rec.full:
            rec.dropped += 1
            return
        graph = session.runtime.graph
        messages = list(
            navigation_frame(
                step,
                result,
                graph,
                meta,
                index=rec.index,
                wall=wall,
                depth_fov_deg=self.params.motion.depth_fov_deg,
            ).messages
        )
        extra: list[Message] = []
        behaviour = result.command.behaviour
        if behaviour != rec.behaviour:
            rec.behaviour = behaviour
            why = f": {result.command.reason}" if result.command.reason else ""
            extra.append(log_message(wall, robot, f"{behaviour}{why}"))
        if rec.scene is not None and rec.scene.graph is graph:
            fine = messages_position(messages)
            robot_scene = None if fine is None else rec.scene.robot(fine, wall)
            if robot_scene is not None:
                extra.append((topics.SCENE, robot_scene))
        rec.index += 1
        self._write(rec, extra + messages, wall, frame=True)

    def task_ended(self, robot: str, task: schemas.TaskPublic) -> None:
        rec = self._current(robot)
        if rec is None or rec.task != task.id:
            return
        wall = self.clock()
        why = f" ({task.reason})" if task.reason else ""
        ended = [
            (topics.TASK, task.model_dump()),
            log_message(wall, robot, f"task {task.id} to {task.goal} {task.state}{why}"),
        ]
        self._write(rec, ended, wall, frame=False)
        self._finish(robot, None)

    # --- teaching -------------------------------------------------------------------------

    def teaching_started(self, robot: str, tour_id: int, *, record: bool | None) -> None:
        self._finish(robot, "teaching started")
        if record if record is not None else self.record_all:
            self._start_teaching(robot, tour_id, "started")

    def teaching_image(
        self, robot: str, tour_id: int, data: bytes, meta: schemas.FrameMeta, *, spin: bool
    ) -> None:
        rec = self._current(robot)
        if rec is None and self.record_all:  # teaching carried on after a restart
            rec = self._start_teaching(robot, tour_id, "carried on after a restart")
        if rec is None or rec.task is not None or rec.tour != tour_id:
            return
        if rec.full:
            rec.dropped += 1
            return
        wall = self.clock()
        messages = teaching_frame(
            data,
            meta,
            index=rec.index,
            wall=wall,
            spin=spin,
            depth_fov_deg=self.params.motion.depth_fov_deg,
        )
        rec.index += 1
        self._write(rec, list(messages), wall, frame=True)

    def teaching_marked(self, robot: str, tour_id: int, result: schemas.MarkResult) -> None:
        rec = self._current(robot)
        if rec is None or rec.task is not None or rec.tour != tour_id:
            return
        made = "new place" if result.created else "known place"
        path = "" if result.edge is None else f", closing a path of {result.edge.image_count}"
        wall = self.clock()
        text = f"marked {made} {result.location.name}{path}"
        self._write(rec, [log_message(wall, robot, text)], wall, frame=False)

    def teaching_ended(
        self, robot: str, tour_id: int, ended: schemas.TeachingEnded, *, finished: bool
    ) -> None:
        rec = self._current(robot)
        if rec is None or rec.task is not None or rec.tour != tour_id:
            return
        wall = self.clock()
        graph = self.repo.graph(tour_id)
        how = "finished" if finished else f"aborted ({ended.discarded_images} images discarded)"
        last = [
            (topics.TOUR, tour_message(graph, tour_id, ended.tour.name)),
            log_message(wall, robot, f"teaching {how}: {graph.n_locations} places"),
        ]
        self._write(rec, last, wall, frame=False)
        self._finish(robot, None)

    # --- inner workings -------------------------------------------------------------------

    def _household(self, robot: str) -> int:
        household = self.repo.robot_household(robot)
        if household is None:
            from server.errors import NotFound

            raise NotFound(f"no robot named {robot!r}")
        return household

    def _current(self, robot: str) -> _Recording | None:
        with self._lock:
            return self._open.get(robot)

    def _start_teaching(self, robot: str, tour_id: int, how: str) -> _Recording:
        wall = self.clock()
        graph = self.repo.graph(tour_id)
        tour = tour_message(graph, tour_id, self.repo.tour(tour_id).name)
        rec = self._start(robot, tour_id, None, tour, {"kind": "teach"}, wall)
        first: list[Message] = [(topics.TOUR, tour)]
        if graph.n_locations:
            first.append((topics.SCENE, Scene(graph).tour(wall)))
        first.append(log_message(wall, robot, f"teaching tour {tour_id} {how}"))
        self._write(rec, first, wall, frame=False)
        return rec

    def _start(
        self,
        robot: str,
        tour_id: int,
        task: int | None,
        tour: dict[str, Any],
        meta: dict[str, str],
        wall: float,
    ) -> _Recording:
        household = self._household(robot)
        path = self.store.new_path(household, robot, tour_id, task, wall)
        rec = _Recording(robot=robot, path=path, task=task, tour=tour_id)
        metadata = {
            "format": str(FORMAT_VERSION),
            "robot": robot,
            "household": str(household),
            "tour": str(tour_id),
            "tour_name": str(tour["name"]),
            "fingerprint": str(tour["fingerprint"]),
            "started_at": repr(wall),
            "navigation_overrides": json.dumps(self.overrides, sort_keys=True),
            **meta,
        }
        with self._lock:
            self._open[robot] = rec
        max_bytes = self.store.retention.file_bytes

        def open_file() -> None:
            rec.file = McapFile(path, metadata=metadata, max_bytes=max_bytes)

        self._put(open_file, essential=True)
        return rec

    def _write(self, rec: _Recording, messages: list[Message], wall: float, *, frame: bool) -> None:
        log_ns = round(wall * 1e9)

        def write() -> None:
            f = rec.file
            if f is None or f.closed:
                return
            for topic, payload in messages:
                f.write(topic, payload, log_ns)
            if frame:
                f.end_frame()
                if f.full():
                    rec.full = True

        if not self._put(write, essential=not frame):
            rec.dropped += 1

    def _finish(self, robot: str, why: str | None) -> None:
        """Close ``robot``'s open recording (``why``: logged in it when it did not end with
        its task), then apply the retention limits."""
        with self._lock:
            rec = self._open.pop(robot, None)
            if rec is not None:
                self._closing.add(rec.path)
        if rec is None:
            return
        wall = self.clock()
        notes = []
        if why is not None:
            notes.append(log_message(wall, robot, f"recording ended: {why}", level=3))
        if rec.dropped:
            text = (
                f"{rec.dropped} frames not recorded (the file reached its size limit or the "
                "disk could not keep up)"
            )
            notes.append(log_message(wall, robot, text, level=3))
        if notes:
            self._write(rec, notes, wall, frame=False)

        def close() -> None:
            try:
                if rec.file is not None:
                    rec.file.close()
            finally:
                with self._lock:
                    self._closing.discard(rec.path)
            deleted = self.store.enforce(self.open_paths())
            if deleted:
                log.info("recordings deleted to keep within the limits: %d", len(deleted))

        self._put(close, essential=True)

    def _put(self, job: Callable[[], None], *, essential: bool) -> bool:
        """Hand ``job`` to the writer; a frame (not ``essential``) is dropped when the queue
        is full, anything else waits for room."""
        if self._closed:
            return False
        try:
            if essential:
                self._jobs.put(job, timeout=30)
            else:
                self._jobs.put_nowait(job)
        except queue.Full:
            return False
        return True

    def _write_forever(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None:
                return
            started = time.thread_time()
            try:
                job()
            except Exception:  # a full disk: the robot goes on, the recording may be cut
                log.exception("recording could not be written")
            self.writer_cpu_s += time.thread_time() - started


def messages_position(messages: list[Message]) -> int | None:
    """The most likely fine state in a frame's ``/belief`` message."""
    for topic, payload in messages:
        if topic == topics.BELIEF:
            return int(payload["position"]["fine"])
    return None
