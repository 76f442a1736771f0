"""A navigation task: "go to the kitchen", from request to its end."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from server.navigation.observation import elapsed
from server.navigation.params import NavigationParams


class TaskState(StrEnum):
    """Where a task is in its life; every state but ``UNDERWAY`` is final."""

    UNDERWAY = "underway"
    ARRIVED = "arrived"
    FAILED = "failed"
    CANCELLED = "cancelled"


@dataclass
class Task:
    """One "go to X" request and how it ended.

    ``started_at``/``ended_at`` are wall-clock seconds (for people and persistence);
    ``started_robot_time`` the robot time of its first frame; ``steps`` the frames it has taken.
    ``arrive_streak``/``explore_streak`` count the consecutive frames that end it as arrived
    (``arrive_steps``) or lost (``lost_steps``)."""

    id: int
    goal: int  # location index in the runtime's graph
    goal_name: str
    started_at: float
    started_robot_time: float | None = None
    state: TaskState = TaskState.UNDERWAY
    reason: str | None = None
    ended_at: float | None = None
    steps: int = 0
    arrive_streak: int = 0
    explore_streak: int = 0

    @property
    def underway(self) -> bool:
        return self.state == TaskState.UNDERWAY

    def end(self, state: TaskState, reason: str | None, now: float) -> None:
        """End the task (a task that has ended stays as it ended)."""
        if self.underway:
            self.state, self.reason, self.ended_at = state, reason, now

    def advance(
        self,
        *,
        there: bool,
        exploring: bool,
        t: float,
        wall: float,
        params: NavigationParams,
        give_up: str | None = None,
    ) -> None:
        """Count one frame: ``there`` the robot stands at the goal as docking confirms,
        ``exploring`` the policy voted Explore; ``t`` its robot time, ``wall`` the wall clock;
        ``give_up`` why a behaviour gave up ("stuck: ...", "lost: ..."), if one did.
        Ends the task as arrived, lost (failed) or timed out (failed) when it is time to."""
        p = params
        self.steps += 1
        if give_up is not None:
            self.end(TaskState.FAILED, give_up, wall)
            return
        self.arrive_streak = self.arrive_streak + 1 if there else 0
        self.explore_streak = self.explore_streak + 1 if exploring else 0
        if self.arrive_streak >= p.arrive_steps:
            self.end(TaskState.ARRIVED, None, wall)
        elif self.explore_streak >= p.lost_steps:
            why = f"lost: no confident position for {self.explore_streak} frames"
            self.end(TaskState.FAILED, why, wall)
        elif (
            self.started_robot_time is not None
            and elapsed(t, self.started_robot_time) > p.max_task_s
        ):
            self.end(TaskState.FAILED, f"timeout: still underway after {p.max_task_s:.0f} s", wall)
