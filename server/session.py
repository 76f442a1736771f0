"""One robot's navigation as the HTTP service holds it: a thin holder of its runtime.

The navigation itself (belief, policy, behaviours, arbiter) is :class:`server.navigation.Navigator`;
this adds what a server needs around it: the lock that serialises one robot's frames, a bounded
history of steps for the dashboard, and the wall clock of its last frame for the silence
watchdog. No I/O: the navigation service persists what must survive a restart.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from server.belief.tracker import BeliefSummary, Tracker
from server.navigation import Command, Frame, Navigator, Task, TaskState, TourRuntime
from server.navigation.observation import Outcome
from server.navigation.pathtrack import PathEstimate
from server.policy.voting import Decision
from server.vision.features import ImageFeatures
from server.vision.index import Similarity


@dataclass(frozen=True)
class StepRecord:
    """What one step saw and decided (kept in a bounded history). ``outcome``: the winning
    behaviour, every proposal and the events (``None`` without a task underway)."""

    timestamp: float
    jpeg: bytes  # the frame as the robot sent it
    features: ImageFeatures
    similarity: Similarity
    summary: BeliefSummary
    decision: Decision | None
    command: Command
    step_ms: float
    outcome: Outcome | None = None
    path: PathEstimate | None = None  # the pose relative to the taught path (topometric repeat)

    def best_match(self) -> tuple[int, int | None, float | None]:
        """The most likely upper state, its best-matching stored image (canonical index, or
        ``None`` when the state has none) and that image's similarity to the frame."""
        state = self.summary.state
        best_state = int(np.argmax(state)) if len(state) else 0
        images, sims = self.similarity.best_image, self.similarity.image
        if best_state >= len(images) or not 0 <= int(images[best_state]) < len(sims):
            return best_state, None, None
        k = int(images[best_state])
        return best_state, k, float(sims[k])


@dataclass(frozen=True)
class Segment:
    """A stretch of a task during which one behaviour drove the robot: robot seconds from
    ``t0`` to ``t1``, the behaviour label (:data:`server.navigation.BEHAVIOURS`) and the
    reason of its first frame."""

    t0: float
    t1: float
    behaviour: str
    reason: str


TIMELINE_SEGMENTS = 4000
"""A task's behaviour timeline keeps at most this many segments (the oldest go first)."""


class RobotSession:
    """One robot on one tour: its navigator, its lock, its recent steps, and the timeline of
    behaviours of its current task (for the dashboard's strip)."""

    def __init__(self, robot: str, runtime: TourRuntime) -> None:
        self.robot = robot
        self.navigator = Navigator(runtime)
        self.lock = threading.Lock()
        self.history: deque[StepRecord] = deque(maxlen=runtime.params.history)
        self.timeline: deque[Segment] = deque(maxlen=TIMELINE_SEGMENTS)
        self.last_frame_wall: float | None = None

    @property
    def runtime(self) -> TourRuntime:
        return self.navigator.runtime

    @property
    def task(self) -> Task | None:
        return self.navigator.task

    @property
    def tracker(self) -> Tracker:
        return self.navigator.tracker

    @property
    def last_command(self) -> Command | None:
        return self.navigator.last_command

    @property
    def last_timestamp(self) -> float | None:
        return self.navigator.last_timestamp

    def start_task(self, task: Task) -> None:
        """Make ``task`` the robot's task (:meth:`Navigator.start`)."""
        self.navigator.start(task)
        self.timeline.clear()

    def resume_task(self, task: Task) -> None:
        """Carry on with a persisted task after a restart (:meth:`Navigator.resume`)."""
        self.navigator.resume(task)
        self.timeline.clear()

    def rebase(self, runtime: TourRuntime) -> None:
        """Move to a newer snapshot of the same tour (:meth:`Navigator.rebase`)."""
        self.navigator.rebase(runtime)

    def step(
        self,
        image: npt.NDArray[np.uint8],
        *,
        timestamp: float,
        v: float,
        w: float = 0.0,
        depth: npt.ArrayLike | None = None,
        wall: float = 0.0,
        jpeg: bytes = b"",
    ) -> StepRecord:
        """Process one frame (robot ``timestamp`` s, odometry ``v`` m/s and ``w`` rad/s, depth
        ranges in metres) into the next command; ``wall`` is the wall clock."""
        started = time.perf_counter()
        ranges = None if depth is None else np.asarray(depth, dtype=np.float64)
        step = self.navigator.step(Frame(image, timestamp, v, w, ranges), wall=wall)
        self.last_frame_wall = wall
        record = StepRecord(
            timestamp=timestamp,
            jpeg=jpeg,
            features=step.features,
            similarity=step.similarity,
            summary=step.summary,
            decision=step.decision,
            command=step.command,
            step_ms=(time.perf_counter() - started) * 1000.0,
            outcome=step.outcome,
            path=step.path,
        )
        self.history.append(record)
        if step.outcome is not None:
            self._extend_timeline(timestamp, step.outcome)
        return record

    def _extend_timeline(self, t: float, outcome: Outcome) -> None:
        label = outcome.command.behaviour
        last = self.timeline[-1] if self.timeline else None
        if last is not None and last.behaviour == label:
            self.timeline[-1] = Segment(last.t0, t, label, last.reason)
        else:
            self.timeline.append(Segment(t, t, label, outcome.reason))

    def check_silence(self, wall: float) -> bool:
        """Fail an underway task whose robot has sent no frame for ``frame_timeout_s``."""
        task = self.task
        if task is None or not task.underway:
            return False
        last = self.last_frame_wall if self.last_frame_wall is not None else task.started_at
        if wall - last > self.navigator.params.frame_timeout_s:
            task.end(TaskState.FAILED, f"timeout: no frame for {wall - last:.1f} s", wall)
            return True
        return False
