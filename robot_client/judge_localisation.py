"""How well a navigation trial localised, judged against the simulator's ground truth.

The navigator never sees the truth; only this judge does. Per frame it reads what the server
answered (is the belief "localised", on which state) and compares it with the true pose:

* a **location** is right when the robot stands within :data:`LOCATION_RADIUS_M` of the
  place (the plan's position of the place of that name), or when it is the nearest place to
  the robot among the places of the room the robot is in (of all places when that room has
  none): a robot down the corridor from the hall place is at the hall, one in the corridor
  looking into the kitchen is not in the kitchen;
* an **edge** is right when the robot is within :data:`EDGE_RADIUS_M` of one of the poses its
  images were taught at, facing within :data:`EDGE_HEADING_RAD` of the way that image faced
  (the tour's taught poses, ``GET /tours/{id}``; without them edges are not judged).

Figures (:meth:`LocalisationJudge.summary`): the robot seconds from the task's start (a
uniform belief) to the first frame localised on a right state, the number of wrong
"localised" claims (runs of consecutive frames localised on a wrong state) and their frames.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from robot_client.sim.floorplan import FloorPlan
from server import schemas

LOCATION_RADIUS_M = 1.0
"""A "localised at a place" claim is right within this distance of the place."""
EDGE_RADIUS_M = 0.75
"""A "localised on an edge" claim is right within this distance of one of its taught poses..."""
EDGE_HEADING_RAD = math.pi / 3
"""... facing within this angle of the way that image was taken."""


class LocalisationJudge:
    """Judges the frames of one trial (see the module docstring)."""

    def __init__(self, plan: FloorPlan, tour: schemas.TourGraphPublic | None) -> None:
        self.plan = plan
        self.places = {p.name: (p.x, p.y) for p in plan.places}
        self.room_of = {p.name: _room(plan, p.x, p.y) for p in plan.places}
        self.edge_poses: dict[int, np.ndarray] = {}
        for e in [] if tour is None else tour.edges:
            if e.poses:
                self.edge_poses[e.id] = np.asarray(e.poses, dtype=np.float64)
        self.t0: float | None = None
        self.first_correct_s: float | None = None
        self.wrong_claims = 0
        self.wrong_frames = 0
        self.judged_frames = 0
        self._wrong_run = False

    def right(
        self, state: schemas.StateProbability, x: float, y: float, theta: float
    ) -> bool | None:
        """Whether the robot at ``(x, y, theta)`` is in ``state`` (``None``: cannot tell)."""
        if state.kind == "location":
            at = self.places.get(state.name)
            if at is None:
                return None
            if math.dist(at, (x, y)) <= LOCATION_RADIUS_M:
                return True
            room = _room(self.plan, x, y)
            here = [n for n, r in self.room_of.items() if r == room] or list(self.places)
            return min(here, key=lambda n: math.dist(self.places[n], (x, y))) == state.name
        poses = self.edge_poses.get(state.id)
        if poses is None:
            return None
        near = np.hypot(poses[:, 0] - x, poses[:, 1] - y) <= EDGE_RADIUS_M
        facing = np.abs(np.remainder(poses[:, 2] - theta + np.pi, 2 * np.pi) - np.pi)
        return bool(np.any(near & (facing <= EDGE_HEADING_RAD)))

    def observe(
        self, t: float, x: float, y: float, theta: float, result: schemas.NavigationFrameResult
    ) -> None:
        """One frame: robot time ``t`` (s), the true pose, and the server's answer."""
        if self.t0 is None:
            self.t0 = t
        belief = result.belief
        wrong = False
        if belief.localised and belief.localised_state is not None:
            verdict = self.right(belief.localised_state, x, y, theta)
            if verdict is not None:
                self.judged_frames += 1
                wrong = not verdict
                if verdict and self.first_correct_s is None:
                    self.first_correct_s = t - self.t0
        if wrong:
            self.wrong_frames += 1
            self.wrong_claims += not self._wrong_run
        self._wrong_run = wrong

    def summary(self) -> dict[str, Any]:
        """The trial's localisation figures (keys of :class:`robot_client.trial.TrialResult`)."""
        return {
            "first_correct_s": self.first_correct_s,
            "wrong_claims": self.wrong_claims,
            "wrong_claim_frames": self.wrong_frames,
        }


def _room(plan: FloorPlan, x: float, y: float) -> str | None:
    room = plan.room_at(x, y)
    return None if room is None else room.name
