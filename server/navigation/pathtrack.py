"""The robot's pose relative to the taught path it follows, kept frame by frame.

:class:`PathTracker` holds one task's path tracking filter (:mod:`server.navigation.tracking`):
which edge it tracks, the pose in that edge's frame and its covariance. Every frame it is carried
by the odometry, then corrected by the camera against the taught images near the estimate
(:func:`server.vision.relpose.relative_pose`: the heading, and the direction of the robot from
each taught camera). It follows the edge the policy chooses: it starts on it where the belief
puts the robot, and when the policy moves on to the next edge of the route at the place where
the tracked edge ends, it carries its estimate across into the next edge's frame (the turn
between the two edges read from their images taken at the place), so the robot drives through
intermediate places without searching.

It also keeps the robot's own trace since it last knew where it was on the path, which
retracing drives back along (:class:`server.navigation.behaviours.Retrace`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from server.belief.model import ActionKind
from server.navigation.geometry import EdgePath, compose, relative, wrap
from server.navigation.localplan import LocalPlanParams
from server.navigation.pursuit import PursuitParams
from server.navigation.scanmatch import (
    ScanFit,
    ScanParams,
    match_profiles,
    match_profiles_robust,
)
from server.navigation.tracking import (
    OdometryNoise,
    initial_cov,
    path_frame_cov,
    predict,
    update_along,
    update_bearing,
    update_heading,
    update_pose,
)
from server.policy.voting import Decision
from server.vision.features import ImageFeatures
from server.vision.homing import HomingParams, match_features
from server.vision.relpose import CameraModel, RelativePose, RelPoseParams, relative_pose

FloatArray = npt.NDArray[np.float64]
LinkFn = Callable[[int, int], "float | None"]
"""``link(e_in, e_out)``: the heading of ``e_in``'s last image in ``e_out``'s frame (rad), or
``None`` when their images cannot tell."""
DepthFn = Callable[[int], "npt.NDArray[np.float32] | None"]
"""``depth(image)``: the depth profile taught with a canonical image, or ``None``."""


@dataclass(frozen=True)
class TopometricParams:
    """Topometric repeat: tracking the taught path and following it (docs/navigation.md).

    * ``enabled`` (True): follow taught edges with the path tracker (pure pursuit on the pose
      relative to the path); False: homing on the next image with the taught motion replayed,
      as before.
    * ``camera_hfov_deg`` (75.18), ``camera_pitch_deg`` (5.0): the robot's camera
      (:class:`server.vision.relpose.CameraModel`; the simulated robot's values).
    * ``ahead_m`` ((0.0, 0.5, 1.0)): the taught images matched every frame, metres along the
      path from the estimate (the nearest one, and ahead: the robot sees what they saw).
    * ``heading_sigma`` (0.03 rad), ``bearing_sigma`` (0.15 rad): the least uncertainty of a
      heading and of a direction measured from one taught image (added to the fit's own).
      One direction is used per frame, from the fit that moved most (``bearing_parallax_px``
      at least, ``bearing_inliers`` matches agreeing): two views of nearly the same place
      tell the heading well and the direction poorly.
    * ``along_sigma`` (0.4 m): how far along the path the belief's most likely image is
      trusted (the along-path position the camera's directions tell least).
    * ``scan`` (True), ``scan_sigma_m`` (0.04), ``scan_sigma_rad`` (0.02): with a depth
      profile now and one taught with the image nearest the estimate, their alignment
      (:mod:`server.navigation.scanmatch`) measures the whole pose; its covariance is at least
      these (the fit's own is optimistic), and it is gated at ``scan_gate`` (three degrees of
      freedom, 11.34: 99 %); along the path it is trusted to ``scan_along_sigma_m`` (0.3 m)
      only (a corridor's profile aligns as well one door further on: a tracker that trusted
      it stood "at the end" of a corridor 2.8 m short of it, the belief's word outvoted).
      While not locked the fit starts from several guesses, shifted
      sideways by ``join_lateral_m`` (joining the path from up to 1.5 m beside it).
    * ``rival_m`` (0.3 m), ``rival_frames`` (8): while locked, the profile is also aligned from
      those guesses; when on this many fits in a row (frames without one do not count) the
      best of them fits better than the fit from the estimate and puts the robot more than
      ``rival_m`` beside it, each within ``rival_m`` of the one before, the estimate has
      settled in the wrong one of two alignments (a wall one desk further over fits as well,
      for a while) and the gate keeps the right one out: it starts afresh at that alignment,
      not locked until measured again (a robot tracked 1.15 m beside the path, sd 0.02 m,
      stood 0.3 m from it and turned to and fro for 50 s against the wall beyond which the
      estimate put the path). A rival rests on at least ``rival_pairs`` (12) points
      agreeing: one of 7-8 pairs, 15 % better in score than the estimate's own, moved a
      robot tracked on the path 1.46 m off it.
    * ``refute_fits`` (8): while locked, when this many scan fits in a row (frames without one
      do not count) lie beyond the gate, the estimate is surer than its measurements allow:
      its position uncertainty is widened back to ``init_along_m`` and ``init_lateral_m`` (the
      heading's is kept) and it is not locked until measured again, so the fits can move it.
      The rival above needs a better alignment from the sideways starts; here the alignment
      from the estimate itself lands away from it, fit after fit, and the gate refuses it (a
      robot tracked 0.3 m right of the path, sd 0.05 m, stood 1.1 m from it; the fits put it
      left of the estimate on 32 of 38 frames, the gate refused 34 of them, and it drove into
      the furniture beside the path until it was stuck).
    * ``depth_fov_deg`` (90): the field of view the depth profile's rays span (as
      ``MotionParams.depth_fov_deg``).
    * ``gate`` (9.0): a measurement whose squared Mahalanobis distance exceeds this is not
      used (3 standard deviations).
    * ``init_along_m`` (0.5), ``init_lateral_m`` (0.6), ``init_heading_rad`` (1.0): how
      uncertain a new estimate is, placed where the belief says.
    * ``lock_lateral_m`` (0.3), ``lock_heading_rad`` (0.2), ``lock_fix_s`` (1.5),
      ``lock_frames`` (5): the estimate is *locked* (the path follower trusts it) while its
      lateral and heading standard deviations are within these, a heading was measured in the
      last ``lock_fix_s`` seconds of robot time, and headings were measured on at least
      ``lock_frames`` frames since it started on this edge (one frame's fits can all be wrong).
    * ``chain_m`` (0.4): within this of the tracked edge's end, the next edge of the route
      takes over (through the place, without stopping).
    * ``switch_frames`` (5): a locked tracker leaves its edge for another the policy asks for
      only after this many frames of asking (look-alike edges flip the vote).
    * ``commit_mass`` (0.25): while the tracker is locked on an edge and the belief holds at
      least this much on it (its images, its start and the place it ends at), the policy's
      vote is taken at the tracked position (the vote of that image, :func:`committed`):
      two edges that leave a place alike split the belief and flipped the vote between them
      from frame to frame, turning a robot that knew where it was back to searching.
    * ``arrive_m`` (0.12 m): a tracker locked on the edge into the goal that puts the robot
      within this of the edge's end docks it there, whichever way it faces: arrival needs
      no scale docking then (beside the end, the path follower drives onto it).
    * ``arrive_stretch_m`` (0.5 m): while it does, the belief's mass on that edge's images
      within this of its end counts as at the goal (the belief favoured an image just before
      the edge's exit zone at a robot standing on the taught spot, and never arrived).
    * ``path_evidence`` (4.0): while the tracker is locked, the belief's update weighs the
      images of the tracked edge near the tracked position (a Gaussian over metres along,
      of the tracker's along-path standard deviation and at least 0.3 m) this many times
      more than every other state (:func:`path_likelihood`): the depth profile and the views
      matched along the edge are evidence the engine's similarities alone do not carry (a
      place's spin images, looking down a corridor, matched every frame driven along it, and
      the belief stayed at the place for 3.5 m of driving). 1 turns it off.
    * ``end_depth`` (True), ``end_depth_m`` (0.2 m), ``end_depth_rad`` (0.15 rad): at the end
      of the edge into the goal by the tracker, where the place's depth profiles find no spot
      (a corridor's), the robot compares what its depth profile sees straight ahead (the rays
      within ``end_depth_rad``) with what the profile taught on arriving there saw, ray by ray
      looking the same way (:func:`server.navigation.docking.seen_further`): seeing more
      than ``end_depth_m`` further (or nothing where a surface was taught), it stands short of
      the spot, whatever the tracker says, and creeps on until it sees what was taught, for
      at most the depth's reach (``scan_fit.max_range_m``). A tracker's along-path position
      can be metres off in a plain corridor with a standard deviation of centimetres (its
      measurements there repeat each other): robots "arrived" 2.5-3.4 m short of the end.
    * ``link_sigma`` (0.15 rad): how uncertain the turn between two edges at a place is,
      as read from their images.
    * ``restart_m`` (2.0 m), ``restart_s`` (10 s): a tracker that is not locked and puts the
      robot further than ``restart_m`` beside the path, or has measured no heading for
      ``restart_s``, starts afresh where the belief puts the robot.
    * ``retrace_after_s`` (2.0 s), ``retrace_max_m`` (2.5 m): a tracker that has been lost
      this long drives back along its own trace to where it was last locked, if that is no
      further than this.
    * ``noise``, ``relpose``, ``pursuit``, ``local_plan``: the odometry's uncertainty, the
      two-view fit, the path follower's settings and its plan around obstacles
      (:mod:`server.navigation.localplan`).
    """

    enabled: bool = True
    camera_hfov_deg: float = 75.18
    camera_pitch_deg: float = 5.0
    ahead_m: tuple[float, ...] = (0.0, 0.5, 1.0)
    heading_sigma: float = 0.03
    bearing_sigma: float = 0.15
    bearing_parallax_px: float = 4.0
    bearing_inliers: int = 12
    along_sigma: float = 0.4
    scan: bool = True
    scan_sigma_m: float = 0.04
    scan_sigma_rad: float = 0.02
    scan_gate: float = 11.34
    scan_along_sigma_m: float = 0.3
    join_lateral_m: tuple[float, ...] = (0.0, 0.5, -0.5, 1.0, -1.0, 1.5, -1.5)
    depth_fov_deg: float = 90.0
    rival_m: float = 0.3
    rival_frames: int = 8
    rival_pairs: int = 12
    refute_fits: int = 8
    gate: float = 9.0
    init_along_m: float = 0.5
    init_lateral_m: float = 0.6
    init_heading_rad: float = 1.0
    lock_lateral_m: float = 0.3
    lock_heading_rad: float = 0.2
    lock_fix_s: float = 1.5
    lock_frames: int = 5
    chain_m: float = 0.4
    switch_frames: int = 5
    commit_mass: float = 0.25
    path_evidence: float = 4.0
    arrive_m: float = 0.12
    arrive_stretch_m: float = 0.5
    end_depth: bool = True
    end_depth_m: float = 0.2
    end_depth_rad: float = 0.15
    link_sigma: float = 0.15
    restart_m: float = 2.0
    restart_s: float = 10.0
    retrace_after_s: float = 2.0
    retrace_max_m: float = 2.5
    noise: OdometryNoise = field(default_factory=OdometryNoise)
    relpose: RelPoseParams = field(default_factory=RelPoseParams)
    scan_fit: ScanParams = field(default_factory=ScanParams)
    pursuit: PursuitParams = field(default_factory=PursuitParams)
    local_plan: LocalPlanParams = field(default_factory=LocalPlanParams)

    @property
    def camera(self) -> CameraModel:
        return CameraModel(hfov_deg=self.camera_hfov_deg, pitch_deg=self.camera_pitch_deg)


@dataclass(frozen=True)
class PathEstimate:
    """Where the robot is relative to the taught path, as the tracker estimates it this frame.

    Attributes:
        edge: the tracked edge (index into the graph's edges).
        pose: ``(3,)`` the robot's pose in the edge's frame (x, y m; heading rad).
        cov: ``(3, 3)`` its covariance.
        along_m: metres along the path of the robot's nearest point on it.
        lateral_m: metres left of the path (negative: right).
        heading_error: rad, the robot's heading minus the path's there.
        sigma_lateral, sigma_along (m), sigma_heading (rad): standard deviations.
        locked: the estimate is good enough to steer by (:class:`TopometricParams`).
        fixes: taught images whose heading was used this frame.
        image: canonical index of the taught image nearest the estimate; index: its index
            along the edge.
        length_m: the edge's length.
        since_fix_s: robot seconds since a heading was last measured.
        chained: the estimate came onto this edge from the end of the one before it, through
            their place (:meth:`PathTracker.step`), not afresh where the belief put it.
    """

    edge: int
    pose: FloatArray
    cov: FloatArray
    along_m: float
    lateral_m: float
    heading_error: float
    sigma_lateral: float
    sigma_along: float
    sigma_heading: float
    locked: bool
    fixes: int
    image: int
    index: int
    length_m: float
    since_fix_s: float
    chained: bool = False

    @property
    def remaining_m(self) -> float:
        """Metres of the edge ahead of the robot's nearest point."""
        return max(self.length_m - self.along_m, 0.0)


@dataclass(frozen=True)
class TracePoint:
    """A pose the robot passed, in the frame of the edge tracked then, and whether the
    tracker was locked there."""

    edge: int
    pose: FloatArray
    locked: bool


class PathTracker:
    """One task's path tracking filter (fresh for every task)."""

    def __init__(
        self,
        paths: tuple[EdgePath, ...],
        features: tuple[ImageFeatures, ...],
        edge_first: npt.NDArray[np.int64],
        params: TopometricParams,
        *,
        link: LinkFn | None = None,
        edge_ends: tuple[tuple[int, int], ...] = (),
        depth: DepthFn | None = None,
    ) -> None:
        """``paths``: every edge's taught path; ``features``: every taught image's features
        (canonical order); ``edge_first``: the canonical index of each edge's first image;
        ``link``: how two edges meet at a place (:data:`LinkFn`); ``edge_ends``: each edge's
        (source, target) locations; ``depth``: the taught depth profiles (:data:`DepthFn`)."""
        self.paths = paths
        self.features = features
        self.edge_first = edge_first
        self.p = params
        self.camera = params.camera
        self.link = link
        self.edge_ends = edge_ends
        self.taught_depth = depth
        self.edge: int | None = None
        self.mean = np.zeros(3)
        self.cov = np.eye(3)
        self.along = 0.0
        self.last_fix: float | None = None  # robot time of the last heading measurement
        self.fixed_frames = 0  # frames with a heading measured since it started on this edge
        self.asked_other = 0  # frames the policy has asked for another edge while locked
        self.rival = 0  # scan fits in a row that put the robot elsewhere beside the path
        self.rival_lateral = 0.0  # where the last of them put it (m left of the path)
        self.refuted = 0  # scan fits in a row, while locked, that the gate refused
        self.trace: list[TracePoint] = []  # since the last locked frame (that one first)
        self.chained = False  # the estimate came onto this edge through a place
        self.estimate: PathEstimate | None = None

    def image(self, edge: int, k: int) -> int:
        """Canonical index of image ``k`` of ``edge``."""
        n = self.paths[edge].n_images
        return int(self.edge_first[edge]) + int(np.clip(k, 0, n - 1))

    # -- the frame ---------------------------------------------------------------------------

    def step(
        self,
        features: ImageFeatures,
        *,
        t: float,
        v: float,
        w: float,
        dt: float,
        decision: Decision,
        along_belief: int | None,
        depth: npt.ArrayLike | None = None,
        facing: bool = True,
    ) -> PathEstimate | None:
        """One frame: carry the estimate by the odometry, follow the policy's edge, correct
        by the camera and the depth profile. ``along_belief``: the image of the policy's edge
        the belief puts the robot at (where a new estimate starts); ``depth``: the frame's
        depth profile (m, left to right) or ``None``; ``facing`` False: the robot, searching
        for the edge at its start place, faces away from where it sets off (a corridor looks
        alike both ways: views and depth would lock it on the path backwards), so nothing
        corrects the estimate and it is not locked until it faces that way. ``None`` while
        there is no edge to track."""
        if self.edge is not None:
            self.mean, self.cov = predict(self.mean, self.cov, v, w, dt, self.p.noise)
        wanted = self.wanted(decision)
        if wanted is not None and wanted != self.edge:
            self._follow(wanted, decision, along_belief)
        elif wanted is not None and self._astray():
            self._start(wanted, decision, along_belief)  # afresh, where the belief says
        if self.edge is None:
            self.estimate = None
            return None
        if not facing:
            self.fixed_frames, self.last_fix = 0, None
            self.estimate = est = self._estimate(t, 0)
            self._remember(est)
            return est
        if along_belief is not None and wanted == self.edge:
            self._along(along_belief)
        fixes = self._correct(features, t)
        if depth is not None and self.p.scan:
            fixes += self._scan(np.asarray(depth, dtype=np.float64))
        if fixes:
            self.last_fix = t
            self.fixed_frames += 1
        self.estimate = est = self._estimate(t, fixes)
        self._remember(est)
        return est

    def _astray(self) -> bool:
        """Whether the estimate has drifted beyond use while not locked: further beside the
        path than ``restart_m`` (a robot that far off has left it; the tracker would never
        find it again by starting there), or without a heading measured for ``restart_s``."""
        est = self.estimate
        if est is None or est.locked:
            return False
        return abs(est.lateral_m) > self.p.restart_m or est.since_fix_s > self.p.restart_s

    def wanted(self, decision: Decision) -> int | None:
        """The edge the policy's decision asks to be on: the active edge of Navigate, the
        edge RotateAndFindEdge looks for; ``None`` otherwise."""
        a = decision.action
        if a.kind == ActionKind.NAVIGATE:
            return decision.active_edge if decision.active_edge is not None else a.edge
        if a.kind == ActionKind.ROTATE_AND_FIND_EDGE:
            return a.edge
        return None

    def _follow(self, wanted: int, decision: Decision, along_belief: int | None) -> None:
        """Move to edge ``wanted``: across a place from the tracked edge's end, or afresh."""
        current = self.edge
        est = self.estimate
        if current is not None and est is not None:
            ends_at = self.edge_ends[current][1] if self.edge_ends else None
            starts_at = self.edge_ends[wanted][0] if self.edge_ends else None
            near_end = est.remaining_m <= self.p.chain_m
            if ends_at is not None and ends_at == starts_at and near_end:
                self._chain(current, wanted)
                return
            if est.locked:
                self.asked_other += 1
                if self.asked_other < self.p.switch_frames:
                    return
        self._start(wanted, decision, along_belief)

    def _start(self, edge: int, decision: Decision, along_belief: int | None) -> None:
        path = self.paths[edge]
        if decision.action.kind == ActionKind.ROTATE_AND_FIND_EDGE or along_belief is None:
            k = 0
        else:
            k = int(np.clip(along_belief, 0, path.n_images - 1))
        p = self.p
        self.edge = edge
        self.mean = path.poses[k].copy()
        heading = path.heading_at(float(path.along[k]))
        self.cov = initial_cov(heading, p.init_along_m, p.init_lateral_m, p.init_heading_rad)
        self.along = float(path.along[k])
        self.last_fix = None
        self.fixed_frames = 0
        self.asked_other = 0
        self.rival = 0
        self.refuted = 0
        self.trace = []
        self.chained = False

    def _chain(self, current: int, nxt: int) -> None:
        """Carry the estimate from the end of ``current`` into ``nxt``'s frame."""
        p = self.p
        end = self.paths[current].poses[-1]
        turn = None if self.link is None else self.link(current, nxt)
        sigma = p.link_sigma if turn is not None else p.init_heading_rad
        # the last image of ``current`` in ``nxt``'s frame: at its start (both were taken at
        # the place), heading ``turn`` (unknown: as the next edge starts)
        anchor = np.array([0.0, 0.0, 0.0 if turn is None else turn])
        here = relative(end, self.mean)
        mean = compose(anchor, here)
        rot = float(anchor[2] - end[2])
        c, s = math.cos(rot), math.sin(rot)
        J = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        cov = J @ self.cov @ J.T
        cov[2, 2] += sigma**2
        self.edge, self.mean, self.cov = nxt, mean, 0.5 * (cov + cov.T)
        self.along = 0.0
        self.asked_other = 0
        self.rival = 0
        self.refuted = 0
        self.chained = True

    # -- the camera --------------------------------------------------------------------------

    def _along(self, k: int) -> None:
        """Correct the along-path position by the belief's most likely image ``k``."""
        assert self.edge is not None
        path = self.paths[self.edge]
        k = int(np.clip(k, 0, path.n_images - 1))
        s = float(path.along[k])
        up = update_along(
            self.mean,
            self.cov,
            path.point_at(s),
            path.heading_at(s),
            self.p.along_sigma,
            gate=self.p.gate,
        )
        if up.used:
            self.mean, self.cov = up.mean, up.cov

    def _correct(self, features: ImageFeatures, t: float) -> int:
        """Correct the estimate with the taught images near it; the number of headings used."""
        assert self.edge is not None
        path, p = self.paths[self.edge], self.p
        along, _ = path.project(self.mean[:2])
        heading = float(self.mean[2])
        images = sorted({path.image_at(along + a, heading) for a in p.ahead_m})
        fixes = 0
        best: tuple[RelativePose, FloatArray] | None = None
        for k in images:
            taught = path.poses[k]
            fit = self._fit(features, self.image(self.edge, k))
            if fit is None:
                continue
            sigma = p.heading_sigma + fit.yaw_sigma
            up = update_heading(self.mean, self.cov, float(taught[2]) + fit.yaw, sigma, gate=p.gate)
            if up.used:
                self.mean, self.cov = up.mean, up.cov
                fixes += 1
            usable = (
                fit.bearing is not None
                and fit.parallax_px >= p.bearing_parallax_px
                and fit.inliers >= p.bearing_inliers
            )
            if usable and (best is None or fit.parallax_px > best[0].parallax_px):
                best = (fit, taught)
        if best is not None:
            fit, taught = best
            assert fit.bearing is not None
            sigma_b = p.bearing_sigma + (fit.bearing_sigma or 0.0)
            up = update_bearing(self.mean, self.cov, taught, fit.bearing, sigma_b, gate=p.gate)
            if up.used:
                self.mean, self.cov = up.mean, up.cov
        return fixes

    def _scan(self, depth: npt.NDArray[np.float64]) -> int:
        """Correct the estimate by aligning the frame's depth profile with the one taught
        nearest the estimate; 1 when it was used."""
        assert self.edge is not None
        if self.taught_depth is None:
            return 0
        path, p = self.paths[self.edge], self.p
        along, _ = path.project(self.mean[:2])
        locked = self.estimate is not None and self.estimate.locked
        best, wide = self._scan_fits(path, along, depth, locked)
        h = path.heading_at(along)
        if locked and best is not None and self._rivalled(path, wide) and wide is not None:
            self.mean, self.cov = self._measured(wide[1], wide[2], h)
            self.fixed_frames = 0
            return 1
        if best is None:
            return 0
        measured, R = self._measured(*best, h)
        up = update_pose(self.mean, self.cov, measured, R, gate=p.scan_gate)
        self.refuted = self.refuted + 1 if locked and not up.used else 0
        if self.refuted >= p.refute_fits:
            self._widen(h)
        if not up.used:
            return 0
        self.mean, self.cov = up.mean, up.cov
        return 1

    def _widen(self, heading: float) -> None:
        """Widen the position uncertainty back to a new estimate's (along the path at
        ``heading`` and across it), keep the heading's, and measure afresh before locking:
        the scan fits refuted the estimate (``refute_fits``)."""
        p = self.p
        sh = math.sqrt(max(float(self.cov[2, 2]), 0.0))
        self.cov = initial_cov(heading, p.init_along_m, p.init_lateral_m, sh)
        self.fixed_frames = 0
        self.refuted = 0

    def _scan_fits(
        self, path: EdgePath, along: float, depth: npt.NDArray[np.float64], locked: bool
    ) -> tuple[tuple[ScanFit, FloatArray] | None, tuple[ScanFit, ScanFit, FloatArray] | None]:
        """The profile aligned with those taught near ``along`` (:meth:`_scan_images`): the
        best fit and its taught pose (from the estimate while ``locked``, from several
        sideways guesses while not); and while locked, the fit from the estimate, a better one
        from the guesses and their taught pose where there is one (``None`` otherwise)."""
        assert self.edge is not None and self.taught_depth is not None
        p = self.p
        best: tuple[ScanFit, FloatArray] | None = None
        wide: tuple[ScanFit, ScanFit, FloatArray] | None = None
        for k in self._scan_images(path, along):
            taught = self.taught_depth(self.image(self.edge, k))
            if taught is None:
                continue
            pose_k = path.poses[k]
            guess = relative(pose_k, self.mean)
            robust = match_profiles_robust(
                taught,
                depth,
                guess,
                fov_deg=p.depth_fov_deg,
                params=p.scan_fit,
                lateral_m=p.join_lateral_m,
            )
            fit = robust
            if locked:
                fit = match_profiles(
                    taught, depth, guess, fov_deg=p.depth_fov_deg, params=p.scan_fit
                )
                if (
                    fit is not None
                    and robust is not None
                    and robust.score < fit.score
                    and robust.pairs >= p.rival_pairs
                    and (wide is None or robust.score < wide[1].score)
                ):
                    wide = (fit, robust, pose_k)
            if fit is not None and (best is None or fit.score < best[0].score):
                best = (fit, pose_k)
        return best, wide

    def _rivalled(self, path: EdgePath, wide: tuple[ScanFit, ScanFit, FloatArray] | None) -> bool:
        """Whether the best alignment from many guesses has now fitted better than the one
        from the estimate (``wide``: the two, relative to the taught pose, and that pose; or
        ``None``: it did not) and put the robot more than ``rival_m`` beside it, at the same
        offset from the path within ``rival_m``, on ``rival_frames`` fits in a row (frames
        with no fit at all do not count)."""
        if wide is None:
            self.rival = 0
            return False
        fit, rival, pose_k = wide
        _, lateral = path.project(compose(pose_k, fit.pose)[:2])
        _, other = path.project(compose(pose_k, rival.pose)[:2])
        if abs(other - lateral) <= self.p.rival_m:
            self.rival = 0
            return False
        same = self.rival > 0 and abs(other - self.rival_lateral) <= self.p.rival_m
        self.rival = self.rival + 1 if same else 1
        self.rival_lateral = other
        if self.rival < self.p.rival_frames:
            return False
        self.rival = 0
        return True

    def _measured(
        self, fit: ScanFit, pose_k: FloatArray, heading: float
    ) -> tuple[FloatArray, FloatArray]:
        """A scan fit relative to the taught pose ``pose_k`` as a measured pose in the edge's
        frame and its covariance (at least the scan's floor; along the path, at ``heading``,
        a profile may align one door further on: it tells the offset from the path and the
        heading well, how far along only loosely)."""
        p = self.p
        measured = compose(pose_k, fit.pose)
        c, s = math.cos(float(pose_k[2])), math.sin(float(pose_k[2]))
        J = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        R = J @ fit.cov @ J.T + np.diag([p.scan_sigma_m**2, p.scan_sigma_m**2, p.scan_sigma_rad**2])
        t = np.array([math.cos(heading), math.sin(heading)])
        R[:2, :2] += p.scan_along_sigma_m**2 * np.outer(t, t)
        return measured, R

    def _scan_images(self, path: EdgePath, along: float) -> list[int]:
        """The taught images to match the depth profile against: the one nearest ``along``;
        where the taught robot turned on the spot there (a place, before it set off or after
        it stopped), up to four across that turn, since the robot may face any way there."""
        k = path.image_at(along)
        same = path.stretch(k)
        if len(same) <= 1:
            return [k]
        picks = np.unique(np.linspace(0, len(same) - 1, 4).round().astype(int))
        return [int(same[i]) for i in picks]

    def _fit(self, features: ImageFeatures, image: int) -> RelativePose | None:
        src, dst = match_features(features, self.features[image], params=HomingParams())
        return relative_pose(src, dst, self.camera, self.p.relpose)

    # -- what it says ------------------------------------------------------------------------

    def _estimate(self, t: float, fixes: int) -> PathEstimate:
        assert self.edge is not None
        path, p = self.paths[self.edge], self.p
        along, lateral = path.project(self.mean[:2])
        self.along = along
        heading = path.heading_at(along)
        nearest = path.image_at(along, float(self.mean[2]))
        pc = path_frame_cov(self.cov, heading)
        sl, sa = math.sqrt(max(pc[1, 1], 0.0)), math.sqrt(max(pc[0, 0], 0.0))
        sh = math.sqrt(max(self.cov[2, 2], 0.0))
        since = math.inf if self.last_fix is None else max(t - self.last_fix, 0.0)
        locked = (
            sl <= p.lock_lateral_m
            and sh <= p.lock_heading_rad
            and since <= p.lock_fix_s
            and self.fixed_frames >= p.lock_frames
        )
        return PathEstimate(
            edge=self.edge,
            pose=self.mean.copy(),
            cov=self.cov.copy(),
            along_m=along,
            lateral_m=lateral,
            heading_error=float(wrap(self.mean[2] - heading)),
            sigma_lateral=sl,
            sigma_along=sa,
            sigma_heading=sh,
            locked=locked,
            fixes=fixes,
            image=self.image(self.edge, nearest),
            index=nearest,
            length_m=path.length,
            since_fix_s=since,
            chained=self.chained,
        )

    def _remember(self, est: PathEstimate) -> None:
        """Keep the trace since the last locked frame (retracing drives back along it)."""
        point = TracePoint(est.edge, est.pose, est.locked)
        if est.locked:
            self.trace = [point]
        elif self.trace and self.trace[0].edge == est.edge:
            self.trace.append(point)
        else:
            self.trace = []

    def retrace_route(self) -> list[FloatArray]:
        """The poses to drive back through (the most recent first, the last locked one last),
        in the tracked edge's frame; empty when there is nothing to retrace."""
        if len(self.trace) < 2 or self.edge is None or self.trace[0].edge != self.edge:
            return []
        return [tp.pose for tp in reversed(self.trace)]


def path_likelihood(
    estimate: PathEstimate | None,
    edge_first_fine: int,
    along: npt.NDArray[np.float64],
    n_fine: int,
    ratio: float,
) -> FloatArray | None:
    """``(n_fine,)`` the tracker's word as a likelihood over the fine states: 1 at the images
    of the tracked edge (fine states from ``edge_first_fine``, their metres ``along`` it)
    within the tracker's along-path uncertainty of its estimate, falling off as a Gaussian to
    ``1 / ratio`` elsewhere and everywhere else; ``None`` while the tracker is not locked (or
    ``ratio`` is 1: no evidence)."""
    if estimate is None or not estimate.locked or ratio <= 1.0:
        return None
    sigma = max(estimate.sigma_along, 0.3)
    near = np.exp(-0.5 * ((np.asarray(along) - estimate.along_m) / sigma) ** 2)
    out = np.full(n_fine, 1.0 / ratio)
    out[edge_first_fine : edge_first_fine + len(along)] += (1.0 - 1.0 / ratio) * near
    return out
