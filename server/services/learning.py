"""Learning from repeat runs: collect what a task could teach, store it as undoable changes.

A :class:`NavigationObserver`: while ``NavigationParams.learning.collect`` is on, every task
keeps its tracker's steps. When the task has arrived, ``POST /robots/{robot}/learn`` stores
them as a learned change of the tour (docs/learning.md): *transitions* (the run's expected
motion counts, :mod:`server.belief.learning`). Every change is listed per tour and can be removed;
the tour's runtime is rebuilt from what remains, so removing every change gives back exactly
the taught behaviour.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from server import schemas
from server.belief.learning import TransitionCounts, expected_motion_counts
from server.belief.model import BeliefModel
from server.errors import Conflict
from server.navigation import NavigationParams
from server.services.navigation import NavigationObserver
from server.session import RobotSession
from server.storage.repo import LearnedChangeRow, Repo


@dataclass
class _Run:
    """What one task collected."""

    tour_id: int
    task_id: int
    started: float
    model: BeliefModel
    session: RobotSession | None = None
    state: str = "underway"


def change_public(row: LearnedChangeRow) -> schemas.LearnedChange:
    return schemas.LearnedChange(
        id=row.id,
        tour=row.tour_id,
        kind=row.kind,  # type: ignore[arg-type]  # repo.LEARNED_KINDS, checked on insert
        created_at=row.created_at,
        source=row.source,
        summary=row.summary,
        images=row.images,
        edge=row.edge_id,
    )


class LearningService(NavigationObserver):
    """Collects per robot (an observer of the navigation service) and stores on request."""

    def __init__(
        self,
        repo: Repo,
        params: NavigationParams,
        on_change: Callable[[int], None],
        *,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.repo = repo
        self.params = params.learning
        self.on_change = on_change
        self.clock = clock
        self._runs: dict[str, _Run] = {}
        self._lock = threading.Lock()

    # --- observer -------------------------------------------------------------------------

    def task_started(
        self, robot: str, session: RobotSession, tour_id: int, *, record: bool | None, resumed: bool
    ) -> None:
        if not self.params.collect:
            return
        task = session.task
        run = _Run(
            tour_id=tour_id,
            task_id=0 if task is None else int(task.id),
            started=self.clock(),
            model=session.runtime.model,
            session=session,
        )
        with self._lock:
            self._runs[robot] = run

    def task_ended(self, robot: str, task: schemas.TaskPublic) -> None:
        run = self._runs.get(robot)
        if run is not None:
            run.state = task.state

    # --- requests -------------------------------------------------------------------------

    def learn(self, robot: str, household: int) -> list[schemas.LearnedChange]:
        """Store what the robot's last task collected as learned changes of its tour (409 when
        there is nothing: no arrived task, or collection off)."""
        with self._lock:
            run = self._runs.get(robot)
        if run is None or run.state != "arrived":
            raise Conflict(
                f"robot {robot!r} has no arrived task to learn from (learning.collect is "
                f"{'on' if self.params.collect else 'off'}; only a task that arrived teaches)"
            )
        self.repo.tour(run.tour_id, household)  # 404 for another household's tour
        source = f"robot {robot}, task {run.task_id} started {_iso(run.started)}"
        now = self.clock()
        made: list[int] = []
        counts = self._counts(run)
        if counts is not None:
            made.append(
                self.repo.add_learned_change(
                    run.tour_id,
                    "transitions",
                    source=source,
                    summary=f"{float(counts.steps.sum()):.0f} steps of driving along edges",
                    now=now,
                    counts=counts.to_bytes(),
                )
            )
        with self._lock:
            if self._runs.get(robot) is run:
                del self._runs[robot]
        if made:
            self.on_change(run.tour_id)
        rows = {r.id: r for r in self.repo.learned_changes(run.tour_id)}
        return [change_public(rows[i]) for i in made if i in rows]

    def _counts(self, run: _Run) -> TransitionCounts | None:
        session = run.session
        if self.params.run_steps == 0 or session is None:
            return None
        steps = session.tracker.run()
        if len(steps) < 2 or session.tracker.model is not run.model:
            return None
        counts = expected_motion_counts(run.model, steps)
        return counts if counts.steps.sum() > 0 else None

    def changes(self, tour_id: int, household: int) -> list[schemas.LearnedChange]:
        self.repo.tour(tour_id, household)
        return [change_public(r) for r in self.repo.learned_changes(tour_id)]

    def remove(self, tour_id: int, change_id: int, household: int) -> None:
        """Delete one change (404: no such change of the household's tour)."""
        self.repo.tour(tour_id, household)
        self.repo.remove_learned_change(tour_id, change_id)
        self.on_change(tour_id)


def _iso(t: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t))
