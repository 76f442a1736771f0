"""Docking at the goal, and the approach into it that says when to dock.

One behaviour with one state, because its parts hand over to each other:

* the approach (``NavigationParams.approach_s``): robot time spent following a taught edge into
  the goal, as the robot's last move; it is counted from the motion the arbiter chose this frame
  (:meth:`Docking.track`);
* place docking (``place_dock``, :meth:`Docking.place`): a robot whose belief is at the goal
  before it came in along an edge docks on the goal's own spin images, on two axes (look for
  one, creep along it until the scale agrees, turn a quarter turn, again), then counts as
  approached;
* docking along the edge (``dock``, :meth:`Docking.confirm`): once the belief has arrived after
  an approach, the view has the last word: it creeps on or backs up until the scale of the
  edge's last views agrees, then (``dock_second_axis``) turns a quarter turn and place-docks a
  second axis.

The arbiter asks :meth:`place` among the motion behaviours and :meth:`confirm` last.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from server.belief.model import Action, ActionKind
from server.motion import navigate_command, ray_angles, rotate_command
from server.navigation.behaviours import goal_end, track_command
from server.navigation.command import Command, Proposal
from server.navigation.geometry import inverse, relative
from server.navigation.observation import Observation, ViewRequest, Views
from server.navigation.params import NavigationParams
from server.navigation.pathtrack import PathEstimate
from server.navigation.pursuit import heading_error, pursue, steer_to
from server.navigation.runtime import TourRuntime
from server.navigation.scanmatch import ScanFit, match_profiles_starts
from server.navigation.tracking import move
from server.vision.homing import ScaleResult


def top_spins(rt: TourRuntime, obs: Observation, location: int, most: int = 3) -> list[int]:
    """``location``'s spin images (canonical indices) the engine ranks highest for this frame."""
    spins = rt.spin_images[location]
    ranked = spins[np.argsort(-obs.similarity.image[spins], kind="stable")[:most]]
    return [int(i) for i in ranked]


SPOT_M = 0.08
"""Within this of a place's taught spot (by the depth profiles) the robot stands on it, m."""
AMBIGUOUS_SCORE = 0.01
"""An alignment of the profiles elsewhere whose score is within this of the best one's makes
the spot ambiguous (:attr:`~server.navigation.scanmatch.ScanFit.score`)."""


def spot_by_scan(
    rt: TourRuntime, obs: Observation, location: int
) -> npt.NDArray[np.float64] | None:
    """Where ``location``'s taught spot is, in the robot's frame (``(2,)`` metres, x ahead, y
    left), from the frame's depth profile aligned with those taught with the place's spin
    images (all taken on the spot; the three the engine ranks highest for this frame are
    tried, from starts up to 1.2 m around it:
    :func:`~server.navigation.scanmatch.match_profiles_starts`). ``None`` without a depth
    profile or taught ones; when the place's best spin view is less similar to the frame than
    ``MotionParams.found_similarity`` (a depth profile aligns with any wall: the camera must
    see the place); when none aligns well (fewer than 10 points agreeing, or more than 5 cm
    apart on average); or when another alignment about as good puts the spot elsewhere."""
    tp = rt.params.topometric
    if obs.depth is None or not tp.enabled or not tp.scan:
        return None
    spins = top_spins(rt, obs, location)
    if not spins or float(obs.similarity.image[spins[0]]) < rt.params.motion.found_similarity:
        return None
    fits: list[ScanFit] = []
    for image in spins:
        taught = rt.taught_depth.get(image)
        if taught is None:
            continue
        fits += match_profiles_starts(
            taught,
            obs.depth,
            np.zeros(3),
            fov_deg=tp.depth_fov_deg,
            params=tp.scan_fit,
            lateral_m=(0.0, 0.6, -0.6, 1.2, -1.2),
            along_m=(0.0, 0.6, -0.6),
            turns_rad=(0.0,),
        )
    if not fits:
        return None
    fits.sort(key=lambda f: f.score)
    best = fits[0]
    if best.pairs < 10 or best.rms_m > 0.05:
        return None
    # the robot's pose in the spin image's frame, whose origin is the spot: the spot as the
    # robot sees it
    spot = inverse(best.pose)[:2]
    for other in fits[1:]:  # another alignment about as good puts it elsewhere: cannot tell
        if other.score > best.score + AMBIGUOUS_SCORE:
            break
        if float(np.hypot(*(inverse(other.pose)[:2] - spot))) > 2 * SPOT_M:
            return None
    return np.asarray(spot, dtype=np.float64)


class SpotFix:
    """A place's taught spot as the depth profiles place it, kept between frames: each
    frame's estimate (:func:`spot_by_scan`) is carried to the next by the robot's odometry,
    and the spot counts as found only when two estimates in a row agree within ``agree_m``
    (a place's spin profiles can align wrongly, one frame here, the next there: the robot
    turned back and forth in a hall so). A found spot is carried on by the odometry through
    up to ``carry_frames`` frames whose profiles say nothing (docking drives on, rather than
    standing still on each such frame)."""

    agree_m = 0.25
    carry_frames = 5

    def __init__(self) -> None:
        self.spot: npt.NDArray[np.float64] | None = None  # robot frame, last frame's estimate
        self.found: npt.NDArray[np.float64] | None = None  # robot frame, last found spot
        self.carried = 0  # frames the found spot has been carried without a new one

    def reset(self) -> None:
        self.spot = self.found = None
        self.carried = 0

    def update(
        self, rt: TourRuntime, obs: Observation, location: int
    ) -> npt.NDArray[np.float64] | None:
        """The spot in the robot's frame when this frame's estimate agrees with the last
        one's (carried by the odometry), or the last found spot carried here; else ``None``
        (it remembers this frame's estimate)."""
        moved = move(np.zeros(3), obs.v, obs.w, obs.dt)
        previous, carried = (
            None if spot is None else relative(moved, np.array([spot[0], spot[1], 0.0]))[:2]
            for spot in (self.spot, self.found)
        )
        estimate = spot_by_scan(rt, obs, location)
        self.spot = estimate
        if (
            estimate is not None
            and previous is not None
            and float(np.hypot(*(estimate - previous))) <= self.agree_m
        ):
            self.found, self.carried = estimate, 0
            return estimate
        self.carried += 1
        disagrees = estimate is not None and (
            carried is None or float(np.hypot(*(estimate - carried))) > self.agree_m
        )
        if carried is None or disagrees or self.carried > self.carry_frames:
            self.found = None
            return None
        self.found = carried
        return carried


def seen_further(
    depth: npt.ArrayLike,
    taught: npt.ArrayLike,
    turn: float,
    *,
    fov_deg: float,
    half_angle_rad: float,
    max_range_m: float,
) -> float | None:
    """How much further the robot sees straight ahead than a taught profile did, m: the median,
    over the rays of ``depth`` within ``half_angle_rad`` of straight ahead, of their range less
    the taught range looking the same way (``turn``: the robot's heading less the taught
    one's, rad; the robot's own offset is what is measured, so it is not corrected for):
    interpolated between the two taught rays either side where both saw a surface, else that
    of the nearest taught ray.
    A ray that sees nothing (not finite, or beyond ``max_range_m``) where the taught one saw a
    surface counts as ``inf`` further; taught rays that saw nothing are left out. ``None``
    when fewer than three rays are left (the taught view saw nothing ahead: it cannot tell).

    Both profiles ``(n,)`` and ``(m,)`` span ``fov_deg``, leftmost ray first."""
    now = np.asarray(depth, dtype=np.float64)
    was = np.asarray(taught, dtype=np.float64)
    if len(now) < 2 or len(was) < 2:
        return None
    angles = ray_angles(len(now), fov_deg)
    half = np.radians(fov_deg) / 2
    step = 2 * half / (len(was) - 1)
    # where each ray looks among the taught rays (taught ray i looks at half - i step):
    # between two that saw a surface, their ranges interpolated; else the nearest one's
    at = (half - (angles + turn)) / step
    use = (np.abs(angles) <= half_angle_rad) & (at > -0.5) & (at < len(was) - 0.5)
    seen = np.isfinite(was) & (was < max_range_m)
    lo = np.clip(np.floor(at).astype(np.int64), 0, len(was) - 2)
    f = np.clip(at - lo, 0.0, 1.0)
    both = seen[lo] & seen[lo + 1]
    nearest = np.clip(np.round(at).astype(np.int64), 0, len(was) - 1)
    safe = np.where(seen, was, 0.0)
    then = np.where(both, (1 - f) * safe[lo] + f * safe[lo + 1], was[nearest])
    use &= both | seen[nearest]
    if int(use.sum()) < 3:
        return None
    r = now[use]
    further = np.where(np.isfinite(r) & (r < max_range_m), r - then[use], np.inf)
    return float(np.median(further))


def toward_spot(spot: npt.NDArray[np.float64], rt: TourRuntime) -> tuple[float, float]:
    """``(v, w)`` driving to ``spot`` (robot frame), slowly (``MotionParams.dock_v``, turning
    to face it first when it lies far to the side or behind)."""
    tp = rt.params.topometric
    slow = replace(tp.pursuit, speed=max(rt.params.motion.dock_v, tp.pursuit.min_v))
    distance = float(np.hypot(*spot))
    return pursue(np.zeros(3), spot, params=slow, remaining_m=distance)


def best_fit(
    fits: Callable[[int], ScaleResult | None], candidates: list[int]
) -> tuple[int, ScaleResult | None]:
    """Of ``candidates``, the one the frame fits best by ``fits`` (most inliers; docking reads
    :meth:`Views.zoomed_scale`) and that fit; the first and ``None`` when none fits."""
    best: tuple[int, ScaleResult | None] = (candidates[0] if candidates else 0, None)
    for i in candidates:
        fit = fits(i)
        if fit is not None and (best[1] is None or fit.inliers > best[1].inliers):
            best = (i, fit)
    return best


def look_fit(
    views: Views, candidates: list[int], p: NavigationParams
) -> tuple[int, ScaleResult | None]:
    """The view looked for among ``candidates`` (place docking and settling turn until one is
    in sight and lined up) and its fit: :func:`best_fit` of the zoomed fits, read on the
    taught images' zooms with ``dock_taught_zooms`` ``"look"`` (no extraction of the frame's
    zooms while turning). Creeping and the verdicts read the frame's zooms."""
    fits = views.taught_zoomed_scale if p.dock_taught_zooms == "look" else views.zoomed_scale
    return best_fit(fits, candidates)


def scale_verdict(log_scales: list[float], fit: ScaleResult, tol: float) -> tuple[bool, bool]:
    """Add ``fit``'s scale to ``log_scales`` (the last three are kept) and say from their
    median whether the robot stands short of the view (``(True, False)``), past it
    (``(False, True)``) or within ``tol`` (relative) of it (``(False, False)``)."""
    log_scales.append(float(np.log(fit.scale)))
    del log_scales[:-3]
    log_scale = float(np.median(log_scales))
    return log_scale > np.log1p(tol), log_scale < np.log1p(-tol)


@dataclass
class Approach:
    """How the robot has been coming into the goal."""

    seconds: float = 0.0  # robot time following a taught edge into the goal
    done: bool = False  # for approach_s, as its last move (or no approach is needed)
    edge: int | None = None  # the edge of that approach
    dock_m: float = 0.0  # metres of docking moves commanded since the approach began
    log_scales: list[float] = field(default_factory=list)  # docking's last few log scales
    spot_checks: int = 0  # frames held at the tracked end for the place's depth to tell
    crept_m: float | None = None  # metres crept on from the tracked end (None: not creeping)
    crept_there: bool = False  # the creep from the tracked end has ended: there
    on_spot: bool = False  # place docking put the robot on the taught spot (done by it)

    def docked_on_spot(self) -> None:
        """Place docking has put the robot on the taught spot: the approach is done."""
        self.done, self.edge, self.on_spot = True, None, True


SPOT_CHECKS = 3
"""Frames the robot holds at the end of a tracked path for the place's depth to tell."""
SPOT_HANDOVER_M = 0.25
"""A taught spot by the place's depth further than this from the end of a tracked path
hands over to place docking, m."""
SCAN_MISSES = 5
"""Frames in a row docking by depth may find no spot before the views' scale takes over."""


@dataclass
class PlaceDocking:
    """Docking on the goal's spin images: the phase (idle, look, scan, creep, turn, done, off), axes
    docked, the spin image docked on, radians turned and metres crept (as commanded) in this
    phase, the last few log scales on this axis, radians turned with the belief off the goal,
    and whether this is the second axis of docking along an edge; ``turned``: radians turned
    since place docking started, whatever the phase (the depth's turning budget: a spot found
    and lost again starts the look afresh)."""

    phase: str = "idle"
    axes: int = 0
    target: int | None = None
    rad: float = 0.0
    m: float = 0.0
    log_scales: list[float] = field(default_factory=list)
    away_rad: float = 0.0
    second_axis: bool = False
    scan_misses: int = 0
    turned: float = 0.0

    def start(self, phase: str) -> None:
        self.phase, self.rad, self.m = phase, 0.0, 0.0
        self.log_scales.clear()


class Docking:
    """Place docking, the approach and docking along the edge, for one task's goal."""

    name = "place-dock"

    def __init__(self, runtime: TourRuntime, goal: int) -> None:
        self.rt = runtime
        self.p = runtime.params
        self.goal = goal
        self.needs_approach = self.p.approach_s > 0 and runtime.approachable[goal]
        # the approach rule is on but the goal has no round trip to come in by
        self.waived = self.p.approach_s > 0 and not runtime.approachable[goal]
        self.approach = Approach(done=not self.needs_approach)
        self.placing = PlaceDocking()
        self.spot = SpotFix()  # the goal's taught spot by the depth profiles
        self._engaged = False

    # -- views -------------------------------------------------------------------------------

    def _edge_ends(self, edge: int, most: int = 8) -> list[int]:
        """The images taught at the end of ``edge``: from the last one taught while moving
        forward (where the guide may have turned to name the place), ``most`` evenly spaced."""
        rt = self.rt
        last = rt.graph.edges[edge].n_images - 1
        ks = np.unique(np.linspace(rt.arrival[edge], last, most).round().astype(int))
        return [rt.edge_image(edge, int(k)) for k in ks]

    def wants(self, obs: Observation) -> ViewRequest:
        """Spin views while place docking may look, its target while it creeps, and the edge's
        end views (for every edge the robot may be coming in on) when the arrival may be
        confirmed this frame.

        While place docking turns or creeps, this frame's :meth:`place` and :meth:`confirm`
        read at most its target: nothing during a quarter turn that this frame does not end
        (:meth:`place` turns on, or gives up with the belief off the goal, and then
        :meth:`confirm` has nothing to confirm), the target only while creeping (a lost view
        turns without looking), no spin view while it docks by the depth only
        (:meth:`_by_depth`). A frame that asks for nothing zooms nothing."""
        pl = self.placing
        if self.p.place_dock and pl.phase == "turn" and not self._turn_ends(obs):
            return ViewRequest()
        if self.p.place_dock and pl.phase == "creep":
            return ViewRequest(zoomed=frozenset({int(pl.target if pl.target is not None else 0)}))
        zoomed: set[int] = set()
        looks = pl.phase in ("turn", "creep") or (
            pl.phase in ("look", "scan") and not self._by_depth(obs)
        )
        if (self.p.place_dock and looks) or (pl.phase == "idle" and obs.at_goal):
            zoomed.update(self._spins(obs))
            if pl.target is not None:
                zoomed.add(pl.target)
        return ViewRequest(zoomed=frozenset(zoomed | self._arrival_views(obs)))

    def _arrival_views(self, obs: Observation) -> set[int]:
        """The edge's end views (every edge the robot may be coming in on) and the spin views,
        when :meth:`confirm` may confirm an arrival this frame."""
        a, pl = self.approach, self.placing
        could_arrive = a.done or a.seconds + obs.dt >= self.p.approach_s
        if not (self.p.dock and obs.at_goal and not pl.second_axis and could_arrive):
            return set()
        zoomed: set[int] = set()
        d = obs.decision
        for edge in {a.edge, d.active_edge, d.action.edge}:
            if edge is not None and self.rt.graph.edges[edge].target == self.goal:
                zoomed.update(self._edge_ends(edge))
        zoomed.update(self._spins(obs))
        return zoomed

    def _turn_ends(self, obs: Observation) -> bool:
        """Whether place docking's quarter turn reaches pi / 2 this frame (as
        :meth:`_turned_away` and :meth:`place` will count it)."""
        pl, last = self.placing, None if obs.previous is None else obs.previous.command
        rad = pl.rad if last is None else pl.rad + abs(last.w) * obs.dt
        return not rad < np.pi / 2

    def _best(self, views: Views, candidates: list[int]) -> tuple[int, ScaleResult | None]:
        return best_fit(views.zoomed_scale, candidates)

    def _verdict(self, log_scales: list[float], fit: ScaleResult) -> tuple[bool, bool]:
        return scale_verdict(log_scales, fit, self.p.dock_scale_tol)

    def _spins(self, obs: Observation, most: int = 3) -> list[int]:
        """The goal's spin images the engine ranks highest for this frame."""
        return top_spins(self.rt, obs, self.goal, most)

    # -- place docking -----------------------------------------------------------------------

    def place(self, obs: Observation) -> Proposal | None:
        """Docking on the goal's own spin images (reported as DoNothing: the robot turns and
        creeps on the spot as far as the belief is concerned), or ``None``."""
        self._engaged = False
        pl = self.placing
        if not self._placing(obs):
            return None
        self._engaged = True  # turning on the spot on purpose is not being stuck
        scanned = self._scan_dock(obs)
        if scanned is not None:
            return scanned
        if pl.phase == "turn":
            if pl.rad < np.pi / 2:
                return self._turn("turning a quarter turn to dock a second axis")
            pl.start("look")
        if pl.phase == "look":
            looked = self._look(obs)
            if looked is not None or pl.phase == "off":
                return looked
        return self._creep(obs)

    def _scan_dock(self, obs: Observation) -> Proposal | None:
        """Dock on the goal's taught spot by the depth profiles (:func:`spot_by_scan`): drive
        to it and stand there (docked: the approach is done). ``None`` when the profiles
        cannot tell (no depth, nothing aligns): the views' scale docks instead."""
        pl = self.placing
        if pl.phase not in ("look", "scan"):
            return None
        spot = self.spot.update(self.rt, obs, self.goal)
        if spot is None:
            if pl.phase == "scan":
                pl.scan_misses += 1
                if pl.scan_misses <= SCAN_MISSES:  # a frame that cannot tell: hold still
                    hold = Command(0.0, 0.0, Action.do_nothing(), None, "place-dock")
                    return Proposal(hold, "the depth profile says nothing this frame")
                pl.start("look")
            return None
        pl.phase, pl.scan_misses = "scan", 0
        if float(np.hypot(*spot)) <= SPOT_M:
            pl.phase = "done"
            self.approach.docked_on_spot()
            return Proposal(Command(0.0, 0.0, Action.do_nothing()), "on the taught spot (depth)")
        v, w = toward_spot(spot, self.rt)
        command = Command(v, w, Action.do_nothing(), None, "place-dock")
        return Proposal(command, f"to the taught spot {float(np.hypot(*spot)):.2f} m away (depth)")

    def _placing(self, obs: Observation) -> bool:
        """Whether place docking goes on (or starts) this frame: off when it is switched off,
        done, given up, not needed (the robot came in along an edge) or turned away. A goal
        whose approach is waived (no round trip to come in by: a place with no taught edge out
        of it, as the last place of a tour) is docked on too unless the robot came in along an
        edge: without, the belief alone said "arrived" (a robot carried into the corridor
        beside the hall "arrived" at a dead-end office 5.2 m away after a server restart). With the
        approach rule off (``approach_s`` 0) the belief's word stands, as it did."""
        pl, p, a = self.placing, self.p, self.approach
        if not p.place_dock or pl.phase in ("done", "off"):
            return False
        came_in = a.done and (a.edge is not None or not self.waived)
        if came_in and pl.phase == "idle":
            return False  # came in along an edge: docking proper (and its second axis) decides
        if pl.phase != "idle":
            return not self._turned_away(obs)
        if not obs.at_goal:
            return False
        if (obs.goal_ambiguity or 0.0) > p.place_dock_ambiguity:
            pl.phase = "off"  # a look-alike place: come in along an edge
            return False
        pl.start("look")
        return True

    def _turned_away(self, obs: Observation) -> bool:
        """Count what the last command turned and crept; give up (``off``) once it has turned
        ``place_dock_away`` with the belief off the goal. At the place its spin images show all
        round; a turn that mostly sees elsewhere says a look-alike view started the docking."""
        pl, last = self.placing, None if obs.previous is None else obs.previous.command
        if last is None:
            return False
        pl.rad += abs(last.w) * obs.dt
        pl.turned += abs(last.w) * obs.dt
        pl.m += abs(last.v) * obs.dt
        if not obs.at_goal:
            pl.away_rad += abs(last.w) * obs.dt
            if pl.away_rad > self.p.place_dock_away:
                pl.phase = "off"
                return True
        return False

    def _by_depth(self, obs: Observation) -> bool:
        """Whether place docking looks by the depth profiles only this frame (reading no spin
        view): the robot has depth and this is not the second axis of docking along an edge
        (``NavigationParams.place_dock``)."""
        return obs.depth is not None and not self.placing.second_axis

    def _turn(self, why: str) -> Proposal:
        command = Command(*rotate_command(self.p.motion), Action.do_nothing(), None, "place-dock")
        return Proposal(command, why)

    def _look(self, obs: Observation) -> Proposal | None:
        """Turn until a spin image is in view and lined up; ``None`` once it is (creep on). A
        robot with depth turns for the depth profiles' spot only (:meth:`_scan_dock`), up to
        ``place_dock_turns`` turns since place docking started, then gives up (``off``)."""
        pl, p, mp = self.placing, self.p, self.p.motion
        if self._by_depth(obs):
            if pl.turned >= 2 * np.pi * p.place_dock_turns:
                pl.phase = "off"  # the depth found no spot: the round trip takes over
                return None
            return self._turn("looking for the taught spot by the depth profiles")
        target, fit = look_fit(obs.views, self._spins(obs), p)
        seen = fit is not None and fit.inliers >= p.dock_min_inliers
        if fit is None or not seen or abs(fit.offset) > mp.toward_offset:
            if pl.rad >= 2 * np.pi * p.place_dock_turns:
                pl.phase = "off"  # nothing to dock on: the round trip takes over
                return None
            if fit is not None and seen:  # in sight: turn toward it, slowing down
                toward = rotate_command(mp, toward=fit.offset)
                return Proposal(
                    Command(*toward, Action.do_nothing(), None, "place-dock"), "turning toward it"
                )
            return self._turn("looking for one of the place's views")
        pl.start("creep")
        pl.target = target
        return None

    def _creep(self, obs: Observation) -> Proposal:
        """Creep along the spin image docked on until the scale agrees (three fits in a row)."""
        pl, p, mp = self.placing, self.p, self.p.motion
        target = int(pl.target if pl.target is not None else 0)
        fit = obs.views.zoomed_scale(target)
        if fit is None or fit.inliers < p.dock_min_inliers:
            pl.phase = "look"  # lost the view; the turning budget goes on
            return self._turn("lost the view; looking again")
        short, past = self._verdict(pl.log_scales, fit)
        settled = not (short or (past and p.dock_reverse))
        if settled and len(pl.log_scales) < 3 and pl.m < p.dock_max_m:
            # one fit may be off (parallax at close range): hold still until three agree
            hold = Command(0.0, 0.0, Action.do_nothing(), target, "place-dock")
            return Proposal(hold, "holding still until three views agree")
        if pl.m >= p.dock_max_m or settled:
            pl.axes += 1
            if pl.axes >= 2:
                pl.phase = "done"
                self.approach.docked_on_spot()
                return Proposal(Command(0.0, 0.0, Action.do_nothing()), "docked on two axes")
            pl.start("turn")
            return self._turn("one axis docked; a quarter turn to the next")
        _, w = navigate_command(fit.offset, taught_v=0.0, taught_w=0.0, params=mp)
        v = mp.dock_v if short else -mp.dock_v
        command = Command(v, w, Action.do_nothing(), target, "place-dock")
        return Proposal(
            command,
            "creeping on: the view looks smaller than taught"
            if short
            else "backing up: the view looks larger than taught",
        )

    # -- the approach --------------------------------------------------------------------------

    def track(self, command: Command, dt: float, path: PathEstimate | None = None) -> None:
        """Count the robot time spent following a taught edge into the goal (``approach_s``);
        any other move but standing still starts the count again (the approach must be the
        robot's last move: one that turned or explored since may have lost its place). With
        topometric repeat, only following with the path tracker locked on that edge counts
        (``path``: this frame's estimate): driving along an edge the robot is not sure to be
        on brought robots that were elsewhere to "arrive" by the belief alone. Once place
        docking has put the robot on the taught spot, following an edge into the goal
        without the lock does not start the count again."""
        a = self.approach
        edge, kind = command.action.edge, command.action.kind
        tracked = not self.p.topometric.enabled or (
            path is not None and path.locked and path.edge == edge
        )
        into_goal = (
            kind == ActionKind.NAVIGATE
            and edge is not None
            and self.rt.graph.edges[edge].target == self.goal
        )
        if into_goal and tracked:
            if edge != a.edge:
                a.edge, a.dock_m = edge, 0.0
            a.seconds += dt
            a.done = a.done or a.seconds >= self.p.approach_s
        elif into_goal and a.on_spot:
            # docked on the taught spot by the place's own views or depth, then following an
            # edge into the goal without the tracker's lock (a turn at the end of a path
            # taught by hand): still there. Starting again sent a robot 0.1 m from the goal
            # out on its round trip, over and over
            pass
        elif kind != ActionKind.DO_NOTHING:
            self._moved_on()

    def _moved_on(self) -> None:
        """The robot drove other than into the goal: the approach starts again; a goal with no
        round trip to come in by docks afresh at its next stay. Kept, a place docking given up
        elsewhere let the belief alone say "arrived" 160 frames later (a robot 4 m from the
        office, the belief at it for four frames)."""
        a = self.approach
        if self.needs_approach:
            a.seconds, a.done, a.edge, a.dock_m, a.spot_checks = 0.0, False, None, 0.0, 0
            a.on_spot, a.crept_m, a.crept_there = False, None, False
        elif self.waived and self.placing.phase in ("done", "off"):
            self.placing, a.on_spot = PlaceDocking(), False
            self.spot.reset()

    # -- docking along the edge ----------------------------------------------------------------

    def confirm(self, obs: Observation, placing: bool) -> tuple[Proposal | None, bool]:
        """The view's word on an arrival the belief has called after an approach.

        Args:
            placing: place docking had something to say this frame (then nothing is confirmed).
        Returns:
            ``(proposal, there)``: a docking move (``None``: keep the motion chosen) and
            whether the robot stands at the goal (or the view cannot tell).
        """
        a, p, mp = self.approach, self.p, self.p.motion
        if placing or not (a.done and obs.at_goal):
            a.log_scales.clear()
            return None, False
        if a.edge is not None and self._tracker_decides(obs, a.edge):
            a.log_scales.clear()
            return self._confirm_tracked(obs, a.edge)
        if not p.dock or a.edge is None or self.placing.second_axis:
            return None, True  # (the second axis ends in place docking's own verdict)
        if a.log_scales:  # the last frame's command was a docking move
            # counted as commanded, not as driven: a robot pressed against something gives up too
            a.dock_m += mp.dock_v * obs.dt
        target, fit = self._arrival_view(obs, a.edge)
        if fit is None or fit.inliers < p.dock_min_inliers:
            a.log_scales.clear()
            turn = self._second_axis()
            return turn, turn is None
        return self._dock_move(a.edge, target, fit)

    def _tracker_decides(self, obs: Observation, edge: int) -> bool:
        """Whether the path tracker has the word on the arrival by ``edge``: topometric
        repeat tracks that edge, locked, or lost but short of its last
        ``arrive_stretch_m`` (a tracker lost within it, its views at the goal too close to a
        wall to fit, leaves it to the views' scale, as without topometric repeat)."""
        est, tp = obs.path, self.p.topometric
        if not tp.enabled or est is None or est.edge != edge:
            return False
        return est.locked or est.remaining_m > tp.arrive_stretch_m

    def _confirm_tracked(self, obs: Observation, edge: int) -> tuple[Proposal | None, bool]:
        """:meth:`confirm` while the path tracker is locked on the edge the robot came in by:
        it knows where the robot is on the way in; it follows the path to its end and faces
        the way taught; the robot is there when the tracker says so, and only then (a
        tracker that lost the path sends it on along it first). Lost short of the end while the
        policy holds the goal (nothing else moves the robot), the robot turns on the spot: the
        belief and the tracker disagree, and fresh views settle it (the tracker locks on again,
        or the belief leaves the goal and the policy sends the robot on); standing, it waited
        for the unstick's 20 s in the closed-loop fault test."""
        est = obs.path
        if est is None or est.edge != edge:
            return None, False
        if self.approach.crept_m is not None:
            return self._creep_on(obs, est)
        if not est.locked:
            if obs.decision.action.kind != ActionKind.DO_NOTHING:
                return None, False
            look = Command(*rotate_command(self.p.motion), Action.do_nothing(), None, "dock")
            why = "the path tracker lost the way in short of the goal: looking round"
            return Proposal(look, why), False
        if self._tracked_there(obs, edge):
            return self._check_spot(obs, est)
        command, why = track_command(self.rt, obs, est)
        docking = Command(command.v, command.w, command.action, command.target_image, "dock")
        return Proposal(docking, f"on to the taught spot: {why}"), False

    def _check_spot(self, obs: Observation, est: PathEstimate) -> tuple[Proposal | None, bool]:
        """At the end of the path by the tracker: the place's own depth profiles (taught on
        the spot, :class:`SpotFix`) have the last word. Held still up to ``SPOT_CHECKS``
        frames for two of their estimates to agree; a spot further than ``SPOT_HANDOVER_M``
        hands over to place docking by depth (a tracker sure of a lateral offset 0.8 m wrong
        stood "at the end" of the path into an office); none, or one near: arrived."""
        a = self.approach
        spot = self.spot.update(self.rt, obs, self.goal)
        if spot is None and self.spot.spot is not None and a.spot_checks < SPOT_CHECKS:
            a.spot_checks += 1
            hold = Command(0.0, 0.0, Action.navigate(est.edge), est.image, "dock")
            return Proposal(hold, "at the end of the path: the place's depth profile?"), False
        if spot is None:
            return self._check_ahead(obs, est)
        if float(np.hypot(*spot)) <= SPOT_HANDOVER_M:
            return None, True
        self.placing.start("scan")
        v, w = toward_spot(spot, self.rt)
        command = Command(v, w, Action.do_nothing(), None, "place-dock")
        why = f"the place's depth puts its taught spot {float(np.hypot(*spot)):.2f} m away"
        return Proposal(command, why), False

    def _further(self, obs: Observation, est: PathEstimate) -> tuple[float | None, float]:
        """What the depth profile sees straight ahead beyond what the profile taught on
        arriving at the end of the tracked edge saw (:func:`seen_further`; ``None``: cannot
        tell), and the turn (rad) that faces the robot the way it was taught to arrive."""
        rt, tp = self.rt, self.p.topometric
        k = rt.arrival[est.edge]
        heading = float(rt.paths[est.edge].poses[k][2])
        turn = heading_error(est.pose, heading)
        taught = rt.taught_depth.get(rt.edge_image(est.edge, k))
        if not tp.end_depth or obs.depth is None or taught is None:
            return None, turn
        further = seen_further(
            obs.depth,
            taught,
            -turn,
            fov_deg=tp.depth_fov_deg,
            half_angle_rad=tp.end_depth_rad,
            max_range_m=tp.scan_fit.max_range_m,
        )
        return further, turn

    def _check_ahead(self, obs: Observation, est: PathEstimate) -> tuple[Proposal | None, bool]:
        """At the end of the path by the tracker, the place's depth profiles finding no spot:
        what the robot sees straight ahead against what was taught on arriving there
        (``TopometricParams.end_depth``; the rays compared look the same way, whichever way
        the robot faces: turning to face the taught way lost the lock of robots whose guide
        had turned at the end). Further, it stands short of the spot and creeps on
        (:meth:`_creep_on`); else, or when it cannot tell, arrived."""
        further, _ = self._further(obs, est)
        if further is None or further <= self.p.topometric.end_depth_m:
            return None, True
        self.approach.crept_m = 0.0
        return self._creep_on(obs, est)

    def _creep_on(self, obs: Observation, est: PathEstimate) -> tuple[Proposal | None, bool]:
        """Creep on the way taught on arriving while the robot sees further ahead than was
        taught at the spot; arrived once it does not (or cannot tell), or after the depth's
        reach (``scan_fit.max_range_m``) of creeping, and there until the approach starts
        again (the tracker, short by what it crept, would send it back to where it stopped)."""
        a, tp, mp = self.approach, self.p.topometric, self.p.motion
        if a.crept_there:
            return None, True
        further, turn = self._further(obs, est)
        crept = a.crept_m or 0.0
        if further is None or further <= tp.end_depth_m or crept >= tp.scan_fit.max_range_m:
            a.crept_there = True
            return None, True
        v = max(mp.dock_v, tp.pursuit.min_v)
        a.crept_m = crept + v * obs.dt  # as commanded, as docking counts its moves
        w = steer_to(turn, tp.pursuit)
        creep = Command(v, w, Action.navigate(est.edge), est.image, "dock")
        seen = (
            "nothing ahead where a surface was taught at the spot"
            if not np.isfinite(further)
            else f"{further:.2f} m further ahead than taught at the spot"
        )
        return Proposal(creep, f"short of the goal: sees {seen}"), False

    def _tracked_there(self, obs: Observation, edge: int) -> bool:
        """Whether the path tracker, locked on ``edge``, puts the robot at its end (within
        ``TopometricParams.arrive_m`` of it): the view's word, measured, with no scale to
        read. Whichever way it faces: a path whose guide turned on the spot at its end
        (180 degrees, to where the place's spin began) had the robot turn so far that the
        tracker, matching no view on the way round, let go, and the belief, seeing the next
        edge's views, sent the robot on along it."""
        est, tp = obs.path, self.p.topometric
        if est is None or not est.locked or est.edge != edge:
            return False
        end = goal_end(self.rt, est)
        return float(np.hypot(end[0], end[1])) <= tp.arrive_m

    def _dock_move(self, edge: int, target: int, fit: ScaleResult) -> tuple[Proposal | None, bool]:
        """Creep on, back up, or settle (then the second axis) by the scale of ``fit``."""
        a, p, mp = self.approach, self.p, self.p.motion
        short, past = self._verdict(a.log_scales, fit)
        if a.dock_m >= p.dock_max_m or not (short or (past and p.dock_reverse)):
            a.log_scales.clear()
            turn = self._second_axis()
            if turn is not None:
                return turn, False
            return Proposal(Command(0.0, 0.0, Action.navigate(edge), target), "docked"), True
        _, w = navigate_command(fit.offset, taught_v=0.0, taught_w=0.0, params=mp)
        if short:
            creep = Command(mp.dock_v, w, Action.navigate(edge), target, "dock")
            return Proposal(creep, "stopped short: the view looks smaller than taught"), False
        # backing up the way it came: the tracker has no backward motion, so it holds still
        back = Command(-mp.dock_v, w, Action.do_nothing(), target, "dock")
        return Proposal(back, "went past: the view looks larger than taught"), False

    def _arrival_view(self, obs: Observation, edge: int) -> tuple[int, ScaleResult | None]:
        """The taught view the frame fits best at the end of ``edge`` (its last images) or,
        when none of them fits (the robot faces elsewhere), among the goal's spin images."""
        ends = self._edge_ends(edge)
        target, fit = self._best(obs.views, ends)
        if fit is not None and fit.inliers >= self.p.dock_min_inliers:
            return target, fit
        return self._best(obs.views, self._spins(obs))

    def _second_axis(self) -> Proposal | None:
        """Start docking on the goal's spin images a quarter turn on from where docking along
        the edge settled (``dock_second_axis``): the turn, or ``None`` when there is no second
        axis to dock (off, already done, or no spin images)."""
        p, pl = self.p, self.placing
        if not (p.dock_second_axis and p.place_dock) or pl.second_axis:
            return None
        if len(self.rt.spin_images[self.goal]) == 0:
            return None
        pl.second_axis = True
        pl.start("turn")
        pl.axes, pl.away_rad = 1, 0.0
        command = Command(*rotate_command(p.motion), Action.do_nothing(), None, "dock")
        return Proposal(command, "docked along the edge; a quarter turn for the second axis")

    def events(self) -> frozenset[str]:
        return frozenset({"docking on purpose"}) if self._engaged else frozenset()
