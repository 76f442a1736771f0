"""One command per frame from the behaviours' proposals, by a written order of precedence.

The first behaviour in :data:`PRECEDENCE` that proposes something wins (subsumption):

=============  ==========================================================================
behaviour      proposes when
=============  ==========================================================================
``backoff``    it has been pressed against something while told to drive (bump reflex)
``escape``     the winner wanted to drive forward for ``escape_s`` and the robot did not move
``place-dock`` the belief is at the goal before the robot came in along an edge
``unstick``    the stall watchdog fired: little driven for ``stall_s``
``retrace``    the path tracker lost the taught path: back along the robot's own trace
``settle``     a departure from the place the belief is at lost its edge: dock on the place
``find-edge``  the policy says RotateAndFindEdge, or a fruitless search turn explores
``follow``     the policy says Navigate, or the path tracker has joined the edge sought
``explore``    the policy says Explore
``stand``      always (the policy's action, standing still)
=============  ==========================================================================

Docking along the edge (``dock``) is asked last, once the winner above is known, because
whether the robot came in along an edge into the goal depends on the motion chosen this frame
(:meth:`server.navigation.docking.Docking.track`); when it has something to say it overrides
everything. Obstacle avoidance then blends into whatever moves forward
(:class:`Avoid`), and a task that has ended stands still.
"""

from __future__ import annotations

from collections.abc import Mapping

from server.motion import MotionParams, avoid_obstacles, avoid_side
from server.navigation.command import Command, Proposal
from server.navigation.observation import Observation

PRECEDENCE: tuple[str, ...] = (
    "backoff",
    "escape",
    "place-dock",
    "unstick",
    "retrace",
    "settle",
    "find-edge",
    "follow",
    "explore",
    "stand",
)
"""Behaviour names, highest precedence first (see the module docstring)."""


class NoProposal(RuntimeError):
    """No behaviour proposed anything: the ``stand`` behaviour is missing."""


def arbitrate(proposals: Mapping[str, Proposal | None]) -> tuple[str, Proposal]:
    """The winning behaviour's name and proposal: the first in :data:`PRECEDENCE` with one.

    Raises:
        NoProposal: none proposed anything; ValueError: a name not in ``PRECEDENCE``.
    """
    unknown = set(proposals) - set(PRECEDENCE)
    if unknown:
        raise ValueError(f"behaviours {sorted(unknown)} have no place in PRECEDENCE")
    for name in PRECEDENCE:
        proposal = proposals.get(name)
        if proposal is not None:
            return name, proposal
    raise NoProposal("no behaviour proposed a command; 'stand' always should")


class Avoid:
    """Obstacle avoidance blended into the chosen command as obstacles close in (001 7.3),
    turning the same way as on the last frame while obstacles stay near
    (:func:`server.motion.avoid_side`: choosing afresh every frame swung the robot back and
    forth in front of an armchair). Its side is read every frame of the task."""

    name = "avoid"

    def __init__(self, params: MotionParams) -> None:
        self.mp = params
        self.side = 0  # +1 left, -1 right, 0 nothing near

    def look(self, obs: Observation) -> None:
        self.side = avoid_side(obs.depth, self.mp, self.side)

    def apply(self, command: Command, obs: Observation) -> Command:
        v, w = avoid_obstacles(command.v, command.w, obs.depth, self.mp, side=self.side)
        if (v, w) == (command.v, command.w):
            return command
        return Command(v, w, command.action, command.target_image, command.behaviour)
