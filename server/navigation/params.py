"""Everything that tunes navigation, in one frozen dataclass with documented defaults.

Deployment overrides come by name (``TEACHREPEAT_NAVIGATION``, :func:`server.tuning.tuned`),
dotted for the nested parameter objects (``motion.unstick_s``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from server.belief.model import TransitionParams
from server.belief.questions import QuestionParams
from server.belief.tracker import TrackerParams
from server.motion import MotionParams
from server.navigation.pathtrack import TopometricParams
from server.policy.costs import CostParams
from server.policy.voting import PolicyParams
from server.vision.distinctiveness import DistinctivenessParams
from server.vision.features import FeatureParams
from server.vision.index import CHANGED_WEIGHTS, EngineParams

ROBUST_WEIGHTS: tuple[float, ...] = (0.1, 0.0, 0.1, 0.1, 0.7)
"""First-pass weights of the blocks (histogram, thumbnail, descriptor mean, descriptor variance,
patch-normalised thumbnail) that hold up under lighting changes: mostly the locally normalised
thumbnail."""


@dataclass(frozen=True)
class AmbiguityParams:
    """Ambiguity-aware navigation (seed 000, docs/ambiguity.md). Least-ambiguous routes and
    active disambiguation were measured three times with no gain and removed (2026-12-02,
    docs/ambiguity.md section 2).

    * ``alike_departures`` (True): a robot driving onto the edge it found carries on when
      the policy switches to another edge whose images along the same stretch look like the
      frame as well (:class:`server.navigation.behaviours.FindEdge`): leaving one of several
      look-alike rooms, the split belief flipped the vote between their doors every few
      frames, and the robot turned back to searching each time instead of leaving. On since
      2026-11-29: on the office floor the first right "localised" came sooner (mean 32.4 ->
      19.3 s on the trials it was chosen on, 19.0 -> 10.7 s held out) and more trials arrived,
      no home arrived less (docs/ambiguity.md 5.2). False: the behaviour before.
    * ``distinctiveness``: how every taught image's entropy is computed
      (:mod:`server.vision.distinctiveness`); always computed when a tour changes.
    """

    alike_departures: bool = True
    distinctiveness: DistinctivenessParams = field(default_factory=DistinctivenessParams)


def two_appearance_models() -> EngineParams:
    """The engine navigation uses: the defaults with the change-robust second model."""
    return EngineParams(changed_weights=CHANGED_WEIGHTS)


@dataclass(frozen=True)
class NavigationParams:
    """Everything that tunes navigation, with documented defaults.

    * ``arrive_mass`` (0.6) and ``arrive_steps`` (3): the task is "arrived" once, on this many
      consecutive frames, at least this belief is *at the goal* (the goal location plus the
      last images of the edges ending there, which were taken at the place) and the recent
      images agree with the prediction (the tracker's evidence ratio is at least
      ``TrackerParams.localised_evidence``), and never before ``arrive_min_steps`` frames of
      the task: a robot carried away right after a task does not "arrive" on a stale belief.
    * ``approach_s`` (1.0 s of robot time): the task arrives only after the robot has followed
      a taught edge into the goal for this long (Navigate on an edge whose target is the
      goal) as its last move: turning or exploring since starts the count again, since a robot
      that had to look round may have lost its place (with topometric repeat only following
      with the path tracker locked on that edge counts; once place docking has put the
      robot on the taught spot, following an edge into the goal without the lock does not
      start it again). Until then the goal votes to leave by
      its cheapest round trip (:func:`server.policy.voting.build_vote_plan`, ``hold_goal``):
      a robot that finds itself in the goal room but off the taught spot backs out, turns
      round and homes in along the end of the taught path, which is how it reaches the spot
      (0.05-0.1 m in the simulated home) rather than stopping wherever it stood (0.7-0.9 m
      off). Waived for a goal with no taught edge into it or out of it. 0 disables it.
    * ``dock`` (True), ``dock_scale_tol`` (0.06), ``dock_min_inliers`` (10), ``dock_max_m``
      (1.5 m), ``dock_reverse`` (True): when the belief says "arrived", the view must agree. The
      frame is matched against the images taught at the end of the edge the robot came in on
      (from the last one taken while driving forward; the best-matching one counts,
      :func:`server.vision.homing.homing_scale`): the scene looks larger in that image when
      the robot stopped short of the place and smaller when it went past it. While the median
      of the last three scales is more than ``dock_scale_tol`` away from 1, the robot creeps
      forward (or backs up, with ``dock_reverse``) at ``MotionParams.dock_v``, steered by the
      same matches, for at most ``dock_max_m`` per approach (as commanded: a robot that cannot
      move gives up as soon); then it arrives. A frame with fewer
      than ``dock_min_inliers`` matches agreeing on a scale cannot tell (a bare wall) and
      leaves the belief's word standing. In the simulated home the belief alone stopped 0.4-1.0
      m short of the place, or 1.4-3.4 m past it, in 7 of 50 runs with moved furniture.
      When none of those images fits (the robot faces elsewhere), the goal's spin images are
      tried (the three the engine ranks highest), and only when they do not fit either does
      the belief's word stand.
    * ``dock_second_axis`` (True): once docking along the edge has settled, the robot turns a
      quarter turn and docks on the goal's spin images there, as place docking does on its
      second axis, then arrives. Docking along the view cannot see a sideways offset: in the
      simulated home a robot that came in along the living room's taught path 0.6 m to the
      side of it stopped there.
    * ``place_dock`` (True), ``place_dock_ambiguity`` (0.5), ``place_dock_turns`` (1.25):
      a robot whose belief is at the goal before it came in along a taught edge first tries to
      dock on the place's own spin images, on two axes: it turns until the frame matches a spin
      image (``dock_min_inliers`` agreeing on a scale), creeps along that view until the scale
      agrees (as in docking), turns a quarter turn and does the same on the view there, then
      arrives. Only at a place whose spin images do not look like elsewhere in the tour (their
      mean similarity to images more than a metre from the place, ``TourRuntime.place_ambiguity``,
      at most ``place_dock_ambiguity``: look-alike rooms are still approached along an edge,
      which tells them apart). A robot that finds no spin image in ``place_dock_turns`` turns
      falls back to the round trip below. In the simulated home the round trip failed in
      small rooms: leaving the bathroom from 0.5-1 m off the place, the robot turned back at
      the door, the belief returned to the place, and it set off again for the rest of the
      trial. With place docking 135 of 150 benchmark runs succeed instead of 128 (moved
      furniture 43/50 instead of 37/50); it costs 3 runs in the unchanged home that the round
      trip had brought onto the spot and docking left 0.6-0.9 m off (a scale seen along one
      view at close range, with parallax, can mislead).
      A robot with a depth sensor docks on a place by the depth profiles only
      (:func:`~server.navigation.docking.spot_by_scan`), turning up to ``place_dock_turns``
      turns in all for them, then takes the round trip, which comes in along an edge with the
      path tracker: the floor's texture repeats every metre or two, and the views' scale
      settled 1.4-2 m from the spot (docs/navigation.md section 4).
    * ``place_dock_away`` (pi rad): place docking gives up (the round trip takes over) once the
      robot has turned this far while docking with the belief off the goal. At the place its
      spin images show all round; a turn that mostly sees elsewhere says a look-alike view
      started the docking. In a simulated home, under changed light, one view of a place passed
      for the goal: docking started there, went on although for most of each turn the belief
      named the place the robot was really in, and said "arrived" 5.3 m from the goal.
    * ``dock_zooms`` ((1.3, 1.69)): both dockings read the scale through the frame zoomed in
      and out by each of these factors as well as as it is
      (:func:`server.vision.homing.homing_scale_zoomed`; four more feature extractions on a
      docking step, none otherwise). The corner descriptors are not scale invariant: off the
      spot by 0.4-0.8 m, the near scene looks 1.3-2 times larger or smaller than taught and
      matched few corners, so the fit rested on far scene at a scale of ~1 and docking stopped
      short. () reads the frame as it is only. Benchmark of 2026-11-24 (with the tour-build
      race fixed the same day): 47/50 unchanged, 47/50 lighting, 42/50 moved furniture, against
      44, 48 and 43 on 2026-11-23; the three unchanged-home runs place docking had left 0.6-0.9
      m off now arrive (0.06-0.48 m, replayed alone).
    * ``dock_taught_zooms`` ("look"): where place docking and settling turn to look for one
      of the place's views (:func:`server.navigation.docking.look_fit`), ``"look"`` reads
      those zooms on the taught images instead of the frame, made once per taught image
      (:meth:`TourRuntime.taught_levels`,
      :func:`server.vision.homing.homing_scale_taught_zoomed`; no extraction of the frame's
      zooms on those frames); creeping and every verdict on the scale read the frame's zooms,
      as ``"off"`` does everywhere. Measured 2026-11-29 (docs/reliability.md): ``bench load``
      server CPU per frame 6.0 / 6.7 ms with ``"look"`` against 7.4 / 7.7 with ``"off"``
      (docking's share 0.4-0.5 ms against 1.6-1.8: looking was most of it); closed loop, the
      same 144 trials paired (apartment + studio 20 and the office floor 8 per condition,
      same / lighting / moved, seed 100): ``"look"`` 102 arrived, ``"off"`` 97, 8 and 7 wrong
      places, 8 and 6 ended 0.5 m or more from the spot, and the robots at the right place
      stopped as closely (p50 / p90 0.085 / 0.30 m against 0.085 / 0.31 m). The verdicts on
      the taught images' zooms too (``"both"``) saved as much CPU but docked less closely
      (2026-11-28: 100 arrived, 7 wrong, 10 ended 0.5 m or more off, p90 0.46 m; the sofa
      trial of the two-room test home ends 0.95 m off against 0.21 m; single views 0.8 m
      behind the spot read "short" less often, 39 % right against 55 %); the zooms out alone
      on the taught images, everywhere (``"out"``), arrived less often (14 of 20 trials
      against 16, 2026-11-26). Both were removed (2026-12-05; the code is in the git
      history).
    * ``bump_s`` (1.0 s of robot time) and ``bump_fraction`` (0.25): a robot told to drive
      forward that reports less than this fraction of the commanded speed for this long is
      pressed against something its depth profile does not show (a chair's corner beside its
      field of view); it backs off (``MotionParams.backoff_v`` for ``backoff_s``) turning
      toward the more open side, then carries on. 0 disables it.
    * ``fresh_belief`` (True): a new task starts from the uniform prior (001's b0): the robot
      may have been carried since its last task, and a stale belief at the goal made it
      "arrive" in one second, metres away, in the simulated home.
    * ``stall_s`` (20 s of robot time) and ``stall_m`` (0.3 m): a navigating robot that has
      driven less than ``stall_m`` (by its reported speed) in ``stall_s`` is stuck, whatever
      the reason (pressed against a wall beside a door it is homing at, a search that keeps
      almost finding its edge): it explores toward open space for ``MotionParams.unstick_s``
      and then carries on from there. Longer than a full search turn (``find_turns`` at
      ``spin_w``: 16 s), so a robot that is only looking round is left alone. 0 disables it.
    * ``escape_s`` (3 s of robot time) and ``escape_m`` (0.05 m): the behaviour that won the
      arbiter wanted to drive forward on every frame of ``escape_s`` (before obstacle avoidance,
      which may hold the speed at zero: the robot sat 0.24 m from a door frame so, turning back
      and forth) and the robot reported less than ``escape_m`` driven: it escapes (backs off,
      turns to the most open side, drives that way: :class:`server.navigation.behaviours.Escape`)
      and tries again. Back-offs of the bump reflex count as escapes too.
    * ``escape_tries`` (4) and ``escape_free_m`` (1.0 m): a robot that needs more than this
      many escapes, none followed by ``escape_free_m`` of driving, fails its task (stuck).
      ``escape_s`` 0 disables escaping.
    * ``search_departures`` (3): RotateAndFindEdge that has driven onto the same edge this many
      times in one task, losing it each time, is in a loop (the departure view matches from
      where the robot stands but the edge does not follow, e.g. 1 m off the taught spot): it
      explores instead, like after a fruitless search turn.
    * ``departure_min_s`` (1 s of robot time): driving along an edge for less than this before
      the policy turns back to searching is a flicker of the vote, not a departure that lost its
      edge (for ``search_departures`` and settling).
    * ``search_rounds`` (4): fruitless search rounds (a full search turn without finding the
      edge, or a loop) in one task; each explores longer (``MotionParams.unstick_s`` times the
      round, at most three times), and one more fails the task (lost) rather than wandering.
    * ``settle_tries`` (2): after a departure from a place lost its edge, the robot docks on
      that place's spin images before searching again (:class:`server.navigation.settle.Settle`),
      at most this many times per place and task; 0 disables it.
    * ``max_task_s`` (300 s of robot time): a task still underway after this fails (timeout).
    * ``lost_steps`` (200 frames): this many consecutive Explore decisions fail the task (lost).
    * ``frame_timeout_s`` (5 s, wall clock): a navigating robot silent for this long has its
      task failed and must re-localise.
    * ``max_dt_s`` (1.0 s): a longer gap between frames is treated as this for prediction.
    * ``history`` (200): steps kept per robot for the dashboard and debugging.
    * ``engine`` (two appearance models, :func:`two_appearance_models`): every frame is
      scored with the tour's learned weights and with the change-robust weights
      (:data:`CHANGED_WEIGHTS`), weighed by the tracker behind the change gate
      (:mod:`server.belief.appearance`): the tour's model alone while the frames look like
      the tour in its own light, both once a stretch of frames does not (a changed season or
      lamps). ``engine.changed_weights=null`` keeps the tour's model alone, as before
      2026-11-28 (docs/localize.md: Nordland across seasons 0.168 / 0.668 with one model).
    * ``signature_weights`` (None): the engine's first-pass block weights used for navigation;
      ``None`` = the weights learned for the tour. Learned from a single teaching traversal they
      cannot see a change of light (~0.75 on the colour histogram): the simulated lighting
      condition failed 0/10. ``ROBUST_WEIGHTS`` hold up under light changes (6/10, and the top
      state under changed light agreed with the unchanged one for 0.78 of 120 random poses vs
      0.33) but make places less distinct in unchanged light (7/20 with 7 wrong arrivals vs
      15/20 with 1-2), so they are an option, not the default.
    * ``ambiguity``: distinctiveness and carrying on along a look-alike departure
      (:class:`AmbiguityParams`).
    * ``topometric``: following taught edges by the robot's pose relative to the taught path
      (:class:`server.navigation.pathtrack.TopometricParams`).
    """

    arrive_mass: float = 0.6
    arrive_steps: int = 3
    arrive_min_steps: int = 5
    approach_s: float = 1.0
    dock: bool = True
    dock_scale_tol: float = 0.06
    dock_min_inliers: int = 10
    dock_max_m: float = 1.5
    dock_reverse: bool = True
    place_dock: bool = True
    place_dock_ambiguity: float = 0.5
    place_dock_turns: float = 1.25
    place_dock_away: float = float(np.pi)
    dock_zooms: tuple[float, ...] = (1.3, 1.69)
    dock_taught_zooms: Literal["off", "look"] = "look"
    dock_second_axis: bool = True
    fresh_belief: bool = True
    stall_s: float = 20.0
    stall_m: float = 0.3
    escape_s: float = 3.0
    escape_m: float = 0.05
    escape_tries: int = 4
    escape_free_m: float = 1.0
    search_departures: int = 3
    search_rounds: int = 4
    departure_min_s: float = 1.0
    settle_tries: int = 2
    max_task_s: float = 300.0
    lost_steps: int = 200
    frame_timeout_s: float = 5.0
    max_dt_s: float = 1.0
    bump_s: float = 1.0
    bump_fraction: float = 0.25
    history: int = 200
    signature_weights: tuple[float, ...] | None = None
    features: FeatureParams = field(default_factory=FeatureParams)
    engine: EngineParams = field(default_factory=two_appearance_models)
    transitions: TransitionParams = field(default_factory=TransitionParams)
    tracker: TrackerParams = field(default_factory=TrackerParams)
    policy: PolicyParams = field(default_factory=PolicyParams)
    costs: CostParams = field(default_factory=CostParams)
    motion: MotionParams = field(default_factory=MotionParams)
    ambiguity: AmbiguityParams = field(default_factory=AmbiguityParams)
    topometric: TopometricParams = field(default_factory=TopometricParams)
    questions: QuestionParams = field(default_factory=QuestionParams)

    def __post_init__(self) -> None:
        if not all(np.isfinite(z) and z > 1 for z in self.dock_zooms):
            raise ValueError(f"dock_zooms must be finite factors > 1, got {self.dock_zooms}")
        if self.dock_taught_zooms not in ("off", "look"):
            raise ValueError(
                f"dock_taught_zooms must be 'off' or 'look', got {self.dock_taught_zooms!r}"
            )
