"""Snapshots of what the server is doing, taken off the robots' hot path.

A :class:`Publisher` thread wakes at most ``hz`` times a second, reads the live navigation
sessions *without taking their locks* (``session.history[-1]`` and ``session.task`` are read as
they are: a step appends its record atomically), copies what the dashboard shows into an
immutable :class:`Snapshot`, keeps only the latest one and hands it to a sink (the dashboard's
renderer). A robot's step never waits for the dashboard: the only locks the publisher touches are
the navigation service's short registry lock (a dict copy) and the repository's connection lock
for a few tiny queries (robots, tours and teaching rows, cached stored images).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from server import schemas
    from server.domain import TourGraph
    from server.navigation.pathtrack import PathEstimate
    from server.services.container import Services
    from server.services.control import LiveFrame
    from server.session import RobotSession, Segment, StepRecord

FloatArray = npt.NDArray[np.float64]

log = logging.getLogger(__name__)

LISTS_EVERY_S = 1.0
"""Seconds between two reads of the robot and tour lists from the database."""


@dataclass(frozen=True)
class StepView:
    """What the last step of a navigating robot saw and decided (copied, immutable).

    Array shapes refer to the snapshot's ``graph``: ``state_belief`` is ``(n_states,)`` b(s)
    (locations then edges, sums to 1), ``fine_belief`` is ``(n_fine,)`` (one entry per location,
    then one per edge image; sums to 1), ``along_edge`` holds ``(n_images_e,)`` b(i | e) per edge.
    Image references are canonical image indices (``graph.image_ids[k]`` is the storage id).
    """

    index: int  # how many steps this session has taken when the record was made
    timestamp: float  # robot clock, s
    jpeg: bytes
    state_belief: FloatArray
    fine_belief: FloatArray
    along_edge: tuple[FloatArray, ...]
    top_states: tuple[tuple[int, float], ...]
    entropy: float  # nats
    localised: bool
    best_state: int  # the most likely upper state
    best_image: int | None  # best-matching stored image of ``best_state``
    best_similarity: float | None
    image_similarity: FloatArray  # (n_images,) similarity of the frame to every stored image
    action: str  # rotate_and_find_edge | navigate | explore | do_nothing
    action_edge: int | None
    behaviour: str  # what the motion layer is doing (server.navigation.BEHAVIOURS)
    reason: str | None  # why the winning behaviour chose the command (None without a task)
    target_image: int | None  # canonical image the robot homes on (Navigate)
    votes: dict[str, float]  # vote mass per action name, sums to 1 (empty when no task)
    active_edge: int | None
    v: float  # m/s
    w: float  # rad/s
    step_ms: float
    appearance: tuple[float, ...] = (1.0,)  # belief over the engine's appearance models
    light_change: float = 1.0  # the frame's change evidence (server.belief.appearance)
    model_weights: tuple[tuple[float, ...], ...] = ()  # each model's signature block weights
    path: PathEstimate | None = None  # the pose relative to the taught path being tracked


@dataclass(frozen=True)
class TaskView:
    """A navigation task as the dashboard shows it."""

    id: int
    goal: str
    state: str  # underway | arrived | failed | cancelled
    reason: str | None
    steps: int
    started_at: float


@dataclass(frozen=True)
class Snapshot:
    """Everything the dashboard draws for the selected robot, at one instant.

    ``graph_key`` changes exactly when the drawn graph changes (another tour, or teaching added
    places or paths), so the renderer rebuilds the scene only then.
    """

    taken_at: float  # wall clock, s
    robots: tuple[str, ...]
    tours: tuple[tuple[int, str], ...]  # (id, name), in id order
    robot: str | None
    mode: str  # idle | teaching | navigating
    tour_id: int | None
    tour_name: str | None
    bound: bool  # the robot is navigating or teaching this tour (not just browsing it)
    graph: TourGraph | None
    graph_key: tuple[object, ...]
    step: StepView | None = None
    task: TaskView | None = None
    teaching: schemas.TeachingState | None = None
    history_t: FloatArray = field(default_factory=lambda: np.zeros(0))  # robot clock, s
    history_top: FloatArray = field(default_factory=lambda: np.zeros(0))  # max b(s) per step
    history_entropy: FloatArray = field(default_factory=lambda: np.zeros(0))  # nats
    timeline: tuple[Segment, ...] = ()  # the current task's behaviours over time
    activity: tuple[tuple[str, str], ...] = ()  # (robot, "navigating to kitchen") of busy robots
    live: LiveFrame | None = None  # the robot's latest frame and the command it got
    control: schemas.RobotControlPublic | None = None  # driving by hand, spins, connection


Selection = Callable[[], tuple[str | None, int | None]]
"""Returns the selected robot and the tour to show when that robot is not bound to one. No
robot selected: the first robot that is navigating or teaching, else the first robot."""


class Publisher:
    """Takes snapshots at most ``hz`` times a second in its own thread; keeps the latest.

    ``sink(snapshot)`` runs in the publisher thread after each snapshot (the dashboard's
    renderer); an exception in it is logged and the thread keeps going. :meth:`poke` asks for
    a snapshot right away (after a button press), still never faster than ``hz``.
    ``household``: list only that household's robots and tours (``None``: every household's).
    """

    def __init__(
        self,
        services: Services,
        *,
        selection: Selection,
        household: int | None = None,
        sink: Callable[[Snapshot], None] | None = None,
        hz: float = 5.0,
        image_cache: int = 256,
    ) -> None:
        if not hz > 0:
            raise ValueError(f"hz must be positive, got {hz}")
        self.services = services
        self.selection = selection
        self.household = household
        self.sink = sink
        self.period_s = 1.0 / min(hz, 5.0)  # never more often than 5 Hz
        self.latest: Snapshot | None = None
        self.published = 0  # snapshots handed to the sink
        self.publish_ms: deque[float] = deque(maxlen=1000)  # wall time of snapshot + sink
        self._images: OrderedDict[int, bytes] = OrderedDict()
        self._image_cache = image_cache
        self._graphs: dict[tuple[object, ...], TourGraph] = {}
        self._session_tours: dict[tuple[str, int], int] = {}
        self._lists: tuple[float, tuple[str, ...], tuple[tuple[int, str, int, int, int], ...]] = (
            -1e9,
            (),
            (),
        )
        self._activity: tuple[tuple[str, str], ...] = ()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._published = threading.Condition()
        self._thread: threading.Thread | None = None

    # --- thread ---------------------------------------------------------------------------

    def start(self) -> None:
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="dashboard-publisher", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=timeout_s)
            self._thread = None

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def poke(self) -> None:
        """Take the next snapshot as soon as the rate limit allows."""
        self._wake.set()

    def wait_published(self, after: int, timeout_s: float = 5.0) -> bool:
        """Wait until more than ``after`` snapshots were published; False on timeout."""
        with self._published:
            return self._published.wait_for(lambda: self.published > after, timeout=timeout_s)

    def _run(self) -> None:
        next_at = 0.0
        while not self._stop.is_set():
            delay = next_at - time.monotonic()
            if delay > 0:
                self._stop.wait(delay)  # the rate limit: never faster than hz
                if self._stop.is_set():
                    break
            next_at = time.monotonic() + self.period_s
            self.publish_once()
            # sleep a period, or less when poked
            self._wake.wait(self.period_s)
            self._wake.clear()

    def publish_once(self) -> Snapshot | None:
        """Take one snapshot and hand it to the sink (called by the thread, or by tests)."""
        started = time.perf_counter()
        try:
            snap = self.snapshot()
        except Exception:  # the server may be shutting down; try again next period
            log.exception("dashboard snapshot failed")
            return None
        self.latest = snap
        if self.sink is not None:
            try:
                self.sink(snap)
            except Exception:
                log.exception("dashboard render failed")
        self.publish_ms.append((time.perf_counter() - started) * 1000.0)
        with self._published:
            self.published += 1
            self._published.notify_all()
        return snap

    # --- snapshots ------------------------------------------------------------------------

    def snapshot(self) -> Snapshot:
        """The selected robot's state right now, read without taking any session lock."""
        robots, tours = self._robot_and_tour_lists()
        tour_list = tuple((t[0], t[1]) for t in tours)
        robot, tour_hint = self.selection()
        if robot is not None and robot not in robots:
            robot = None
        if robot is None and robots:
            robot = self._activity[0][0] if self._activity else robots[0]
        session = None if robot is None else self.services.navigation.sessions().get(robot)
        teaching_row = None if robot is None else self.services.repo.teaching(robot)

        tour_id: int | None = None
        graph: TourGraph | None = None
        bound = False
        mode = "idle"
        teaching = None
        if teaching_row is not None:
            mode, bound, tour_id = "teaching", True, teaching_row.tour_id
            teaching = self.services.teaching.state(robot) if robot is not None else None
        elif session is not None:
            runtime = session.runtime
            graph = runtime.graph
            bound = True
            tour_id = self._tour_of(session)
        if tour_id is None and tour_hint is not None and any(t[0] == tour_hint for t in tours):
            tour_id = tour_hint
        if tour_id is None and tours:
            tour_id = tours[0][0]

        names = dict(tour_list)
        if graph is None and tour_id is not None:
            graph = self._stored_graph(tour_id, tours)
        graph_key: tuple[object, ...] = (
            ("none",)
            if graph is None
            else ("tour", tour_id, id(graph), graph.n_locations, graph.n_edges, graph.n_images)
        )
        snap = Snapshot(
            taken_at=time.time(),
            robots=robots,
            tours=tour_list,
            robot=robot,
            mode=mode,
            tour_id=tour_id,
            tour_name=names.get(tour_id) if tour_id is not None else None,
            bound=bound,
            graph=graph,
            graph_key=graph_key,
            teaching=teaching,
            activity=self._activity,
            live=None if robot is None else self.services.control.live(robot),
            control=None if robot is None else self.services.control.public(robot),
        )
        if session is None or teaching_row is not None:
            return snap
        return self._with_session(snap, session)

    def _with_session(self, snap: Snapshot, session: RobotSession) -> Snapshot:
        graph = session.runtime.graph
        task = session.task  # read without the lock: copy the fields once
        task_view = None
        if task is not None:
            task_view = TaskView(
                id=task.id,
                goal=task.goal_name,
                state=task.state,
                reason=task.reason,
                steps=task.steps,
                started_at=task.started_at,
            )
        mode = "navigating" if task_view is not None and task_view.state == "underway" else "idle"
        records = _copy_history(session)
        step = None
        hist_t = np.zeros(0)
        hist_top = np.zeros(0)
        hist_h = np.zeros(0)
        records = [r for r in records if len(r.summary.state) == graph.n_states]
        if records:
            step = _step_view(records[-1], graph, index=len(records))
            weights = tuple(
                tuple(float(x) for x in w) for w in session.runtime.index.model_weights()
            )
            step = dataclasses.replace(step, model_weights=weights)
            hist_t = np.array([r.timestamp for r in records], dtype=np.float64)
            hist_top = np.array([float(r.summary.state.max()) for r in records], dtype=np.float64)
            hist_h = np.array([float(r.summary.entropy) for r in records], dtype=np.float64)
        return Snapshot(
            taken_at=snap.taken_at,
            robots=snap.robots,
            tours=snap.tours,
            robot=snap.robot,
            mode=mode,
            tour_id=snap.tour_id,
            tour_name=snap.tour_name,
            bound=True,
            graph=graph,
            graph_key=snap.graph_key,
            step=step,
            task=task_view,
            teaching=None,
            history_t=hist_t,
            history_top=hist_top,
            history_entropy=hist_h,
            timeline=_copy_timeline(session),
            activity=snap.activity,
            live=snap.live,
            control=snap.control,
        )

    def _tour_of(self, session: RobotSession) -> int | None:
        """The tour a live session navigates (persisted by ``goto``; cached per session)."""
        key = (session.robot, id(session))
        if key not in self._session_tours:
            row = self.services.repo.navigation(session.robot)
            if row is None:
                return None
            self._session_tours = {key: row.tour_id}
        return self._session_tours[key]

    def _robot_and_tour_lists(
        self,
    ) -> tuple[tuple[str, ...], tuple[tuple[int, str, int, int, int], ...]]:
        at, robots, tours = self._lists
        now = time.monotonic()
        if now - at >= LISTS_EVERY_S:
            repo = self.services.repo
            robots = tuple(r.name for r in repo.robots(self.household))
            tours = tuple(
                (t.id, t.name, nl, ne, ni) for t, nl, ne, ni in repo.tours(self.household)
            )
            self._lists = (now, robots, tours)
            self._activity = self._busy(robots)
        return robots, tours

    def _busy(self, robots: tuple[str, ...]) -> tuple[tuple[str, str], ...]:
        """What the robots that are navigating or teaching do (read with the lists)."""
        sessions = self.services.navigation.sessions()
        out = []
        for robot in robots:
            session = sessions.get(robot)
            task = None if session is None else session.task
            if task is not None and task.underway:
                out.append((robot, f"navigating to {task.goal_name}"))
            elif self.services.repo.teaching(robot) is not None:
                out.append((robot, "teaching"))
        return tuple(out)

    def refresh_lists(self) -> None:
        """Forget the cached robot and tour lists (after a change made from the dashboard)."""
        self._lists = (-1e9, (), ())

    def _stored_graph(
        self, tour_id: int, tours: tuple[tuple[int, str, int, int, int], ...]
    ) -> TourGraph | None:
        counts = next((t[2:] for t in tours if t[0] == tour_id), None)
        if counts is None:
            return None
        # the distinctiveness arrives after teaching, in the background: its count is the key too
        key: tuple[object, ...] = (tour_id, *counts, self.services.repo.entropy_images(tour_id))
        graph = self._graphs.get(key)
        if graph is None:
            graph = self.services.repo.graph(tour_id)
            self._graphs = {key: graph}  # keep one: the tour on screen
        return graph

    def image(self, image_id: int) -> bytes | None:
        """The stored JPEG of ``image_id`` (cached: stored images never change)."""
        jpeg = self._images.get(image_id)
        if jpeg is not None:
            self._images.move_to_end(image_id)
            return jpeg
        try:
            jpeg = self.services.repo.image_jpeg(image_id)
        except Exception:
            return None
        self._images[image_id] = jpeg
        while len(self._images) > self._image_cache:
            self._images.popitem(last=False)
        return jpeg


def _copy_timeline(session: RobotSession) -> tuple[Segment, ...]:
    """A copy of the task's behaviour timeline, taken without the session's lock."""
    for _ in range(5):
        with contextlib.suppress(RuntimeError):  # deque mutated during iteration
            return tuple(session.timeline)
    return ()


def _copy_history(session: RobotSession) -> list[StepRecord]:
    """A copy of the session's step history, taken without its lock (retried if a step
    appended while copying)."""
    for _ in range(5):
        with contextlib.suppress(RuntimeError):  # deque mutated during iteration
            return list(session.history)
    return []


def _step_view(record: StepRecord, graph: TourGraph, *, index: int) -> StepView:
    summary = record.summary
    state = np.array(summary.state, dtype=np.float64)
    best_state, best_image, best_similarity = record.best_match()
    if best_image is not None and best_image >= graph.n_images:
        best_image = best_similarity = None
    image_sims = record.similarity.image
    image_similarity = (
        np.zeros(graph.n_images)
        if len(image_sims) != graph.n_images
        else np.array(image_sims, dtype=np.float64)
    )
    decision = record.decision
    votes = {} if decision is None else {str(k): float(v) for k, v in decision.votes.items()}
    command = record.command
    return StepView(
        index=index,
        timestamp=float(record.timestamp),
        jpeg=record.jpeg,
        state_belief=state,
        fine_belief=np.array(summary.belief, dtype=np.float64),
        along_edge=tuple(np.array(a, dtype=np.float64) for a in summary.along_edge),
        top_states=tuple((int(s), float(p)) for s, p in summary.top_states),
        entropy=float(summary.entropy),
        localised=bool(summary.localised),
        best_state=best_state,
        best_image=best_image,
        best_similarity=best_similarity,
        image_similarity=image_similarity,
        action=str(command.action.kind.value),
        action_edge=command.action.edge,
        behaviour=command.behaviour,
        reason=None if record.outcome is None else record.outcome.reason,
        target_image=command.target_image,
        votes=votes,
        active_edge=None if decision is None else decision.active_edge,
        v=float(command.v),
        w=float(command.w),
        step_ms=float(record.step_ms),
        appearance=tuple(float(x) for x in summary.appearance),
        light_change=float(summary.light_change),
        path=record.path,
    )
