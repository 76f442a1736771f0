"""Settling on a place's taught spot before setting off from it again.

A robot that believes it stands at a place, but stands 0.5-1.5 m off the spot where the place
was taught, sees the departure view of the edge it wants from an angle: RotateAndFindEdge lines
up with it, drives off, and loses the edge within a few frames (the views along it do not
follow from here); then the belief falls back to the place and the search starts again. Traced
in the apartment, this loop took 80 % of the frames of the trials that timed out. After such a
lost departure, :class:`Settle` docks on the place's own spin images (as place docking does at
the goal, on one axis: look for a spin view, line up, creep until its scale agrees), and lets
the search start from the taught spot.
"""

from __future__ import annotations

from collections import Counter

import numpy as np

from server.belief.model import Action, ActionKind
from server.motion import navigate_command, rotate_command
from server.navigation.behaviours import DepartureRuns
from server.navigation.command import Command, Proposal
from server.navigation.docking import (
    SPOT_M,
    SpotFix,
    look_fit,
    scale_verdict,
    top_spins,
    toward_spot,
)
from server.navigation.observation import Observation, ViewRequest
from server.navigation.runtime import TourRuntime

OFF_PLACE_FRAMES = 20
"""Frames in a row with the belief elsewhere after which settling on a place stops."""


class Settle:
    """Dock on the place a departure set off from and lost, before searching again.

    It starts when the policy asks RotateAndFindEdge for an edge from the place the belief is
    at, and a departure from that place (driving along one of its edges for at least
    ``departure_min_s``) has ended since the robot last settled there; at most
    ``NavigationParams.settle_tries`` times per place and task. It stops
    when the scale of a spin view agrees (three fits in a row, within ``dock_scale_tol``),
    after ``dock_max_m`` of creeping, after ``place_dock_turns`` turns without a spin view in
    sight, or when the belief has been elsewhere for :data:`OFF_PLACE_FRAMES` frames.
    """

    name = "settle"

    def __init__(self, runtime: TourRuntime) -> None:
        self.rt = runtime
        self.p = runtime.params
        self.departed: set[int] = set()  # places set off from since last settled there
        self.runs = DepartureRuns(runtime.params.departure_min_s)
        self.settles: Counter[int] = Counter()  # settlings per place this task
        self.place: int | None = None  # the place being settled on
        self.phase = "look"  # look, creep
        self.target: int | None = None  # the spin image crept along
        self.rad = 0.0  # turned while settling (as commanded)
        self.m = 0.0  # crept while settling (as commanded)
        self.off = 0  # frames in a row with the belief elsewhere
        self.log_scales: list[float] = []
        self.spot = SpotFix()  # the place's taught spot by the depth profiles
        self._engaged = False

    def _due(self, obs: Observation) -> int | None:
        """The place to start settling on this frame, if one is due (no state changed)."""
        if self.p.settle_tries <= 0:
            return None
        a = obs.decision.action
        if a.kind != ActionKind.ROTATE_AND_FIND_EDGE or a.edge is None:
            return None
        place = self.rt.graph.edges[a.edge].source
        if obs.summary.map_state != place or self.settles[place] >= self.p.settle_tries:
            return None
        ending = self.runs.ending(obs)
        left = None if ending is None else self.rt.graph.edges[ending].source
        return place if place in self.departed or left == place else None

    def wants(self, obs: Observation) -> ViewRequest:
        place = self.place if self.place is not None else self._due(obs)
        if place is None:
            return ViewRequest()
        zoomed = set(top_spins(self.rt, obs, place))
        if self.target is not None and self.place is not None:
            zoomed.add(self.target)
        return ViewRequest(zoomed=frozenset(zoomed))

    def propose(self, obs: Observation) -> Proposal | None:
        self._engaged = False
        ended = self.runs.update(obs)
        if ended is not None:
            self.departed.add(self.rt.graph.edges[ended].source)
        if self.place is None:
            place = self._due(obs)
            if place is None:
                return None
            self.place, self.phase, self.target = place, "look", None
            self.spot.reset()
            self.rad = self.m = 0.0
            self.off = 0
            self.log_scales.clear()
            self.settles[place] += 1
            self.departed.discard(place)
        proposal = self._settle(obs, self.place)
        if proposal is None:
            self.place = None
        self._engaged = proposal is not None
        return proposal

    def _settle(self, obs: Observation, place: int) -> Proposal | None:
        p, mp = self.p, self.p.motion
        prev = obs.previous
        if prev is not None and prev.winner == self.name:
            self.rad += abs(prev.command.w) * obs.dt
            self.m += abs(prev.command.v) * obs.dt
        self.off = 0 if obs.summary.map_state == place else self.off + 1
        if self.off > OFF_PLACE_FRAMES:
            return None
        spot = self.spot.update(self.rt, obs, place)
        if spot is not None:  # the depth profiles tell where the spot is: go there
            distance = float(np.hypot(*spot))
            if distance <= SPOT_M:
                return None  # on the spot: search from here
            v, w = toward_spot(spot, self.rt)
            return self._say(Command(v, w, Action.do_nothing()), f"{distance:.2f} m away (depth)")
        if self.phase == "look":
            target, fit = look_fit(obs.views, top_spins(self.rt, obs, place), p)
            seen = fit is not None and fit.inliers >= p.dock_min_inliers
            if fit is None or not seen or abs(fit.offset) > mp.toward_offset:
                if self.rad >= 2 * np.pi * p.place_dock_turns:
                    return None  # no spin view in sight from here: search from where it is
                if fit is not None and seen:
                    toward = rotate_command(mp, toward=fit.offset)
                    return self._say(Command(*toward, Action.do_nothing()), "turning toward it")
                spin = rotate_command(mp)
                return self._say(Command(*spin, Action.do_nothing()), "looking for its views")
            self.phase, self.target = "creep", target
            self.log_scales.clear()
        return self._creep(obs)

    def _creep(self, obs: Observation) -> Proposal | None:
        p, mp = self.p, self.p.motion
        target = int(self.target if self.target is not None else 0)
        fit = obs.views.zoomed_scale(target)
        if fit is None or fit.inliers < p.dock_min_inliers:
            self.phase = "look"
            spin = rotate_command(mp)
            return self._say(Command(*spin, Action.do_nothing()), "lost the view; looking again")
        short, past = scale_verdict(self.log_scales, fit, p.dock_scale_tol)
        settled = not (short or past)
        if settled and len(self.log_scales) < 3 and self.m < p.dock_max_m:
            return self._say(Command(0.0, 0.0, Action.do_nothing()), "holding until views agree")
        if settled or self.m >= p.dock_max_m:
            return None
        _, w = navigate_command(fit.offset, taught_v=0.0, taught_w=0.0, params=mp)
        v = mp.dock_v if short else -mp.dock_v
        why = "creeping on: the view looks smaller" if short else "backing up: it looks larger"
        return self._say(Command(v, w, Action.do_nothing()), why)

    def _say(self, command: Command, why: str) -> Proposal:
        labelled = Command(command.v, command.w, command.action, self.target, self.name)
        name = self.rt.graph.locations[self.place].name if self.place is not None else "?"
        return Proposal(labelled, f"settling on {name}'s taught spot: {why}")

    def events(self) -> frozenset[str]:
        return frozenset({"settling", "docking on purpose"}) if self._engaged else frozenset()
