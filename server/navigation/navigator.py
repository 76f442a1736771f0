"""One robot navigating one tour: a step is one line of stages.

    perceive (vision, belief, votes, views) -> behaviours propose -> arbiter -> dock -> avoid
    -> task

:class:`Navigator` holds what lives between frames: the belief tracker, the task, and the
task's behaviours (:class:`Crew`, created afresh for every task, so nothing of one task's
behaviour state reaches the next).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from server.belief.model import Action, ActionKind
from server.belief.tracker import BeliefSummary, Tracker
from server.navigation.arbiter import Avoid, arbitrate
from server.navigation.behaviours import (
    Backoff,
    Behaviour,
    Escape,
    Explore,
    FindEdge,
    Follow,
    Retrace,
    Stand,
    Unstick,
)
from server.navigation.command import STAND, Command, Proposal
from server.navigation.docking import Docking
from server.navigation.observation import (
    Frame,
    Observation,
    Outcome,
    ViewRequest,
    elapsed,
    perceive,
)
from server.navigation.pathtrack import PathEstimate, PathTracker
from server.navigation.runtime import TourRuntime, preferred
from server.navigation.settle import Settle
from server.navigation.task import Task
from server.policy.voting import Decision
from server.vision.features import ImageFeatures, extract
from server.vision.index import Similarity


class Crew:
    """The behaviours of one task (fresh for every task), in no particular order: the arbiter
    ranks them. ``docking`` is both the ``place-dock`` behaviour and the final word on arrival."""

    def __init__(self, runtime: TourRuntime, goal: int) -> None:
        self.docking = Docking(runtime, goal)
        self.motion: tuple[Behaviour, ...] = (
            Backoff(runtime),
            Escape(runtime),
            Unstick(runtime),
            Retrace(runtime),
            Settle(runtime),
            FindEdge(runtime),
            Follow(runtime),
            Explore(runtime),
            Stand(runtime),
        )
        self.avoid = Avoid(runtime.params.motion)

    def wants(self, obs: Observation) -> ViewRequest:
        return ViewRequest.union([*(b.wants(obs) for b in self.motion), self.docking.wants(obs)])

    def events(self) -> frozenset[str]:
        out = self.docking.events()
        for b in self.motion:
            out |= b.events()
        return out


def gave_up(events: frozenset[str]) -> str | None:
    """Why a behaviour gave the task up (its ``"failed: ..."`` event, prefix removed), if one
    did this frame; the first in alphabetical order when several did."""
    failures = sorted(e.removeprefix("failed: ") for e in events if e.startswith("failed: "))
    return failures[0] if failures else None


@dataclass(frozen=True)
class Step:
    """What one frame saw and decided. ``decision`` and ``outcome`` are ``None`` without a
    task underway; ``path`` is the pose relative to the taught path being tracked
    (topometric repeat)."""

    features: ImageFeatures
    similarity: Similarity
    summary: BeliefSummary
    decision: Decision | None
    command: Command
    outcome: Outcome | None
    path: PathEstimate | None = None


class Navigator:
    """One robot's navigation on one tour (no I/O, no locks: its holder serialises frames)."""

    def __init__(self, runtime: TourRuntime) -> None:
        self.runtime = runtime
        self.params = runtime.params
        self.tracker = Tracker(runtime.model, runtime.params.tracker)
        self.task: Task | None = None
        self.crew: Crew | None = None
        self.last_action = Action.do_nothing()
        self.last_timestamp: float | None = None
        self.previous: Outcome | None = None
        self.fresh = False  # a task has just started afresh: the next frame's dt is 0
        self.path: PathTracker | None = None  # the task's path tracker (topometric repeat)

    @property
    def last_command(self) -> Command | None:
        return None if self.previous is None else self.previous.command

    @property
    def previous_reason(self) -> str | None:
        return None if self.previous is None else self.previous.reason

    def start(self, task: Task) -> None:
        """Make ``task`` the robot's task (the caller ends any task underway first). With
        ``fresh_belief`` the belief restarts from the prior, and nothing of the last task
        carries over, not even the time since its last frame (the first prediction's dt) or its
        last command (a task that ended driving made the bump reflex back the robot off on the
        next task's first frame)."""
        self.task = task
        self.crew = Crew(self.runtime, task.goal)
        self.path = self._path_tracker()
        if self.params.fresh_belief:
            self.tracker.reset()
            self.last_action = Action.do_nothing()
            self.previous, self.fresh = None, True

    def resume(self, task: Task) -> None:
        """Carry on with ``task`` after a restart, keeping the belief as it was restored (how
        far the approach had come is not persisted: it is done again)."""
        self.task = task
        self.crew = Crew(self.runtime, task.goal)
        self.path = self._path_tracker()

    def _path_tracker(self) -> PathTracker | None:
        return self.runtime.path_tracker() if self.params.topometric.enabled else None

    def rebase(self, runtime: TourRuntime) -> None:
        """Move to a newer snapshot of the same tour (the belief restarts when states changed;
        the task's behaviours start afresh on it)."""
        old, memory = self.tracker.belief, self.tracker.memory()
        self.runtime, self.params = runtime, runtime.params
        self.tracker = Tracker(runtime.model, runtime.params.tracker)
        if old.shape == (runtime.model.n_fine,):
            self.tracker.set_belief(old, memory)
        if self.task is not None:
            self.crew = Crew(runtime, self.task.goal)
            self.path = self._path_tracker()

    def step(self, frame: Frame, *, wall: float = 0.0) -> Step:
        """Process one frame; ``wall`` is the wall clock (for the task's end time only)."""
        p = self.params
        fresh, self.fresh = self.fresh, False
        last = self.last_timestamp
        dt = 0.0 if fresh or last is None else elapsed(frame.timestamp, last)
        dt = float(np.clip(dt, 0.0, p.max_dt_s))
        task, crew = self.task, self.crew
        if task is None or crew is None or not task.underway:
            step = self._idle(frame, dt)
        else:
            step = self._navigate(task, crew, frame, dt, wall)
        self.last_action = step.command.action
        self.last_timestamp = frame.timestamp
        return step

    def _idle(self, frame: Frame, dt: float) -> Step:
        """No task underway: the belief goes on; the robot stands."""
        features = extract(frame.image, self.params.features)
        similarities, likelihood = self.runtime.observe(features)
        summary = self.runtime.believe(
            self.tracker, self.last_action, similarities, likelihood, v=frame.v, w=frame.w, dt=dt
        )
        return Step(features, preferred(similarities, summary), summary, None, STAND, None)

    def _navigate(self, task: Task, crew: Crew, frame: Frame, dt: float, wall: float) -> Step:
        if task.started_robot_time is None:
            task.started_robot_time = frame.timestamp
        obs = perceive(
            self.runtime,
            self.tracker,
            frame,
            last_action=self.last_action,
            dt=dt,
            goal=task.goal,
            steps=task.steps,
            hold_goal=crew.docking.approach.done,
            previous=self.previous,
            wants=crew.wants,
            path=self.path,
        )
        crew.avoid.look(obs)
        proposals: dict[str, Proposal | None] = {b.name: b.propose(obs) for b in crew.motion}
        proposals[crew.docking.name] = placing = crew.docking.place(obs)
        winner, chosen = arbitrate(proposals)
        crew.docking.track(chosen.command, dt, obs.path)
        docking, there = crew.docking.confirm(obs, placing is not None)
        if docking is not None:
            winner, chosen = "dock", docking
        proposals["dock"] = docking
        command = crew.avoid.apply(chosen.command, obs)
        exploring = obs.decision.action.kind == ActionKind.EXPLORE
        events = crew.events()
        task.advance(
            there=there,
            exploring=exploring,
            t=frame.timestamp,
            wall=wall,
            params=self.params,
            give_up=gave_up(events),
        )
        reason = chosen.reason
        if not task.underway:
            command, winner = STAND, "stand"
            reason = f"task {task.state}" + (f": {task.reason}" if task.reason else "")
        self.previous = Outcome(command, winner, reason, proposals, events)
        return Step(
            obs.features,
            obs.similarity,
            obs.summary,
            obs.decision,
            command,
            self.previous,
            path=obs.path,
        )
