"""Navigation: "go to the kitchen", each frame answered with a motion command.

Holds one :class:`TourRuntime` per tour (rebuilt when teaching changes the tour) and one
:class:`RobotSession` per robot. The task and a belief snapshot are persisted, so a restarted
server resumes a navigation where it was instead of starting from a uniform belief.
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
import time
from collections.abc import Callable

import numpy as np

from server import schemas
from server.belief.tracker import BeliefError, BeliefSummary, TrackerMemory
from server.domain import TourGraph
from server.errors import Conflict, DomainError, Invalid, NotFound
from server.imaging import ImageLimits, decode_jpeg
from server.navigation import Command, NavigationParams, Task, TaskState, TourRuntime
from server.navigation.pathtrack import PathEstimate
from server.session import RobotSession, StepRecord
from server.storage.repo import NavigationRow, Repo
from server.vision.features import FeatureParams, ImageFeatures, extract
from server.vision.learning import learn_weights

log = logging.getLogger(__name__)

BELIEF_SNAPSHOT_S = 1.0
"""Seconds of robot time (the frames' timestamps) between two persisted belief snapshots of a
navigating robot: which frames are saved depends on the frames alone, not on how fast this
machine answered them, so a restart resumes from the same belief every time."""
PREBUILD_DELAY_S = 1.0
"""After teaching changes a tour, wait this long for more changes before preparing it."""
STAMP_CHECK_S = 1.0
"""Seconds between two looks at whether another server process on the same database changed a
tour in use (:meth:`Repo.tour_stamp`; several processes behind HAProxy, docs/scale.md). A goto
always looks."""


class NavigationObserver:
    """Told of every task and every step, under the robot's session lock (so in order), by
    :class:`NavigationService`: the recordings (:mod:`server.recording`) and the replay.
    Each method does nothing here; an observer overrides those it needs. A method that raises
    is logged and never fails the robot's request."""

    def task_started(
        self, robot: str, session: RobotSession, tour_id: int, *, record: bool | None, resumed: bool
    ) -> None:
        """``session`` has a new task (``goto``), or resumed one after a restart (``resumed``);
        ``record`` is the task's own recording choice (``None``: the server's setting)."""

    def stepped(
        self,
        robot: str,
        session: RobotSession,
        step: StepRecord,
        result: schemas.NavigationFrameResult,
        meta: schemas.FrameMeta,
        wall: float,
    ) -> None:
        """One frame was answered: what the step saw and decided, and the answer sent."""

    def task_ended(self, robot: str, task: schemas.TaskPublic) -> None:
        """The task is no longer underway (arrived or failed in a step, stopped, replaced by
        a new goal, or failed by the silence watchdog)."""


class NavigationService:
    def __init__(
        self,
        repo: Repo,
        limits: ImageLimits,
        params: NavigationParams | None = None,
        *,
        is_teaching: Callable[[str], bool] = lambda robot: False,
        clock: Callable[[], float] = time.time,
        concurrent_steps: int = 1,
        shared_store: bool = False,
    ) -> None:
        """``concurrent_steps``: frames turned into a command at once over all robots
        (features, belief, command); more wait their turn. Decoding the JPEG and building a
        tour's runtime are not counted, so a large frame or a robot whose tour is being
        prepared does not hold up the others. ``shared_store``: other server processes write
        to the same database (``serve --workers``), so a tour may change without this process
        being told; its stamp is then compared (:meth:`Repo.tour_stamp`). A single process is
        told of every change and never looks."""
        if concurrent_steps < 1:
            raise ValueError("concurrent_steps must be at least 1")
        self.repo = repo
        self.shared_store = shared_store
        self.limits = limits
        self.params = params if params is not None else NavigationParams()
        self.is_teaching = is_teaching
        self.clock = clock
        self._steps = threading.BoundedSemaphore(concurrent_steps)
        self._runtimes: dict[int, TourRuntime] = {}
        self._changes: dict[int, int] = {}  # tour_changed calls per tour
        self._built_from: dict[int, int] = {}  # the tour_changed count each runtime was built at
        self._stamps: dict[int, tuple[int, ...]] = {}  # the tour_stamp each runtime was built at
        self._stamp_checked: dict[int, float] = {}  # monotonic time of the last look
        self._sessions: dict[str, RobotSession] = {}
        self._tour_of: dict[str, int] = {}
        self._snapshot_at: dict[str, float] = {}  # robot time of each robot's last snapshot
        self._lock = threading.RLock()
        self._build_locks: dict[int, threading.Lock] = {}
        self._due: dict[int, float] = {}
        self._wake = threading.Event()
        self._closed = False
        self._worker: threading.Thread | None = None
        self.observers: list[NavigationObserver] = []

    def _tell(self, call: Callable[[NavigationObserver], None]) -> None:
        """``call(observer)`` for every observer; an observer's error is logged, never raised."""
        for observer in self.observers:
            try:
                call(observer)
            except Exception:
                log.exception("navigation observer %s failed", type(observer).__name__)

    def _ended(self, robot: str, task: Task) -> None:
        ended = task_public(task, self._tour_of[robot])
        self._tell(lambda o: o.task_ended(robot, ended))

    def close(self) -> None:
        """Stop the background builder."""
        self._closed = True
        self._wake.set()
        if self._worker is not None:
            self._worker.join(timeout=5)

    # --- tours ----------------------------------------------------------------------------

    def tour_changed(self, tour_id: int) -> None:
        """Teaching changed ``tour_id``: its runtime is stale. A background thread prepares the
        new one (features of the new images, weights) once the changes pause, so that a
        ``goto`` right after teaching does not wait for it."""
        with self._lock:
            self._changes[tour_id] = self._changes.get(tour_id, 0) + 1
            self._due[tour_id] = time.monotonic() + PREBUILD_DELAY_S
            if self._worker is None and not self._closed:
                self._worker = threading.Thread(
                    target=self._prebuild_forever, name="tour-prebuild", daemon=True
                )
                self._worker.start()
        self._wake.set()

    def _prebuild_forever(self) -> None:
        while not self._closed:
            with self._lock:
                now = time.monotonic()
                ready = [t for t, due in self._due.items() if due <= now]
                for t in ready:
                    del self._due[t]
                wait = min((due - now for due in self._due.values()), default=None)
            for tour_id in ready:
                with contextlib.suppress(DomainError):  # e.g. a tour with no places yet
                    self.runtime(tour_id)
            self._wake.wait(timeout=wait)
            self._wake.clear()

    def runtime(self, tour_id: int, *, wait: bool = True) -> TourRuntime:
        """The runtime of ``tour_id``, built (and its features extracted) on first use and
        again after the tour changed. With ``wait`` (a new task) a build under way is waited
        for; without (a step of a task under way) the previous runtime is returned meanwhile,
        and the session moves to the new one at a later step."""
        self._check_stamp(tour_id, always=wait)
        with self._lock:
            rt = self._runtimes.get(tour_id)
            build_lock = self._build_locks.setdefault(tour_id, threading.Lock())
            if rt is not None and (self._is_current(tour_id) or (not wait and build_lock.locked())):
                return rt
        with build_lock:
            with self._lock:
                rt = self._runtimes.get(tour_id)
                if rt is not None and self._is_current(tour_id):
                    return rt
                changes = self._changes.get(tour_id, 0)
            stamp = self.repo.tour_stamp(tour_id)  # before: a change meanwhile is seen later
            rt = self._build(tour_id, version=0 if rt is None else rt.version + 1)
            with self._lock:
                self._stamps[tour_id] = stamp
                # current only if the tour did not change while it was built; a caller that
                # comes during the build waits for it instead of taking the previous runtime
                self._runtimes[tour_id] = rt
                self._built_from[tour_id] = changes
            return rt

    def latest_runtime(self, tour_id: int) -> TourRuntime:
        """The tour's runtime as last built, even when the tour changed since (its rebuild is
        due in the background, :meth:`tour_changed`): for work that must not wait for a build,
        such as asking questions while teaching. Built now only when there is none yet."""
        with self._lock:
            rt = self._runtimes.get(tour_id)
        return rt if rt is not None else self.runtime(tour_id)

    def _check_stamp(self, tour_id: int, *, always: bool) -> None:
        """Whether another process changed the tour since its runtime was built (at most every
        :data:`STAMP_CHECK_S` unless ``always``); if so, as if teaching here had changed it."""
        if not self.shared_store:
            return
        now = time.monotonic()
        with self._lock:
            built = self._stamps.get(tour_id)
            last = self._stamp_checked.get(tour_id)
            if built is None or (not always and last is not None and now - last < STAMP_CHECK_S):
                return
            if not self._is_current(tour_id):  # a rebuild is due anyway; its stamp is newer
                return
            self._stamp_checked[tour_id] = now
        stamp = self.repo.tour_stamp(tour_id)
        if stamp == built:
            return
        with self._lock:
            if self._stamps.get(tour_id) != built:  # another thread noticed it first
                return
            self._stamps[tour_id] = stamp
            self._changes[tour_id] = self._changes.get(tour_id, 0) + 1
        log.info("tour %d changed in another server process: preparing it again", tour_id)

    def _is_current(self, tour_id: int) -> bool:
        """Whether the stored runtime was built after the tour's last change (under the lock)."""
        return self._built_from.get(tour_id) == self._changes.get(tour_id, 0)

    def _build(self, tour_id: int, *, version: int) -> TourRuntime:
        graph = self.repo.graph(tour_id)
        if graph.n_locations == 0:
            raise Conflict(f"tour {tour_id} has no places yet; teach it first")
        rt = TourRuntime(
            graph, self._features([int(i) for i in graph.image_ids]), self.params, version=version
        )
        rt.taught_pixels = self._pixels([int(i) for i in graph.image_ids])
        depths = self.repo.depths([int(i) for i in graph.image_ids])
        rt.taught_depth = {
            k: depths[int(i)] for k, i in enumerate(graph.image_ids) if int(i) in depths
        }
        learned = self._weights(tour_id, rt)
        chosen = self.params.signature_weights
        rt.index.set_weights(learned if chosen is None else np.asarray(chosen, np.float64))
        if len(rt.index.model_weights()) > 1:
            rt.error_levels()  # the change evidence's scale, before the first frame needs it
        self._distinctiveness(tour_id, rt)
        return rt

    def _distinctiveness(self, tour_id: int, rt: TourRuntime) -> None:
        """The images' entropies: stored when computed over this very set of images, else
        computed now (one engine query per sampled image) and stored."""
        graph = rt.graph
        stored = graph.has_entropy and self.repo.entropy_images(tour_id) == graph.n_images
        if stored:
            return
        entropy = rt.distinctiveness()
        rt.attach_distinctiveness(entropy)
        ids = [int(i) for i in graph.image_ids]
        self.repo.set_entropies(tour_id, list(zip(ids, entropy.tolist(), strict=True)))

    def _pixels(self, image_ids: list[int]) -> Callable[[int], np.ndarray | None]:
        """Reads the pixels of ``image_ids[k]`` from the store (for docking's zoom levels,
        :meth:`TourRuntime.taught_levels`); ``None`` for an image no longer stored."""

        def read(k: int) -> np.ndarray | None:
            try:
                return decode_jpeg(self.repo.image_jpeg(image_ids[k]), self.limits)[0]
            except DomainError:  # the image is gone (NotFound) or unreadable
                return None

        return read

    def _features(self, image_ids: list[int]) -> list[ImageFeatures]:
        """Features of the images ``image_ids``, in that order: stored ones are reused,
        missing ones (or ones extracted with other parameters) are extracted and stored."""
        ids = image_ids
        stored = self.repo.features(ids)
        out: list[ImageFeatures] = []
        fresh: list[tuple[int, bytes]] = []
        fp = self.params.features
        for image_id in ids:
            feats = _stored_features(stored.get(image_id), fp)
            if feats is None:
                image, _, _ = decode_jpeg(self.repo.image_jpeg(image_id), self.limits)
                feats = extract(image, fp)
                fresh.append((image_id, feats.to_bytes()))
            out.append(feats)
        if fresh:
            self.repo.set_features(fresh)
        return out

    def _weights(self, tour_id: int, rt: TourRuntime) -> np.ndarray:
        """The tour's signature weights: stored when learned on this very tour, else learned
        now (the engine's documented defaults for tours too small to learn from) and stored."""
        blob, n_images = self.repo.tour_weights(tour_id)
        if blob is not None and n_images == rt.graph.n_images:
            return np.frombuffer(blob, dtype=np.float32).astype(np.float64)
        stored = np.asarray(learn_weights(rt.index, params=self.params.engine), np.float32)
        self.repo.set_tour_weights(tour_id, stored.tobytes(), rt.graph.n_images)
        # as stored: the first build answers bit for bit as every later one
        return stored.astype(np.float64)

    # --- sessions -------------------------------------------------------------------------

    def session(self, robot: str) -> RobotSession | None:
        """The robot's live session; after a restart, rebuilt from the persisted snapshot."""
        with self._lock:
            s = self._sessions.get(robot)
        if s is not None:
            tour_id = self._tour_of[robot]
            rt = self.runtime(tour_id, wait=False)
            if rt is not s.runtime:
                with s.lock:
                    s.rebase(rt)
            return s
        row = self.repo.navigation(robot)
        if row is None:
            return None
        return self._resume(row)

    def _resume(self, row: NavigationRow) -> RobotSession:
        rt = self.runtime(row.tour_id)
        session = RobotSession(row.robot, rt)
        if row.belief is not None and row.belief_images == rt.graph.n_images:
            belief = np.frombuffer(row.belief, dtype=np.float32).astype(np.float64)
            if belief.shape == (rt.model.n_fine,) and belief.sum() > 0:
                session.tracker.set_belief(belief, _memory(row.belief_memory))
        goal = _location_index(rt.graph, row.goal_location_id)
        if goal is not None:
            session.resume_task(
                Task(
                    id=row.task_id,
                    goal=goal,
                    goal_name=rt.graph.locations[goal].name,
                    started_at=row.started_at,
                    state=TaskState(row.state),
                    reason=row.reason,
                    ended_at=row.ended_at,
                    steps=row.steps,
                )
            )
            if row.state == TaskState.UNDERWAY:
                session.last_frame_wall = self.clock()  # the silence clock restarts
        with self._lock:
            self._sessions[row.robot] = session
            self._tour_of[row.robot] = row.tour_id
        if session.task is not None and session.task.underway:
            with session.lock:
                self._tell(
                    lambda o: o.task_started(
                        row.robot, session, row.tour_id, record=None, resumed=True
                    )
                )
        return session

    def tour_of(self, robot: str) -> int:
        """The tour the robot's live session navigates (KeyError when it has none)."""
        with self._lock:
            return self._tour_of[robot]

    def is_navigating(self, robot: str) -> bool:
        """Whether the robot has a task underway (the persisted row answers for a robot with no
        live session, without resuming it)."""
        with self._lock:
            live = self._sessions.get(robot)
        if live is not None:
            return live.task is not None and live.task.underway
        row = self.repo.navigation(robot)
        return row is not None and row.state == TaskState.UNDERWAY

    def _persist(self, session: RobotSession, *, belief: bool) -> None:
        task = session.task
        if task is None:
            return
        rt = session.runtime
        tour_id = self._tour_of[session.robot]
        snapshot = session.tracker.belief.astype(np.float32).tobytes() if belief else None
        memory = json.dumps(session.tracker.memory().to_dict()) if belief else None
        self.repo.save_navigation(
            NavigationRow(
                robot=session.robot,
                tour_id=tour_id,
                task_id=task.id,
                goal_location_id=rt.graph.locations[task.goal].id,
                state=task.state.value,
                reason=task.reason,
                started_at=task.started_at,
                ended_at=task.ended_at,
                steps=task.steps,
                belief=snapshot,
                belief_images=rt.graph.n_images if belief else None,
                belief_memory=memory,
            )
        )
        if belief and session.last_timestamp is not None:
            self._snapshot_at[session.robot] = session.last_timestamp

    # --- requests -------------------------------------------------------------------------

    def goto(self, robot: str, body: schemas.GotoRequest) -> schemas.TaskPublic:
        if self.is_teaching(robot):
            raise Conflict(f"robot {robot!r} is teaching; finish or abort teaching first")
        household = self.repo.robot_household(robot)
        tour_id = body.tour if body.tour is not None else self._default_tour(robot, household)
        self.repo.tour(tour_id, household)  # 404 when unknown or another household's
        places = {loc.name: loc for loc in self.repo.locations(tour_id)}
        place = places.get(body.location)
        if place is None:
            raise NotFound(
                f"tour {tour_id} has no place named {body.location!r}; its places are "
                f"{list(places)}"
            )
        if not place.image_ids:
            raise Conflict(
                f"place {body.location!r} of tour {tour_id} has no image, so the robot could "
                "not recognise arriving there. Give it one: with the robot at the place, start "
                f"teaching tour {tour_id} (POST /robots/{robot}/teach/start), mark "
                f"{body.location!r} (POST /robots/{robot}/teach/locations), post a spin image "
                f"(POST /robots/{robot}/teach/spin) and finish"
            )
        location_id = place.id
        rt = self.runtime(tour_id)
        goal = _location_index(rt.graph, location_id)
        if goal is None:  # pragma: no cover - the runtime was just built
            raise NotFound(f"no place {body.location!r} in the tour")
        session = self.session(robot)  # live, or resumed from the persisted snapshot
        if session is None or self._tour_of.get(robot) != tour_id:
            session = RobotSession(robot, rt)
            with self._lock:
                self._sessions[robot] = session
                self._tour_of[robot] = tour_id
        now = self.clock()
        with session.lock:
            if session.task is not None and session.task.underway:
                session.task.end(
                    TaskState.CANCELLED, f"replaced by a new goal: {body.location}", now
                )
                replaced = task_public(session.task, tour_id)
                self._tell(lambda o: o.task_ended(robot, replaced))
            task = Task(
                id=self.repo.next_task_id(), goal=goal, goal_name=body.location, started_at=now
            )
            session.start_task(task)
            session.last_frame_wall = now
            self._persist(session, belief=True)
            self._tell(
                lambda o: o.task_started(robot, session, tour_id, record=body.record, resumed=False)
            )
            return task_public(task, tour_id)

    def _default_tour(self, robot: str, household: int | None) -> int:
        if robot in self._tour_of:
            return self._tour_of[robot]
        row = self.repo.navigation(robot)
        if row is not None:
            return row.tour_id
        tours = self.repo.tours(household)
        if len(tours) == 1:
            return tours[0][0].id
        # the request is well formed; what is missing is a tour the robot used before
        raise Conflict(
            f"say which tour robot {robot!r} navigates in: it has not navigated yet and there "
            f"are {len(tours)} tours; pass 'tour' (GET /tours lists them)"
        )

    def stop(self, robot: str) -> schemas.TaskPublic:
        session = self.session(robot)
        task = None if session is None else session.task
        if session is None or task is None or not task.underway:
            raise Conflict(f"robot {robot!r} has no navigation underway; nothing to stop")
        with session.lock:
            task.end(TaskState.CANCELLED, "stopped on request", self.clock())
            self._persist(session, belief=True)
            public = task_public(task, self._tour_of[robot])
            self._tell(lambda o: o.task_ended(robot, public))
            return public

    def frame(
        self, robot: str, data: bytes, meta: schemas.FrameMeta
    ) -> schemas.NavigationFrameResult:
        session = self.session(robot)
        if session is None:
            raise Conflict(
                f"robot {robot!r} is not teaching or navigating; start with "
                f"POST /robots/{robot}/teach/start or POST /robots/{robot}/goto"
            )
        image, _, _ = decode_jpeg(data, self.limits)  # outside the slot: any size up to limits
        with session.lock, self._steps:  # one robot's frames in order; a few steps at once
            if session.last_timestamp is not None and meta.timestamp < session.last_timestamp:
                raise Invalid(
                    f"timestamp {meta.timestamp} goes backwards: the previous frame was at "
                    f"{session.last_timestamp}. Send frames in capture order"
                )
            before = None if session.task is None else session.task.state
            now = self.clock()
            depth = None if meta.depth is None else np.asarray(meta.depth, dtype=np.float64)
            record = session.step(
                image,
                timestamp=meta.timestamp,
                v=meta.v,
                w=meta.w,
                depth=depth,
                wall=now,
                jpeg=data,
            )
            task = session.task
            changed = task is not None and task.state != before
            saved = self._snapshot_at.get(robot)
            due = saved is None or meta.timestamp - saved >= BELIEF_SNAPSHOT_S
            if task is not None and (changed or (task.underway and due)):
                self._persist(session, belief=True)
            public = None if task is None else task_public(task, self._tour_of[robot])
            result = frame_result(
                record, session.runtime.graph, public, ttl_s=self.params.motion.ttl_s
            )
            self._tell(lambda o: o.stepped(robot, session, record, result, meta, now))
            if changed and task is not None and public is not None and not task.underway:
                self._tell(lambda o: o.task_ended(robot, public))
            return result

    def state(self, robot: str) -> schemas.NavigationState | None:
        session = self.session(robot)
        if session is None:
            return None
        with session.lock:
            summary = session.tracker.last_summary
            return schemas.NavigationState(
                tour=self._tour_of[robot],
                task=None
                if session.task is None
                else task_public(session.task, self._tour_of[robot]),
                belief=belief_public(summary, session.runtime.graph),
                last_command=None
                if session.last_command is None
                else command_public(
                    session.runtime.graph,
                    session.last_command,
                    session.navigator.previous_reason,
                    ttl_s=self.params.motion.ttl_s,
                ),
            )

    def sweep(self) -> int:
        """Fail the tasks of robots that went silent; returns how many failed."""
        now = self.clock()
        with self._lock:
            sessions = list(self._sessions.values())
        failed = 0
        for session in sessions:
            with session.lock:
                if session.check_silence(now):
                    self._persist(session, belief=True)
                    if session.task is not None:
                        self._ended(session.robot, session.task)
                    failed += 1
        return failed

    def sessions(self) -> dict[str, RobotSession]:
        """A copy of the live sessions (for the dashboard)."""
        with self._lock:
            return dict(self._sessions)


def _memory(stored: str | None) -> TrackerMemory | None:
    """The tracker memory saved with a belief snapshot (``None``: none saved, as in rows from
    before migration 8, or unreadable: the tracker then starts its memory afresh)."""
    if stored is None:
        return None
    try:
        return TrackerMemory.from_dict(json.loads(stored))
    except (ValueError, BeliefError):
        log.warning("a stored tracker memory could not be read; the tracker starts it afresh")
        return None


def _location_index(graph: TourGraph, location_id: int) -> int | None:
    for k, loc in enumerate(graph.locations):
        if loc.id == location_id:
            return k
    return None


def frame_result(
    record: StepRecord,
    graph: TourGraph,
    task: schemas.TaskPublic | None,
    *,
    ttl_s: float,
) -> schemas.NavigationFrameResult:
    """The answer to a navigating robot's frame, from what its step saw and decided."""
    votes = (
        {}
        if record.decision is None
        else {str(k): float(v) for k, v in record.decision.votes.items()}
    )
    reason = None if record.outcome is None else record.outcome.reason
    return schemas.NavigationFrameResult(
        mode="navigating",
        command=command_public(graph, record.command, reason, ttl_s=ttl_s),
        task=task,
        belief=belief_public(record.summary, graph),
        votes=votes,
        path=None if record.path is None else path_public(record.path, graph),
    )


def path_public(est: PathEstimate, graph: TourGraph) -> schemas.PathPublic:
    """The path tracker's estimate as the robot and the dashboard receive it."""
    return schemas.PathPublic(
        edge=graph.edges[est.edge].id,
        along_m=round(est.along_m, 4),
        lateral_m=round(est.lateral_m, 4),
        heading_error=round(est.heading_error, 4),
        sigma_lateral_m=round(est.sigma_lateral, 4),
        sigma_along_m=round(est.sigma_along, 4),
        sigma_heading=round(est.sigma_heading, 4),
        locked=est.locked,
        length_m=round(est.length_m, 4),
        image_id=int(graph.image_ids[est.image]),
        x=round(float(est.pose[0]), 4),
        y=round(float(est.pose[1]), 4),
        theta=round(float(est.pose[2]), 4),
    )


def command_public(
    graph: TourGraph, command: Command, reason: str | None, *, ttl_s: float
) -> schemas.MotionCommand:
    """A motion command as the robot receives it (storage ids of its edge and target image)."""
    edge = command.action.edge
    return schemas.MotionCommand(
        v=command.v,
        w=command.w,
        ttl_s=ttl_s,
        action=command.action.kind.value,
        edge=None if edge is None else graph.edges[edge].id,
        target_image_id=None
        if command.target_image is None
        else int(graph.image_ids[command.target_image]),
        behaviour=command.behaviour,
        reason=reason,
    )


def task_public(task: Task, tour_id: int) -> schemas.TaskPublic:
    return schemas.TaskPublic(
        id=task.id,
        tour=tour_id,
        goal=task.goal_name,
        state=task.state.value,
        reason=task.reason,
        started_at=task.started_at,
        ended_at=task.ended_at,
        steps=task.steps,
    )


def state_public(graph: TourGraph, state: int, probability: float) -> schemas.StateProbability:
    if state < graph.n_locations:
        loc = graph.locations[state]
        return schemas.StateProbability(
            kind="location", id=loc.id, name=loc.name, probability=probability
        )
    edge = graph.edges[state - graph.n_locations]
    return schemas.StateProbability(
        kind="edge", id=edge.id, name=graph.state_name(state), probability=probability
    )


def belief_public(summary: BeliefSummary, graph: TourGraph) -> schemas.BeliefPublic:
    top = [state_public(graph, s, p) for s, p in summary.top_states]
    localised = None
    if summary.localised and summary.localised_state is not None:
        s = summary.localised_state
        localised = state_public(graph, s, float(summary.state[s]))
    return schemas.BeliefPublic(
        top=top,
        entropy=summary.entropy,
        localised=summary.localised,
        localised_state=localised,
        appearance=[round(float(x), 4) for x in summary.appearance],
        light_change=round(float(summary.light_change), 4),
    )


def _stored_features(blob: bytes | None, params: FeatureParams) -> ImageFeatures | None:
    """The stored features of an image when they can be used with ``params``; ``None`` (so the
    caller re-extracts) when missing, written by another format version, or extracted with
    other settings."""
    if blob is None:
        return None
    try:
        feats = ImageFeatures.from_bytes(blob)
    except ValueError:
        return None
    return feats if params.matches(feats) else None
