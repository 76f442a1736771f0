"""What the robot perceives on one frame, computed once by :func:`perceive` and then frozen.

``perceive`` is the only stage of a navigation step that reads the frame: features, similarities
to the tour, the belief update, the policy's votes, and the matches of the frame against the
taught images the behaviours asked for (:class:`ViewRequest`, from each behaviour's ``wants``).
Behaviours then decide from the :class:`Observation` alone; none of them calls into vision.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from functools import cache
from typing import Generic, TypeVar

import numpy as np
import numpy.typing as npt

from server.belief.model import Action, ActionKind
from server.belief.tracker import BeliefSummary, Tracker
from server.navigation.command import Command, Proposal
from server.navigation.pathtrack import PathEstimate, PathTracker
from server.navigation.runtime import TourRuntime, preferred
from server.policy.voting import NAVIGATE as NAVIGATE_CODE
from server.policy.voting import ROTATE0, Decision, decide, plan_for
from server.vision.features import ImageFeatures, extract
from server.vision.homing import (
    HomingResult,
    ScaleResult,
    homing_offset,
    homing_scale,
    homing_scale_taught_zoomed,
    homing_scale_zoomed,
    zoom_levels,
)
from server.vision.index import Similarity

FloatArray = npt.NDArray[np.float64]
T = TypeVar("T")


def elapsed(now: float, then: float) -> float:
    """Robot seconds from ``then`` to ``now``, rounded to the microsecond. The difference of two
    large timestamps carries a rounding error (~1e-13 s at 3000 s) that depends on how large the
    robot clock has grown; thresholds reached exactly (ten frames of 0.1 s against an
    ``approach_s`` of 1 s, 40 frames against ``unstick_s``) then fell one frame earlier or later
    depending on the clock, and with them the course of a whole trial."""
    return round(now - then, 6)


@dataclass(frozen=True)
class ViewRequest:
    """Taught images (canonical indices) a behaviour wants the frame matched against:
    ``offsets`` by homing (:func:`~server.vision.homing.homing_offset`), ``scales`` by a scale
    fit (:func:`~server.vision.homing.homing_scale`), ``zoomed`` by a scale fit through the
    frame's zoom levels (:func:`~server.vision.homing.homing_scale_zoomed`)."""

    offsets: frozenset[int] = frozenset()
    scales: frozenset[int] = frozenset()
    zoomed: frozenset[int] = frozenset()

    def __or__(self, other: ViewRequest) -> ViewRequest:
        return ViewRequest(
            self.offsets | other.offsets, self.scales | other.scales, self.zoomed | other.zoomed
        )

    @staticmethod
    def union(requests: Iterable[ViewRequest]) -> ViewRequest:
        out = ViewRequest()
        for r in requests:
            out = out | r
        return out


class ViewNotRequested(KeyError):
    """A behaviour read a match it did not ask for in ``wants``: a bug in that behaviour."""


@dataclass(frozen=True)
class Views:
    """The frame matched against taught images, as requested (``None``: nothing matched)."""

    offsets: Mapping[int, HomingResult | None] = field(default_factory=dict)
    scales: Mapping[int, ScaleResult | None] = field(default_factory=dict)
    zoomed: Mapping[int, ScaleResult | None] = field(default_factory=dict)
    taught_zoomed: Mapping[int, ScaleResult | None] = field(default_factory=dict)

    def offset(self, image: int) -> HomingResult | None:
        """Homing of the frame on taught image ``image``."""
        _check(self.offsets, image, "offsets")
        return self.offsets[image]

    def scale(self, image: int) -> ScaleResult | None:
        """Scale fit of the frame on taught image ``image``."""
        _check(self.scales, image, "scales")
        return self.scales[image]

    def zoomed_scale(self, image: int) -> ScaleResult | None:
        """Scale fit through the frame's zoom levels on taught image ``image``."""
        _check(self.zoomed, image, "zoomed")
        return self.zoomed[image]

    def taught_zoomed_scale(self, image: int) -> ScaleResult | None:
        """Scale fit of the frame on taught image ``image``'s own zoom levels (requested as
        ``zoomed``): no extraction of the frame's zooms, unless the runtime cannot read the
        taught image's pixels (then the frame's, as :meth:`zoomed_scale`)."""
        _check(self.taught_zoomed, image, "zoomed")
        return self.taught_zoomed[image]


def _check(table: Mapping[int, object], image: int, kind: str) -> None:
    if image not in table:
        raise ViewNotRequested(f"view {kind}[{image}] was not requested in wants()")


@dataclass(frozen=True)
class Outcome:
    """What a frame decided: the chosen command, the behaviour that won and why, every
    behaviour's proposal (by name, ``None`` when it had nothing to say) and the events
    behaviours announced."""

    command: Command
    winner: str
    reason: str
    proposals: Mapping[str, object] = field(default_factory=dict)
    events: frozenset[str] = frozenset()

    @property
    def wanted(self) -> Command | None:
        """The winner's command as it proposed it, before obstacle avoidance changed it."""
        proposal = self.proposals.get(self.winner)
        return proposal.command if isinstance(proposal, Proposal) else None


@dataclass(frozen=True)
class Observation:
    """One frame as the behaviours see it.

    Attributes:
        t: robot time of the frame, s. dt: robot seconds since the last frame (clipped to
            ``max_dt_s``; 0 on a task's first frame).
        v, w: the motion the robot reported for the last frame (odometry), m/s and rad/s.
        depth: ``(n_rays,)`` ranges in metres left to right, or ``None`` (no depth sensor).
        features, similarity: the frame's features and its similarities to the tour.
        summary: the belief after this frame. decision: the policy's votes and action.
        goal: the task's goal location. steps: frames of the task before this one.
        at_goal: the belief puts the robot at the goal (``arrive_mass`` at the goal and the
            images just before it, the evidence agreeing, ``arrive_min_steps`` into the task).
        goal_ambiguity: how much the goal's spin images look like elsewhere
            (:meth:`TourRuntime.place_ambiguity`), when ``at_goal`` (else ``None``).
        views: the matches the behaviours asked for.
        previous: the last frame's :class:`Outcome` (``None`` on a task's first frame).
        path: where the robot is relative to the taught path it tracks
            (:class:`~server.navigation.pathtrack.PathEstimate`), ``None`` when it tracks none.
        retrace: the poses to drive back through to where the path was last tracked (in the
            tracked edge's frame, the most recent first; empty: nothing to retrace).
    """

    t: float
    dt: float
    v: float
    w: float
    depth: FloatArray | None
    features: ImageFeatures
    similarity: Similarity
    summary: BeliefSummary
    decision: Decision
    goal: int
    steps: int
    at_goal: bool
    goal_ambiguity: float | None
    views: Views
    previous: Outcome | None
    path: PathEstimate | None = None
    retrace: tuple[FloatArray, ...] = ()


@dataclass(frozen=True)
class Frame:
    """What the robot sends: the image, its robot timestamp (s), its odometry (m/s, rad/s)
    and its depth profile (metres, left to right; ``None`` without a sensor)."""

    image: npt.NDArray[np.uint8]
    timestamp: float
    v: float
    w: float = 0.0
    depth: FloatArray | None = None


def perceive(
    runtime: TourRuntime,
    tracker: Tracker,
    frame: Frame,
    *,
    last_action: Action,
    dt: float,
    goal: int,
    steps: int,
    hold_goal: bool,
    previous: Outcome | None,
    wants: Callable[[Observation], ViewRequest],
    path: PathTracker | None = None,
) -> Observation:
    """Features, similarities, the belief update, the policy's votes, the path tracker, then
    the views asked for.

    Args:
        tracker: the robot's belief tracker; stepped once (its belief changes).
        last_action: the action executed since the last frame (the belief's prediction).
        dt: robot seconds since the last frame. goal, steps: the task's goal and frames so far.
        hold_goal: the goal votes to leave by its round trip (not yet approached).
        previous: the last frame's outcome.
        wants: given the observation without views, the views the behaviours need.
        path: the task's path tracker (stepped once), or ``None`` (topometric repeat off).
    """
    p = runtime.params
    features = extract(frame.image, p.features)
    similarities, likelihood = runtime.observe(features)
    if path is not None and path.estimate is not None:
        likelihood = likelihood * runtime.path_evidence(path.estimate)[None, :]
    summary = runtime.believe(
        tracker, last_action, similarities, likelihood, v=frame.v, w=frame.w, dt=dt
    )
    similarity = preferred(similarities, summary)
    decision = decide(
        runtime.graph,
        summary.belief,
        goal,
        runtime.costs(goal),
        runtime.params.policy,
        hold_goal=hold_goal,
    )
    if path is not None:
        decision = committed(
            runtime, summary.belief, decision, goal, path.estimate, hold_goal, similarity.image
        )
    estimate = None
    if path is not None:
        wanted = path.wanted(decision)
        searching = decision.action.kind == ActionKind.ROTATE_AND_FIND_EDGE
        estimate = path.step(
            features,
            t=frame.timestamp,
            v=frame.v,
            w=frame.w,
            dt=dt,
            decision=decision,
            along_belief=None if wanted is None else runtime.belief_image(summary.belief, wanted),
            depth=frame.depth,
            facing=not searching
            or wanted is None
            or runtime.faces_departure(similarity.image, wanted),
        )
    mass = runtime.goal_mass(summary.belief, goal, estimate)
    agrees = summary.evidence >= p.tracker.localised_evidence
    at_goal = mass >= p.arrive_mass and agrees and steps + 1 >= p.arrive_min_steps
    seen = Observation(
        t=frame.timestamp,
        dt=dt,
        v=frame.v,
        w=frame.w,
        depth=frame.depth,
        features=features,
        similarity=similarity,
        summary=summary,
        decision=decision,
        goal=goal,
        steps=steps,
        at_goal=at_goal,
        goal_ambiguity=runtime.place_ambiguity(goal) if at_goal else None,
        views=Views(),
        previous=previous,
        path=estimate,
        retrace=() if path is None else tuple(path.retrace_route()),
    )
    return replace(seen, views=match_views(runtime, frame.image, features, wants(seen)))


def committed(
    runtime: TourRuntime,
    belief: FloatArray,
    decision: Decision,
    goal: int,
    estimate: PathEstimate | None,
    hold_goal: bool,
    similarity: FloatArray,
) -> Decision:
    """The decision, or, while the path tracker is locked on an edge the belief still holds
    (``TopometricParams.commit_mass`` on its images, its start and its end place; within
    ``chain_m`` of its start, also on the edges that end at that place), the vote of the
    tracked image when that is to go on along it: the tracker knows where along the edge the
    robot is better than the split belief does (look-alike edges leaving a place flip the
    vote from frame to frame). At the end of the tracked edge, into a place that is not the
    goal, the vote of that place: the route goes on along the edge it votes for, through the
    place without stopping (:func:`through_place`). Explore and a decision for the tracked
    edge are left alone, and so is a search for the tracked edge at its start place while the
    place's spin views (``similarity``: ``(n_images,)``, the engine's for this frame) say the
    robot faces away from where it sets off (:meth:`TourRuntime.faces_departure`), unless the
    tracker came onto the edge through that place from the one before."""
    if estimate is None or not estimate.locked or decision.action.kind == ActionKind.EXPLORE:
        return decision
    tp = runtime.params.topometric
    if estimate.remaining_m <= tp.chain_m:
        return through_place(runtime, belief, decision, goal, estimate, hold_goal)
    edge = estimate.edge
    if decision.action.kind == ActionKind.NAVIGATE and decision.active_edge == edge:
        return decision
    searching = decision.action.kind == ActionKind.ROTATE_AND_FIND_EDGE
    if (
        searching
        and decision.action.edge == edge
        and not estimate.chained
        and not runtime.faces_departure(similarity, edge)
    ):
        return decision
    if held_mass(runtime, belief, estimate) < tp.commit_mass:
        return decision
    plan = plan_for(
        runtime.graph, goal, runtime.costs(goal), runtime.params.policy, hold_goal=hold_goal
    )
    g = runtime.graph
    lo = g.n_locations + int(g.edge_offsets[edge])
    k = estimate.index
    if plan.vote[lo + k] != NAVIGATE_CODE:
        return decision
    target = min(k + 1, g.edges[edge].n_images - 1)
    return replace(decision, action=Action.navigate(edge), target_image=target, active_edge=edge)


def through_place(
    runtime: TourRuntime,
    belief: FloatArray,
    decision: Decision,
    goal: int,
    estimate: PathEstimate,
    hold_goal: bool,
) -> Decision:
    """At the end of the tracked edge (a locked ``estimate`` within ``chain_m`` of it): when
    the edge ends at a place that is not the goal and the belief holds the edge
    (``commit_mass``), Navigate the edge that place votes for, so that the path tracker
    carries its estimate through the place into it (:meth:`PathTracker.step`) rather than
    waiting for the belief to reach the place, stopping and searching for the edge's
    departure; the decision as it is otherwise (the next edge is then the policy's to
    choose)."""
    g = runtime.graph
    place = g.edges[estimate.edge].target
    if (
        place == goal
        or held_mass(runtime, belief, estimate) < runtime.params.topometric.commit_mass
    ):
        return decision
    plan = plan_for(g, goal, runtime.costs(goal), runtime.params.policy, hold_goal=hold_goal)
    code = int(plan.vote[place]) - ROTATE0
    if code < 0 or g.edges[code].source != place or g.edges[code].n_images == 0:
        return decision
    target = min(1, g.edges[code].n_images - 1)
    return replace(decision, action=Action.navigate(code), target_image=target, active_edge=code)


def held_mass(runtime: TourRuntime, belief: FloatArray, estimate: PathEstimate) -> float:
    """The belief's mass on the tracked edge: its images, its start and its end place, and,
    within ``chain_m`` of its start, the images of the edges that end at its start (a robot
    that has just come through the place is still at their end as much as at its start)."""
    g = runtime.graph
    upper = runtime.model.upper_mass(belief)  # (n_states,): the places, then the edges
    L = g.n_locations
    e = g.edges[estimate.edge]
    mass = float(upper[L + estimate.edge] + upper[e.source] + upper[e.target])
    if estimate.along_m <= runtime.params.topometric.chain_m:
        mass += float(upper[L:][list(runtime.model.in_edges[e.source])].sum())
    return mass


class LazyFits(Mapping[int, T | None], Generic[T]):
    """The fits of the requested taught images, each computed the first time a behaviour
    reads it (then kept): a view requested but not read this frame costs nothing. The keys
    are the requested images; reading another raises ``KeyError``."""

    def __init__(self, images: Iterable[int], fit: Callable[[int], T | None]) -> None:
        self._images = frozenset(int(i) for i in images)
        self._fit = fit
        self._done: dict[int, T | None] = {}

    def __getitem__(self, image: int) -> T | None:
        if image not in self._done:
            if image not in self._images:
                raise KeyError(image)
            self._done[image] = self._fit(image)
        return self._done[image]

    def __contains__(self, image: object) -> bool:
        return image in self._images

    def __iter__(self) -> Iterator[int]:
        return iter(sorted(self._images))

    def __len__(self) -> int:
        return len(self._images)


def match_views(
    runtime: TourRuntime,
    image: npt.NDArray[np.uint8],
    features: ImageFeatures,
    request: ViewRequest,
) -> Views:
    """The frame matched against every requested taught image, each match made when a
    behaviour first reads it (:class:`LazyFits`): the same fits, only those read.

    A zoomed fit reads the frame's zoom levels (:func:`~server.vision.homing.zoom_levels`:
    four corner extractions, made once per frame, and only on a frame that reads a zoomed
    fit). ``taught_zoomed`` holds the fits on the taught images' zooms instead
    (:meth:`TourRuntime.taught_levels`, made once per taught image), for looking for a view
    with ``dock_taught_zooms`` ``"look"``; where the runtime has no taught levels (``"off"``,
    or pixels it cannot read) they are the frame's zoomed fits."""
    taught = runtime.features
    p = runtime.params
    frame_levels = cache(lambda: zoom_levels(image, features, p.dock_zooms, p.features))

    zoomed_fits = LazyFits(request.zoomed, lambda i: homing_scale_zoomed(frame_levels(), taught[i]))

    def taught_zoomed(i: int) -> ScaleResult | None:
        levels = runtime.taught_levels(i)
        if levels is None:
            return zoomed_fits[i]  # the frame's zooms: the same fit, made once
        return homing_scale_taught_zoomed(features, levels)

    return Views(
        offsets=LazyFits(request.offsets, lambda i: homing_offset(features, taught[i])),
        scales=LazyFits(request.scales, lambda i: homing_scale(features, taught[i])),
        zoomed=zoomed_fits,
        taught_zoomed=LazyFits(request.zoomed, taught_zoomed),
    )
