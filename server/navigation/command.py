"""The command a navigation step answers with, and a behaviour's proposal of one."""

from __future__ import annotations

from dataclasses import dataclass

from server.belief.model import Action

BEHAVIOURS: dict[str, str] = {
    "stand": "standing still (no task, a task that ended, or DoNothing)",
    "follow": "following a taught path (by the pose relative to it, or by homing)",
    "leave": "driving onto the edge RotateAndFindEdge found",
    "search": "turning to find an edge (RotateAndFindEdge)",
    "explore": "heading for open space (Explore)",
    "unstick": "exploring for a while: stuck, or a full search turn found nothing",
    "backoff": "backing away from something the robot is pressed against",
    "escape": "getting free: backing off, turning to the most open side, driving that way",
    "dock": "creeping onto the place the belief arrived at, until the view's scale agrees",
    "place-dock": "docking on the goal's own spin images",
    "settle": "docking on a place's spin images before setting off from it again",
    "retrace": "driving back along its own trace to where the taught path was last tracked",
}
"""The values of :attr:`Command.behaviour`, with what they mean (shown on the dashboard)."""


@dataclass(frozen=True)
class Command:
    """A motion command before it goes on the wire: ``v`` m/s, ``w`` rad/s, the action the
    belief is predicted with, the target image (canonical index) and the behaviour label."""

    v: float
    w: float
    action: Action
    target_image: int | None = None
    behaviour: str = "stand"  # see BEHAVIOURS


STAND = Command(0.0, 0.0, Action.do_nothing())
"""Standing still, predicting the belief with DoNothing."""


@dataclass(frozen=True)
class Proposal:
    """What a behaviour would have the robot do this frame, and why."""

    command: Command
    reason: str
