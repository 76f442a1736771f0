"""The motion behaviours: each a small class with its own state, born with a task.

Every frame each behaviour first says which views of the frame it needs (``wants``) and then,
from the frozen :class:`~server.navigation.observation.Observation` alone, proposes a command
with its reason, or nothing (``propose``). It may also announce events (``events``) that every
behaviour sees on the next frame in ``Observation.previous``: that is the only way behaviours
learn of each other. None reads or writes another's state; the arbiter
(:mod:`server.navigation.arbiter`) picks one proposal. Docking, which also owns the approach
into the goal, lives in :mod:`server.navigation.docking`.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import replace
from typing import Protocol

import numpy as np
import numpy.typing as npt

from server.belief.model import Action, ActionKind
from server.motion import (
    explore_command,
    navigate_command,
    nearest_ahead,
    open_heading,
    open_side,
    rotate_command,
)
from server.navigation.command import Command, Proposal
from server.navigation.geometry import relative
from server.navigation.localplan import LocalPlanner, goals_ahead
from server.navigation.observation import Observation, ViewRequest, Views, elapsed
from server.navigation.pathtrack import PathEstimate
from server.navigation.pursuit import (
    heading_error,
    lookahead_point,
    lookahead_s,
    pursue,
    steer_to,
    turn_to,
)
from server.navigation.runtime import TourRuntime


class Behaviour(Protocol):
    """A motion behaviour. ``name`` is its place in the arbiter's precedence."""

    name: str

    def wants(self, obs: Observation) -> ViewRequest:
        """The views of this frame :meth:`propose` will read (``obs.views`` is empty here)."""
        ...

    def propose(self, obs: Observation) -> Proposal | None:
        """A command and its reason, or ``None``; updates this behaviour's own state only."""
        ...

    def events(self) -> frozenset[str]:
        """Events of this frame for the others to see on the next one."""
        ...


NOTHING = ViewRequest()
MOVED_AWAY = frozenset({"unsticking", "escaping", "settling", "retracing"})
"""Events that say the robot was driven elsewhere on the last frame, whatever it was doing."""


class DepartureRuns:
    """Runs of frames driven along one edge (the last frame's command Navigate on it, as
    ``leave`` or ``follow``), to tell a departure that lost its edge from a flicker of the
    policy: a run counts once it has lasted ``NavigationParams.departure_min_s`` and ended."""

    def __init__(self, min_s: float) -> None:
        self.min_s = min_s
        self.edge: int | None = None
        self.seconds = 0.0

    @staticmethod
    def _driving(obs: Observation) -> int | None:
        last = None if obs.previous is None else obs.previous.command
        if last is None or last.action.kind != ActionKind.NAVIGATE:
            return None
        return last.action.edge

    def ending(self, obs: Observation) -> int | None:
        """The edge of a run that ends with this frame and counts, if one does (no change)."""
        if self.edge is None or self._driving(obs) == self.edge:
            return None
        return self.edge if self.seconds >= self.min_s else None

    def update(self, obs: Observation) -> int | None:
        """Count this frame; the edge of a run that ended with it and counts, if one did."""
        ended = self.ending(obs)
        edge = self._driving(obs)
        if edge is not None and edge == self.edge:
            self.seconds += obs.dt
        else:
            self.edge, self.seconds = edge, 0.0
        return ended


# -- following an edge ------------------------------------------------------------------------


def follow_views(rt: TourRuntime, edge: int, k: int) -> ViewRequest:
    """The views :func:`follow_command` reads for image ``k`` of ``edge``."""
    e = rt.graph.edges[edge]
    k = int(np.clip(k, 0, e.n_images - 1))
    dep = rt.departure[edge]
    offsets = {rt.edge_image(edge, k)}
    scales: set[int] = set()
    if 0 < dep < e.n_images - 1 and k <= dep:
        scales.add(rt.edge_image(edge, dep))
        offsets.add(rt.edge_image(edge, dep + 1))
    return ViewRequest(offsets=frozenset(offsets), scales=frozenset(scales))


def follow_command(rt: TourRuntime, views: Views, edge: int, k: int, behaviour: str) -> Command:
    """Visual homing on image ``k`` of ``edge`` (Navigate).

    Before the image where the taught robot set off (``TourRuntime.departure``: it turned on
    the spot to face the way out until there) the taught turn is replayed only while the view
    where it set off is not in sight: a frame that matches it (a consensus scale fit of
    ``dock_min_inliers`` within ``MotionParams.toward_offset``) drives on from there. Facing the
    way out from a little further on, the view looks like the end of that turn, and replaying
    the turn spun the robot away from the door it stood at."""
    p = rt.params
    mp = p.motion
    e = rt.graph.edges[edge]
    k = int(np.clip(k, 0, e.n_images - 1))
    dep = rt.departure[edge]
    if 0 < dep < e.n_images - 1 and k <= dep:
        out = views.scale(rt.edge_image(edge, dep))
        if out is not None and (
            out.inliers >= p.dock_min_inliers and abs(out.offset) <= mp.toward_offset
        ):
            k = dep + 1
    target = rt.edge_image(edge, k)
    # a pause while teaching is not repeated (standing still would freeze the belief); the
    # motion replayed is that of the next image that moves. None left: the edge ends.
    moving = rt.moving_from(edge, k)
    if moving is None:
        return Command(0.0, 0.0, Action.navigate(edge), target, behaviour)
    homing = views.offset(target)
    offset = None if homing is None else float(homing.offset)
    v, w = navigate_command(
        offset, taught_v=float(e.v[moving]), taught_w=float(e.w[moving]), params=mp
    )
    return Command(v, w, Action.navigate(edge), target, behaviour)


END_M = 0.05
"""Within this of the end of the route the path follower stands (and turns to the taught
heading at the goal), metres."""


def goal_end(rt: TourRuntime, est: PathEstimate) -> npt.NDArray[np.float64]:
    """``(3,)`` the end of the tracked edge's path (where the goal was taught, the way the
    robot faced on arriving there) in the robot's frame by the estimate: metres ahead and to
    the left, radians to turn."""
    return relative(est.pose, rt.paths[est.edge].poses[-1])


def tracked(rt: TourRuntime, obs: Observation) -> PathEstimate | None:
    """The path estimate, when the tracker is locked on the edge the policy asks for (the
    active edge of Navigate, or the edge RotateAndFindEdge looks for: the robot has joined it
    from where it stands, its view looks like the taught one there, at least
    ``MotionParams.found_similarity``, and the place's spin views say it faces the way the
    edge sets off: :meth:`TourRuntime.faces_departure`)."""
    est = obs.path
    if est is None or not est.locked or asked_edge(obs) != est.edge:
        return None
    if obs.decision.action.kind == ActionKind.ROTATE_AND_FIND_EDGE:
        # joining from a place: only when the view also looks like the taught one there, as
        # a search would need to find it (a corridor's depth and its doors look alike both
        # ways: a tracker locked facing the wrong way sent the robot off backwards)
        seen = float(obs.similarity.image[est.image])
        if seen < rt.params.motion.found_similarity:
            return None
        if not rt.faces_departure(obs.similarity.image, est.edge):
            return None
    return est


def asked_edge(obs: Observation) -> int | None:
    """The edge the policy asks to be on: Navigate's active edge, or the edge
    RotateAndFindEdge looks for (``None`` for Explore and DoNothing)."""
    a = obs.decision.action
    if a.kind == ActionKind.NAVIGATE:
        return obs.decision.active_edge if obs.decision.active_edge is not None else a.edge
    if a.kind == ActionKind.ROTATE_AND_FIND_EDGE:
        return a.edge
    return None


def track_command(
    rt: TourRuntime, obs: Observation, est: PathEstimate, local: LocalPlanner | None = None
) -> tuple[Command, str]:
    """Follow the taught path by the pose relative to it (regulated pure pursuit,
    :mod:`server.navigation.pursuit`), round an obstacle in the way by ``local``'s plan
    (:func:`detour`); at the end of the route, face the way the path
    was taught into the goal."""
    tp = rt.params.topometric
    path = rt.paths[est.edge]
    into_goal = rt.graph.edges[est.edge].target == obs.goal
    action = Action.navigate(est.edge)
    if est.remaining_m <= END_M:
        if not into_goal:
            # the next edge is the policy's to choose once the belief is at the place: creep
            # on the way taught meanwhile (standing still, the belief never got there when
            # the tracker's along was off)
            error = heading_error(est.pose, float(path.poses[-1, 2]))
            w = steer_to(error, tp.pursuit)
            creep = Command(tp.pursuit.min_v, w, action, est.image, "follow")
            return creep, "at the end of the path: on until the next one"
        end = goal_end(rt, est)
        distance = float(np.hypot(end[0], end[1]))
        if distance > tp.arrive_m:  # beside the end (the path ends there): drive onto it
            slow = replace(tp.pursuit, speed=max(rt.params.motion.dock_v, tp.pursuit.min_v))
            v, w = pursue(np.zeros(3), end[:2], params=slow, remaining_m=distance)
            why = f"to the end of the path {distance:.2f} m away"
            return Command(v, w, action, est.image, "follow"), why
        error = heading_error(est.pose, float(path.poses[-1, 2]))
        v, w = (0.0, 0.0) if abs(error) <= 0.05 else turn_to(error, tp.pursuit)
        return Command(v, w, action, est.image, "follow"), "at the goal: facing the way taught"
    nearest = nearest_ahead(obs.depth, rt.params.motion)
    why = f"the path {est.lateral_m:+.2f} m to its side (sd {est.sigma_lateral:.2f} m)"
    way = detour(rt, est, local) if local is not None else None
    if way is not None:
        v, w = pursue(
            np.zeros(3), way, params=tp.pursuit, remaining_m=est.remaining_m, nearest_m=nearest
        )
        return Command(v, w, action, est.image, "follow"), f"round an obstacle to {why}"
    target = lookahead_point(path, est.along_m, est.lateral_m, tp.pursuit)
    v, w = pursue(
        est.pose, target, params=tp.pursuit, remaining_m=est.remaining_m, nearest_m=nearest
    )
    return Command(v, w, action, est.image, "follow"), f"tracking {why}"


def detour(
    rt: TourRuntime, est: PathEstimate, local: LocalPlanner
) -> npt.NDArray[np.float64] | None:
    """``(2,)`` the point to steer at in the robot's frame (metres ahead, to the left) when
    an obstacle the robot remembers lies on the straight line to the point pure pursuit
    steers at: on the local plan round it to the path ahead
    (:meth:`server.navigation.localplan.LocalPlanner.steer`); ``None`` when the way is
    clear, the local plan is off, or no way round is found (then pure pursuit steers, and
    obstacle avoidance keeps the robot off things)."""
    tp = rt.params.topometric
    if not tp.local_plan.enabled:
        return None
    s0 = lookahead_s(est.along_m, est.lateral_m, tp.pursuit)
    return local.steer(goals_ahead(rt.paths[est.edge], est.pose, s0, tp.local_plan))


class Follow:
    """Follow the taught path: by the pose relative to it while the path tracker is locked on
    the edge the policy asks for (topometric repeat, :func:`track_command`); otherwise, on
    Navigate, home along the active edge on the image after the most likely one."""

    name = "follow"

    def __init__(self, runtime: TourRuntime) -> None:
        self.rt = runtime
        self.local = LocalPlanner(
            runtime.params.topometric.local_plan, runtime.params.motion.depth_fov_deg
        )

    def _target(self, obs: Observation) -> tuple[int, int] | None:
        d = obs.decision
        if d.action.kind != ActionKind.NAVIGATE or d.active_edge is None:
            return None
        return d.active_edge, d.target_image if d.target_image is not None else 0

    def wants(self, obs: Observation) -> ViewRequest:
        target = self._target(obs)
        if target is None or tracked(self.rt, obs) is not None:
            return NOTHING
        return follow_views(self.rt, *target)

    def propose(self, obs: Observation) -> Proposal | None:
        self.local.update(obs.v, obs.w, obs.dt, obs.depth)
        est = tracked(self.rt, obs)
        if est is not None:
            return Proposal(*track_command(self.rt, obs, est, self.local))
        target = self._target(obs)
        if target is None:
            return None
        edge, k = target
        return Proposal(follow_command(self.rt, obs.views, edge, k, "follow"), "Navigate")

    def events(self) -> frozenset[str]:
        return frozenset()


# -- finding an edge ----------------------------------------------------------------------------


class FindEdge:
    """RotateAndFindEdge: spin until the view lines up with an image of the edge, then drive
    onto the edge from there (reported as Navigate, so the belief follows onto it) and keep
    going while the frames still match the edge. After ``find_turns`` full turns without
    finding it, the start of the edge is not in sight from here: explore toward open space for
    ``unstick_s`` (labelled ``unstick``), then search afresh (001 7.1). Driving onto the same
    edge more than ``search_departures`` times in a task, losing it each time, is a loop
    (the departure view matches from where the robot stands, the edge does not follow; runs
    along the edge shorter than ``departure_min_s`` are not counted): it
    explores likewise. Each such fruitless round explores longer; after ``search_rounds`` of
    them the task fails (lost) rather than wandering on.

    From a location the sought images are those around where the taught robot began to move
    forward (not the turn on the spot before it: the spin itself finds the heading); turning
    back on an edge, anywhere along the reverse edge. It forgets its search whenever the policy
    stops asking for it, and after an :class:`Unstick` (which moved the robot elsewhere).

    With ``AmbiguityParams.alike_departures``, a departure carries on when the policy asks for
    another edge whose images along the same stretch look like this frame as well (a look-alike
    room's door: the belief, split over the look-alike rooms, flips the vote between their
    edges from frame to frame, and each flip turned the robot back to searching after 0.1-0.7 s
    of driving, so it never left the room whose views would tell them apart).
    """

    name = "find-edge"

    def __init__(self, runtime: TourRuntime) -> None:
        self.rt = runtime
        self.leaving: tuple[int, int, int] | None = None  # edge, image along it, misses
        self.searched_rad = 0.0  # turned while searching without finding the edge
        self.explore_until: float | None = None  # robot time the fruitless-turn explore ends
        self.departures: Counter[int] = Counter()  # runs along each edge that ended, this task
        self.runs = DepartureRuns(runtime.params.departure_min_s)
        self.rounds = 0  # fruitless search rounds this task
        self.why = ""  # why the robot explores
        self._events: frozenset[str] = frozenset()

    def _edge(self, obs: Observation) -> int | None:
        """The edge to find (or to keep leaving along, :meth:`_alike`), or ``None``."""
        a = obs.decision.action
        if a.kind != ActionKind.ROTATE_AND_FIND_EDGE or a.edge is None:
            return None
        leaving = None if self._unstuck(obs) else self.leaving
        if (
            leaving is not None
            and self._alike(obs, leaving, a.edge)
            and self._leave(obs, leaving[0]) is not None
        ):
            return leaving[0]
        return a.edge

    def _alike(self, obs: Observation, leaving: tuple[int, int, int], asked: int) -> bool:
        """Whether the policy, asking for edge ``asked`` while the robot drives onto an edge
        (``leaving``: edge, image along it, misses), asks for a look-alike: this frame matches
        ``asked`` as well, along the same stretch from where the taught robot set off (at least
        ``found_similarity``, the bar a search needs to find it)."""
        edge, k, _ = leaving
        if asked == edge or not self.rt.params.ambiguity.alike_departures:
            return False
        rt = self.rt
        j = rt.departure[asked] + k - rt.departure[edge]
        last = rt.graph.edges[asked].n_images - 1
        window = [rt.edge_image(asked, i) for i in range(max(0, j - 2), min(j + 8, last) + 1)]
        if not window:
            return False
        return float(obs.similarity.image[window].max()) >= rt.params.motion.found_similarity

    def _leave(self, obs: Observation, edge: int) -> tuple[int, int] | None:
        """Where the robot driving onto ``edge`` is now (image, misses), or ``None`` when it is
        not, or has lost the edge."""
        if self.leaving is None or self.leaving[0] != edge:
            return None
        rt, mp = self.rt, self.rt.params.motion
        _, k, misses = self.leaving
        window = [rt.edge_image(edge, j) for j in range(k - 2, k + 8)]
        best = int(np.argmax(obs.similarity.image[window]))
        if float(obs.similarity.image[window[best]]) < mp.lost_similarity:
            misses += 1
        else:
            k, misses = max(k, k - 2 + best), 0
        if misses < mp.lost_steps and k < rt.graph.edges[edge].n_images - 1:
            return k, misses
        return None

    def _sought(self, obs: Observation, edge: int) -> tuple[int, int]:
        """The best-matching sought image of ``edge``: (index along it, canonical index)."""
        rt = self.rt
        last = rt.graph.edges[edge].n_images - 1
        at_location = obs.summary.map_state < rt.graph.n_locations
        dep = rt.departure[edge]
        lo, hi = (max(0, dep - 1), dep + 4) if at_location else (0, last)
        window = [rt.edge_image(edge, j) for j in range(lo, min(hi, last) + 1)]
        best = lo + int(np.argmax(obs.similarity.image[window]))
        return best, rt.edge_image(edge, best)

    def _forget(self) -> None:
        self.leaving, self.searched_rad, self.explore_until = None, 0.0, None

    def wants(self, obs: Observation) -> ViewRequest:
        edge = self._edge(obs)
        if edge is None or self._exploring(obs) or tracked(self.rt, obs) is not None:
            return NOTHING
        leave = None if self._unstuck(obs) else self._leave(obs, edge)
        if leave is not None:
            return follow_views(self.rt, edge, leave[0] + 1)
        _, target = self._sought(obs, edge)
        return ViewRequest(offsets=frozenset({target})) | follow_views(
            self.rt, edge, self._sought(obs, edge)[0] + 1
        )

    def _unstuck(self, obs: Observation) -> bool:
        """Whether an :class:`Unstick`, an :class:`Escape` or a settling on a place ran on the
        last frame (the robot went elsewhere)."""
        return obs.previous is not None and bool(obs.previous.events & MOVED_AWAY)

    def _exploring(self, obs: Observation) -> bool:
        return self.explore_until is not None and elapsed(self.explore_until, obs.t) > 0

    def propose(self, obs: Observation) -> Proposal | None:
        self._events = frozenset()
        ended = self.runs.update(obs)
        if ended is not None:
            self.departures[ended] += 1
        if self._unstuck(obs):
            self.leaving, self.searched_rad = None, 0.0
        if self._exploring(obs):
            return self._explore(obs)
        if obs.decision.action.kind != ActionKind.ROTATE_AND_FIND_EDGE or tracked(self.rt, obs):
            self._forget()  # (the path tracker has joined the edge: following takes over)
            return None
        edge = self._edge(obs)
        if edge is None:
            return None
        if self.explore_until is not None:  # explored after a fruitless turn: search afresh
            self.explore_until, self.searched_rad = None, 0.0
        leave = self._leave(obs, edge)
        if leave is not None:
            k, misses = leave
            self.leaving, self.searched_rad = (edge, k, misses), 0.0
            command = follow_command(self.rt, obs.views, edge, k + 1, "leave")
            if edge != obs.decision.action.edge:  # the vote flipped to a look-alike: on
                return Proposal(command, "driving on: the edge asked for looks alike here")
            return Proposal(command, "driving onto the edge it found")
        self.leaving = None
        command, why = self._search(obs, edge)
        p = self.rt.params
        if command.action.kind != ActionKind.ROTATE_AND_FIND_EDGE:  # found: driving onto it
            if self.departures[edge] < p.search_departures:
                return Proposal(command, why)
            self.departures[edge], self.leaving = 0, None
            return self._fruitless(obs, f"lost the edge {p.search_departures} times after leaving")
        self.searched_rad += abs(command.w) * obs.dt
        if self.searched_rad >= 2 * np.pi * p.motion.find_turns:
            return self._fruitless(obs, f"{p.motion.find_turns} turns without finding the edge")
        return Proposal(command, why)

    def _fruitless(self, obs: Observation, why: str) -> Proposal:
        """A search round that found nothing: explore, longer each round; give up after
        ``search_rounds``."""
        p = self.rt.params
        self.rounds += 1
        if self.rounds > p.search_rounds:
            self._events = frozenset({f"failed: lost: {p.search_rounds} searches found no edge"})
        self.explore_until = obs.t + p.motion.unstick_s * min(self.rounds, 3)
        self.why = f"{why} (round {self.rounds})"
        return self._explore(obs)

    def _search(self, obs: Observation, edge: int) -> tuple[Command, str]:
        rt, mp = self.rt, self.rt.params.motion
        best, target = self._sought(obs, edge)
        last = rt.graph.edges[edge].n_images - 1
        view = float(obs.similarity.image[target])
        homing = obs.views.offset(target)
        # a view where the edge ends leaves nothing to drive onto: spinning on lets the
        # belief move (reporting Navigate would not take it off the reverse edge)
        ends_here = rt.moving_from(edge, min(best + 1, last)) is None
        if homing is not None and view >= mp.found_similarity and not ends_here:
            if abs(homing.offset) <= mp.found_offset:
                self.leaving = (edge, best, 0)
                found = follow_command(rt, obs.views, edge, best + 1, "leave")
                return found, "lined up with the edge's departure view"
            if homing.n_matches >= mp.toward_matches and abs(homing.offset) <= mp.toward_offset:
                turn = rotate_command(mp, toward=float(homing.offset))
                return Command(*turn, Action.rotate(edge), target, "search"), "turning toward it"
        spin = Command(*rotate_command(mp), Action.rotate(edge), target, "search")
        return spin, "looking for the edge"

    def _explore(self, obs: Observation) -> Proposal:
        mp = self.rt.params.motion
        command = Command(*explore_command(obs.depth, mp), Action.explore(), None, "unstick")
        return Proposal(command, self.why)

    def events(self) -> frozenset[str]:
        return self._events


# -- retracing -----------------------------------------------------------------------------------


class Retrace:
    """Recovery by retracing: a path tracker that has lost the taught path for
    ``TopometricParams.retrace_after_s`` while the policy still asks for that edge drives back
    along the robot's own odometry trace (backwards, so the camera keeps facing the way the
    path goes) to where it was last locked on, at most ``retrace_max_m`` back, then lets the
    others carry on from there (the camera sees what it saw when it knew where it was). Once
    per place it was last locked on; spinning and exploring remain for a robot with no trace
    (carried elsewhere)."""

    name = "retrace"

    def __init__(self, runtime: TourRuntime) -> None:
        self.rt = runtime
        self.active = False
        self.done: set[tuple[int, float, float]] = set()  # last-locked poses retraced to
        self._events: frozenset[str] = frozenset()

    def wants(self, obs: Observation) -> ViewRequest:
        return NOTHING

    def propose(self, obs: Observation) -> Proposal | None:
        self._events = frozenset()
        tp = self.rt.params.topometric
        est, route = obs.path, obs.retrace
        if not tp.enabled or est is None or est.locked or not route:
            self.active = False
            return None
        asked = asked_edge(obs)
        if asked != est.edge or (not self.active and est.since_fix_s < tp.retrace_after_s):
            self.active = False
            return None
        goal = route[-1]
        key = (est.edge, round(float(goal[0]), 2), round(float(goal[1]), 2))
        if key in self.done:
            return None
        points = np.array([p[:2] for p in route])
        length = float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())
        if length > tp.retrace_max_m:
            self.done.add(key)
            return None
        here = est.pose[:2]
        if float(np.linalg.norm(here - goal[:2])) <= 0.08:
            self.active = False
            self.done.add(key)
            stand = Command(0.0, 0.0, Action.navigate(est.edge), est.image, "retrace")
            return Proposal(stand, "back where the path was last tracked")
        self.active = True
        self._events = frozenset({"retracing"})
        return Proposal(self._back(est, points), "lost the path: driving back along its trace")

    def _back(self, est: PathEstimate, points: npt.NDArray[np.float64]) -> Command:
        """Reverse pure pursuit toward the trace point ~0.3 m back (or its end)."""
        tp = self.rt.params.topometric
        dist = np.linalg.norm(points - est.pose[:2], axis=1)
        far = np.nonzero(dist >= 0.3)[0]
        target = points[far[0]] if len(far) else points[-1]
        flipped = np.array([est.pose[0], est.pose[1], est.pose[2] + np.pi])
        v, w = pursue(flipped, target, params=tp.pursuit, remaining_m=float(dist[-1]))
        return Command(-min(v, 0.15), w, Action.navigate(est.edge), est.image, "retrace")

    def events(self) -> frozenset[str]:
        return self._events


# -- exploring, standing -----------------------------------------------------------------------


class Explore:
    """Explore: head for open space (the belief is too flat to vote for anything else)."""

    name = "explore"

    def __init__(self, runtime: TourRuntime) -> None:
        self.mp = runtime.params.motion

    def wants(self, obs: Observation) -> ViewRequest:
        return NOTHING

    def propose(self, obs: Observation) -> Proposal | None:
        if obs.decision.action.kind != ActionKind.EXPLORE:
            return None
        action = obs.decision.action
        command = Command(*explore_command(obs.depth, self.mp), action, None, "explore")
        return Proposal(command, "no confident position")

    def events(self) -> frozenset[str]:
        return frozenset()


class Stand:
    """The policy's action with no motion: DoNothing at the goal, or nothing else applies."""

    name = "stand"

    def __init__(self, runtime: TourRuntime) -> None:
        pass

    def wants(self, obs: Observation) -> ViewRequest:
        return NOTHING

    def propose(self, obs: Observation) -> Proposal | None:
        return Proposal(Command(0.0, 0.0, obs.decision.action), obs.decision.action.kind.value)

    def events(self) -> frozenset[str]:
        return frozenset()


# -- getting free ------------------------------------------------------------------------------


class Unstick:
    """Stall watchdog: a robot that has driven less than ``stall_m`` (by its reported speed) in
    ``stall_s`` of robot time is stuck, whatever the reason (pressed against a wall beside a door
    it is homing at, a search that keeps almost finding its edge): it explores toward open space
    for ``MotionParams.unstick_s``, whatever the policy says, and then carries on. Turning on the
    spot on purpose (place docking) and backing off are not being stuck: the window restarts."""

    name = "unstick"

    def __init__(self, runtime: TourRuntime) -> None:
        self.p = runtime.params
        self.since: float | None = None  # robot time the current window began
        self.driven = 0.0  # metres driven in it (as reported)
        self.until: float | None = None
        self._active = False

    def wants(self, obs: Observation) -> ViewRequest:
        return NOTHING

    def propose(self, obs: Observation) -> Proposal | None:
        p = self.p
        if obs.previous is not None and obs.previous.events & {
            "bumped",
            "escaping",
            "docking on purpose",
        }:
            self.since = None
        self._active = False
        if p.stall_s > 0:
            if self.since is None:
                self.since, self.driven = obs.t, 0.0
            self.driven += abs(obs.v) * obs.dt
            if self.driven >= p.stall_m:
                self.since, self.driven = obs.t, 0.0
            elif elapsed(obs.t, self.since) >= p.stall_s:
                self.until = obs.t + p.motion.unstick_s
                self.since, self.driven = obs.t, 0.0
        if self.until is None or elapsed(self.until, obs.t) <= 0:
            return None
        self._active = True
        command = Command(*explore_command(obs.depth, p.motion), Action.explore(), None, "unstick")
        return Proposal(command, f"less than {p.stall_m} m in {p.stall_s:.0f} s")

    def events(self) -> frozenset[str]:
        return frozenset({"unsticking"}) if self._active else frozenset()


class Backoff:
    """Bump reflex: a robot told to drive forward that reports less than ``bump_fraction`` of
    the commanded speed for ``bump_s`` is pressed against something its depth profile does not
    show (a chair's corner beside its field of view); it backs off (``MotionParams.backoff_v``
    for ``backoff_s``) turning toward the more open side, then carries on."""

    name = "backoff"

    def __init__(self, runtime: TourRuntime) -> None:
        self.p = runtime.params
        self.bumped_s = 0.0  # robot seconds driven against something
        self.until: float | None = None
        self.turn = 0.0
        self._fired = False

    def wants(self, obs: Observation) -> ViewRequest:
        return NOTHING

    def propose(self, obs: Observation) -> Proposal | None:
        p, mp = self.p, self.p.motion
        self._fired = False
        last = None if obs.previous is None else obs.previous.command
        if self.until is not None:
            if elapsed(self.until, obs.t) > 0:
                return self._back("backing off")
            self.until = None
        if p.bump_s <= 0 or last is None or last.v < mp.min_v / 2:
            self.bumped_s = 0.0
            return None
        pressed = obs.v < p.bump_fraction * last.v
        self.bumped_s = self.bumped_s + obs.dt if pressed else 0.0
        if self.bumped_s < p.bump_s:
            return None
        # back away turning toward the more open side, so the next try comes in at an angle
        self.bumped_s = 0.0
        self.until = obs.t + mp.backoff_s
        self.turn = mp.spin_w * open_side(obs.depth, mp)
        self._fired = True
        return self._back(f"no progress for {p.bump_s} s while driving forward")

    def _back(self, why: str) -> Proposal:
        command = Command(-self.p.motion.backoff_v, self.turn, Action.do_nothing(), None, "backoff")
        return Proposal(command, why)

    def events(self) -> frozenset[str]:
        return frozenset({"bumped"}) if self._fired else frozenset()


class Escape:
    """Escape from where the robot cannot go on: the behaviour that won wanted to drive forward
    for ``escape_s`` and the robot drove less than ``escape_m`` (obstacle avoidance holding it
    at a door frame, or pressed against something). It backs off (``MotionParams.backoff_v``
    for ``backoff_s``, turning toward the more open side), turns on the spot to the most open
    direction of the depth profile, drives that way for ``escape_go_s`` and lets the others
    try again. Back-offs of the bump reflex count as escapes. More than ``escape_tries``
    escapes with no ``escape_free_m`` of driving after any of them fail the task (stuck).
    Docking on purpose (creeping onto a place) is not being held."""

    name = "escape"

    def __init__(self, runtime: TourRuntime) -> None:
        self.p = runtime.params
        self.window: tuple[float, float] | None = None  # robot time it began, metres driven
        self.phase: str | None = None  # back, turn, go
        self.until = 0.0  # robot time the phase ends (at the latest)
        self.turn = 0.0  # rad/s while backing off
        self.tries = 0
        self.free_m = 0.0  # metres driven since the last escape
        self._events: frozenset[str] = frozenset()

    def wants(self, obs: Observation) -> ViewRequest:
        return NOTHING

    def propose(self, obs: Observation) -> Proposal | None:
        self._events = frozenset()
        if self.p.escape_s <= 0:
            return None
        if self.phase is None and not self._held(obs):
            return None
        proposal = self._run(obs)
        if proposal is not None:
            self._events |= {"escaping"}
        return proposal

    def _held(self, obs: Observation) -> bool:
        """Whether an escape starts this frame (counting the tries and how far the robot has
        driven since the last one)."""
        p, mp, prev = self.p, self.p.motion, obs.previous
        if self.tries:
            self.free_m += abs(obs.v) * obs.dt
            if self.free_m >= p.escape_free_m:
                self.tries, self.free_m = 0, 0.0
        if prev is not None and "bumped" in prev.events:
            self.window = None
            self._tried()
            return False
        wanted = None if prev is None else prev.wanted
        if (
            prev is None
            or wanted is None
            or wanted.v < mp.min_v / 2
            or prev.winner == self.name
            or "docking on purpose" in prev.events
        ):
            self.window = None
            return False
        start, driven = self.window or (obs.t, 0.0)
        driven += abs(obs.v) * obs.dt
        if driven >= p.escape_m:
            start, driven = obs.t, 0.0
        self.window = (start, driven)
        if elapsed(obs.t, start) < p.escape_s:
            return False
        self.window = None
        if not self._tried():
            return False
        self.phase, self.until = "back", obs.t + mp.backoff_s
        self.turn = mp.spin_w * open_side(obs.depth, mp)
        return True

    def _tried(self) -> bool:
        """Count an escape; ``False`` (and the task fails) when there have been too many."""
        self.tries, self.free_m = self.tries + 1, 0.0
        if self.tries <= self.p.escape_tries:
            return True
        self._events = frozenset(
            {f"failed: stuck: {self.p.escape_tries} escapes did not free the robot"}
        )
        return False

    def _run(self, obs: Observation) -> Proposal | None:
        mp = self.p.motion
        if self.phase == "back":
            if elapsed(self.until, obs.t) > 0:
                command = Command(-mp.backoff_v, self.turn, Action.do_nothing(), None, "escape")
                return Proposal(command, f"backing off: held for {self.p.escape_s:.0f} s")
            self.phase, self.until = "turn", obs.t + mp.escape_turn_s
        if self.phase == "turn":
            found = open_heading(obs.depth, mp)
            if found is not None and elapsed(self.until, obs.t) > 0:
                bearing, far = found
                if abs(bearing) > mp.escape_aim_rad or far < mp.avoid_start_m:
                    side = np.sign(bearing) if abs(bearing) > mp.escape_aim_rad else 0.0
                    w = mp.spin_w * float(side or np.sign(self.turn) or 1.0)
                    command = Command(0.0, w, Action.do_nothing(), None, "escape")
                    return Proposal(command, "turning to the most open side")
            self.phase, self.until = "go", obs.t + mp.escape_go_s
        if self.phase == "go" and elapsed(self.until, obs.t) > 0:
            command = Command(*explore_command(obs.depth, mp), Action.explore(), None, "escape")
            return Proposal(command, "driving into open space")
        self.phase = None
        return None

    def events(self) -> frozenset[str]:
        return self._events
