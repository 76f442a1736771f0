"""What the core derives from one snapshot of a tour, shared by every robot navigating it."""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import replace
from functools import lru_cache

import numpy as np
import numpy.typing as npt

from server.belief.appearance import familiarity
from server.belief.model import Action, BeliefModel, build_model
from server.belief.tracker import BeliefSummary, Tracker, fine_likelihood
from server.domain import TourGraph
from server.navigation.geometry import TaughtPaths
from server.navigation.params import NavigationParams
from server.navigation.pathtrack import PathEstimate, PathTracker, path_likelihood
from server.policy.costs import cost_to_goal
from server.vision.distinctiveness import ImageLayout, image_entropy
from server.vision.features import ImageFeatures
from server.vision.homing import HomingParams, ZoomLevel, match_features, taught_zoom_levels
from server.vision.index import Similarity, TourIndex
from server.vision.relpose import relative_pose

FloatArray = npt.NDArray[np.float64]
#: Reads a taught image's pixels by canonical index: ``(H, W, 3) uint8`` BGR, or ``None``
#: when they cannot be had.
TaughtPixels = Callable[[int], "npt.NDArray[np.uint8] | None"]
#: Taught images whose zoom levels (:meth:`TourRuntime.taught_levels`) a runtime keeps, the
#: least recently asked for forgotten first: about 18 kB each with the default features
#: (4 levels of at most 100 corners: 8 bytes of position and 36 of descriptor each).
ZOOM_CACHE_IMAGES = 256


class TourRuntime:
    """What the core derives from one snapshot of a tour. Immutable once built but for the
    taught images' zoom levels it makes as docking asks for them (:meth:`taught_levels`,
    under a lock); shared by every robot navigating the tour."""

    def __init__(
        self,
        graph: TourGraph,
        features: Sequence[ImageFeatures],
        params: NavigationParams,
        *,
        version: int = 0,
    ) -> None:
        if len(features) != graph.n_images:
            raise ValueError(f"{len(features)} features for {graph.n_images} images")
        self.graph = graph
        self.params = params
        self.version = version
        self.features = tuple(features)
        self._levels: tuple[bytes, FloatArray] | None = None  # error_levels(), per weights
        self.index = TourIndex(params.engine)
        if graph.n_images:
            self.index.add(self.features, graph.image_state)
        self.model: BeliefModel = build_model(graph, params.transitions)
        self._costs = lru_cache(maxsize=64)(self._cost_to_goal)
        # canonical index of edge e's first image
        self._edge_first = graph.n_images - int(graph.edge_offsets[-1]) + graph.edge_offsets
        # index along each edge of the image where the taught robot started to move forward
        self.departure = tuple(_first_forward(e.v) for e in graph.edges)
        # index along each edge of the last image taught while moving forward (the robot was
        # at the place from there on, maybe turning to face the way the guide named it)
        self.arrival = tuple(_last_forward(e.v) for e in graph.edges)
        # for every edge image, the index of the first image at or after it that moves
        self._moving = tuple(next_moving(e.v, e.w) for e in graph.edges)
        self.at_location = _at_locations(graph, self.model)
        # locations a robot can leave and come back into along taught edges
        ins = {e.target for e in graph.edges if e.n_images > 0}
        outs = {e.source for e in graph.edges if e.n_images > 0}
        self.approachable = tuple(k in ins and k in outs for k in range(graph.n_locations))
        # canonical indices of each location's spin images (they come first, in order)
        counts = [len(loc.image_ids) for loc in graph.locations]
        firsts = np.cumsum([0, *counts])
        self.spin_images = tuple(
            np.arange(firsts[k], firsts[k + 1], dtype=np.int64) for k in range(graph.n_locations)
        )
        self._ambiguity: dict[int, float] = {}
        # every edge's taught path, dead-reckoned from the taught odometry, and how edges meet
        # at places (the heading of one's last image in the next one's frame, from the images)
        self.paths = TaughtPaths.of(graph)
        # the depth profiles taught with the images (canonical index -> metres, left to right),
        # set by whoever built the runtime when the robot sent them
        self.taught_depth: dict[int, npt.NDArray[np.float32]] = {}
        self._links: dict[tuple[int, int], float | None] = {}
        self._links_lock = threading.Lock()
        self._departure_spins: dict[int, int | None] = {}
        # how to read a taught image's pixels (set by whoever built the runtime), for
        # NavigationParams.dock_taught_zooms; without it docking zooms the frame only
        self.taught_pixels: TaughtPixels | None = None
        self._zoomed: OrderedDict[int, tuple[ZoomLevel, ...] | None] = OrderedDict()
        self._zoomed_lock = threading.Lock()

    def taught_levels(self, image: int) -> tuple[ZoomLevel, ...] | None:
        """Taught image ``image``'s (canonical index) zoom levels for docking's scale fits
        while it looks for a view (``params.dock_taught_zooms`` ``"look"``): the taught image
        zoomed in and out (:func:`~server.vision.homing.taught_zoom_levels` of
        ``params.dock_zooms``). Made from its pixels the first time it is asked for (four
        corner extractions), then kept for the :data:`ZOOM_CACHE_IMAGES` images last asked
        for. ``None`` with ``dock_taught_zooms`` ``"off"`` or when the runtime cannot read the
        taught pixels (no :attr:`taught_pixels`, or it gave ``None``)."""
        p = self.params
        if p.dock_taught_zooms == "off":
            return None
        with self._zoomed_lock:
            if image in self._zoomed:
                self._zoomed.move_to_end(image)
                return self._zoomed[image]
        read = self.taught_pixels
        if read is None:
            return None  # nothing to remember: pixels may be given later
        pixels = read(image)
        levels = (
            None
            if pixels is None
            else taught_zoom_levels(pixels, self.features[image], p.dock_zooms, p.features)
        )
        with self._zoomed_lock:  # two threads may have made it at once: the same levels
            self._zoomed[image] = levels
            self._zoomed.move_to_end(image)
            while len(self._zoomed) > ZOOM_CACHE_IMAGES:
                self._zoomed.popitem(last=False)
        return levels

    def path_tracker(self) -> PathTracker:
        """A fresh path tracking filter for one task on this tour."""
        g = self.graph
        return PathTracker(
            self.paths.edges,
            self.features,
            self._edge_first,
            self.params.topometric,
            link=self.link,
            edge_ends=tuple((e.source, e.target) for e in g.edges),
            depth=self.taught_depth.get,
        )

    def path_evidence(self, estimate: PathEstimate) -> FloatArray:
        """``(n_fine,)`` the path tracker's word as a likelihood (all ones when it has none:
        :func:`~server.navigation.pathtrack.path_likelihood`)."""
        g = self.graph
        first = g.n_locations + int(g.edge_offsets[estimate.edge])
        out = path_likelihood(
            estimate,
            first,
            self.paths[estimate.edge].along,
            g.n_fine,
            self.params.topometric.path_evidence,
        )
        return np.ones(g.n_fine) if out is None else out

    def link(self, edge_in: int, edge_out: int) -> float | None:
        """The heading (rad) of ``edge_in``'s last image in ``edge_out``'s frame, where
        ``edge_in`` ends at the place ``edge_out`` starts from; ``None`` when their images do
        not overlap. Both were taught at the place: the turn between two of their images is
        a rotation, read from the features (:func:`~server.vision.relpose.relative_pose`);
        of the last images of ``edge_in`` (from where the taught robot stopped driving) and
        the first of ``edge_out`` (until it set off), the pair that agrees best. Made once
        per pair and kept."""
        key = (edge_in, edge_out)
        with self._links_lock:
            if key in self._links:
                return self._links[key]
        found = self._find_link(edge_in, edge_out)
        with self._links_lock:
            self._links[key] = found
        return found

    def _find_link(self, edge_in: int, edge_out: int) -> float | None:
        p_in, p_out = self.paths[edge_in], self.paths[edge_out]
        if p_in.n_images == 0 or p_out.n_images == 0:
            return None
        ins = _spread(range(self.arrival[edge_in], p_in.n_images), 4)
        outs = _spread(range(0, min(self.departure[edge_out] + 2, p_out.n_images)), 4)
        camera = self.params.topometric.camera
        best: tuple[int, float] | None = None
        for j in ins:
            for k in outs:
                src, dst = match_features(
                    self.features[self.edge_image(edge_in, j)],
                    self.features[self.edge_image(edge_out, k)],
                    params=HomingParams(),
                )
                fit = relative_pose(src, dst, camera, self.params.topometric.relpose)
                if fit is None or (best is not None and fit.inliers <= best[0]):
                    continue
                # image j of edge_in, in edge_out's frame: image k's heading plus the turn
                heading_j = float(p_out.poses[k, 2]) + fit.yaw
                last = heading_j + float(p_in.poses[-1, 2] - p_in.poses[j, 2])
                best = (fit.inliers, last)
        return None if best is None else best[1]

    def departure_spin(self, edge: int) -> int | None:
        """Which of the source place's spin images (index among them) faces the way ``edge``
        sets off: the one whose features agree best (most inliers of the two-view fit,
        :func:`~server.vision.relpose.relative_pose`) with the edge's image where the taught
        robot set off; ``None`` without spin images or when none fits. Made once per edge."""
        with self._links_lock:
            if edge in self._departure_spins:
                return self._departure_spins[edge]
        spins = self.spin_images[self.graph.edges[edge].source]
        path = self.paths[edge]
        found: int | None = None
        if len(spins) and path.n_images:
            k = self.edge_image(edge, min(self.departure[edge], path.n_images - 1))
            tp = self.params.topometric
            most = 0
            for i, image in enumerate(spins):
                src, dst = match_features(
                    self.features[int(image)], self.features[k], params=HomingParams()
                )
                fit = relative_pose(src, dst, tp.camera, tp.relpose)
                if fit is not None and fit.inliers > most:
                    found, most = i, fit.inliers
        with self._links_lock:
            self._departure_spins[edge] = found
        return found

    def faces_departure(self, similarity: FloatArray, edge: int) -> bool:
        """Whether a robot at ``edge``'s source place, whose view the engine scores
        ``similarity`` ``(n_images,)`` against the taught images, faces within a quarter turn
        of the way the edge sets off: the spin image it looks most like, against the one that
        faces that way (:meth:`departure_spin`), the spin images taken evenly over one turn.
        ``True`` when it cannot tell (fewer than 8 spin images, no fit). A corridor looks
        alike both ways: its views alone let a robot facing away join the path."""
        spins = self.spin_images[self.graph.edges[edge].source]
        departs = self.departure_spin(edge)
        if len(spins) < 8 or departs is None:
            return True
        now = int(np.argmax(similarity[spins]))
        steps = abs(now - departs) % len(spins)
        turn = 2 * np.pi * min(steps, len(spins) - steps) / len(spins)
        return bool(turn <= np.pi / 2)

    def goal_mass(self, belief: FloatArray, goal: int, estimate: PathEstimate | None) -> float:
        """The belief's mass at ``goal``: on the place and the exit zones of the edges into it
        (``at_location``); while the path tracker is locked on an edge into the goal and puts
        the robot within ``TopometricParams.arrive_m`` of its end, also on that edge's images
        within ``arrive_stretch_m`` of the end (the images a robot standing at the end of the
        path matches are physically there, whichever of them the belief favours)."""
        at = self.at_location[goal]
        tp = self.params.topometric
        g = self.graph
        if (
            estimate is None
            or not estimate.locked
            or g.edges[estimate.edge].target != goal
            or estimate.remaining_m > tp.arrive_m
        ):
            return float(belief[at].sum())
        path = self.paths[estimate.edge]
        first = g.n_locations + int(g.edge_offsets[estimate.edge])
        stretch = first + np.nonzero(path.along >= path.length - tp.arrive_stretch_m)[0]
        return float(belief[np.union1d(at, stretch)].sum())

    def belief_image(self, belief: FloatArray, edge: int) -> int:
        """The image of ``edge`` (index along it) the belief ``(n_fine,)`` puts most mass on."""
        g = self.graph
        lo = g.n_locations + int(g.edge_offsets[edge])
        hi = g.n_locations + int(g.edge_offsets[edge + 1])
        if hi <= lo:
            return 0
        return int(np.argmax(belief[lo:hi]))

    def place_ambiguity(self, location: int, near_m: float = 1.0) -> float:
        """How much the place's spin images look like elsewhere in the tour: the mean, over its
        spin images, of the engine's best similarity (in [0, 1]) to an image taken more than
        ``near_m`` metres from the place (by the taught speeds: every image but the place's own
        and the ends of the edges at it). Look-alike rooms score ~0.7 in the simulated home,
        the others 0.2-0.35. Computed on first use (one engine query per spin image)."""
        cached = self._ambiguity.get(location)
        if cached is not None:
            return cached
        g = self.graph
        spins = self.spin_images[location]
        if len(spins) == 0:
            return 1.0
        near = np.zeros(g.n_images, dtype=bool)
        near[spins] = True
        for j, e in enumerate(g.edges):
            if e.n_images == 0 or location not in (e.source, e.target):
                continue
            along = e.metres_along()
            mine = np.zeros(e.n_images, dtype=bool)
            if e.source == location:
                mine |= along <= near_m
            if e.target == location:
                mine |= along >= along[-1] - near_m
            near[self._edge_first[j] + np.arange(e.n_images)] |= mine
        if near.all():
            return 0.0
        best = [
            float(self.index.query(self.features[i], n_states=g.n_states).image[~near].max())
            for i in spins
        ]
        self._ambiguity[location] = out = float(np.mean(best))
        return out

    def distinctiveness(self) -> FloatArray:
        """``(n_images,)`` every image's distinctiveness (nats), computed now
        (:mod:`server.vision.distinctiveness`; one engine query per sampled image: call it
        once the index has its weights)."""
        return image_entropy(
            self.index,
            self.features,
            image_layout(self.graph),
            self.params.ambiguity.distinctiveness,
        )

    def attach_distinctiveness(self, entropy: npt.ArrayLike) -> None:
        """Give the tour's images their ``(n_images,)`` entropies (stored or just computed,
        :mod:`server.vision.distinctiveness`). Part of building the runtime, before it is
        shared."""
        self.graph = replace(self.graph, image_entropy=np.asarray(entropy, dtype=np.float64))

    def moving_from(self, edge: int, k: int) -> int | None:
        """Index of the first image of ``edge`` at or after ``k`` taught while moving (``None``
        when the robot stood still from ``k`` to the end)."""
        nxt = int(self._moving[edge][k])
        return None if nxt < 0 else nxt

    def _cost_to_goal(self, goal: int) -> FloatArray:
        return cost_to_goal(self.graph, goal, self.params.costs)

    def costs(self, goal: int) -> FloatArray:
        """``(n_locations,)`` seconds to reach location ``goal`` from every location."""
        return self._costs(goal)

    def edge_image(self, edge: int, k: int) -> int:
        """Canonical image index of the ``k``-th image of ``edge``."""
        n = self.graph.edges[edge].n_images
        return int(self._edge_first[edge]) + int(np.clip(k, 0, n - 1))

    def observe(self, features: ImageFeatures) -> tuple[tuple[Similarity, ...], FloatArray]:
        """Engine similarities of a frame under every appearance model
        (:meth:`TourIndex.query_models`) and the ``(K, n_fine)`` likelihoods they give, one row
        per model, for :meth:`Tracker.step` to weigh."""
        sims = self.index.query_models(features, n_states=self.graph.n_states)
        return sims, np.stack([fine_likelihood(s.image, self.graph) for s in sims])

    def believe(
        self,
        tracker: Tracker,
        action: Action,
        sims: Sequence[Similarity],
        likelihood: FloatArray,
        *,
        v: float,
        w: float,
        dt: float,
    ) -> BeliefSummary:
        """Step ``tracker`` (:meth:`Tracker.step`) with one frame: the action executed since
        the last frame, the frame's similarities under every appearance model and the
        ``(K, n_fine)`` likelihoods made of them (:meth:`observe`, maybe weighed since), the
        odometry (m/s, rad/s) over ``dt`` s; with the frame's familiarity."""
        return tracker.step(action, likelihood, v=v, w=w, dt=dt, familiarity=self.familiarity(sims))

    def familiarity(self, sims: Sequence[Similarity]) -> float:
        """The frame's familiarity in [0, 1] for :meth:`Tracker.step`: its best error under
        the tour's model among the tour's error levels
        (:func:`server.belief.appearance.familiarity`); NaN with one appearance model."""
        if len(sims) < 2:
            return math.nan
        return familiarity(sims[0].best_error, self.error_levels())

    def error_levels(self) -> FloatArray:
        """The tour's error levels (:meth:`TourIndex.error_levels`, states related when they
        share a place), computed once per set of weights (a query per probe: 0.5-0.8 s of CPU on a
        111-image route, 3.7-4.1 s on 1800 images of 361 states, docs/localize.md)."""
        key = self.index.weights.tobytes()
        if self._levels is None or self._levels[0] != key:
            self._levels = (key, self.index.error_levels(related_states(self.graph)))
        return self._levels[1]


def _spread(indices: range, most: int) -> list[int]:
    """At most ``most`` of ``indices``, evenly spread (both ends kept)."""
    if len(indices) <= most:
        return list(indices)
    picks = np.linspace(0, len(indices) - 1, most).round().astype(int)
    return [indices[int(i)] for i in np.unique(picks)]


def related_states(graph: TourGraph) -> npt.NDArray[np.bool_]:
    """``(n_states, n_states) bool``: states that share a place (a place and itself, a place
    and the edges at it, two edges at one place), whose images overlap near that place."""
    nl = graph.n_locations
    inc = np.zeros((graph.n_states, nl), bool)  # state -> the places it touches
    inc[np.arange(nl), np.arange(nl)] = True
    for j, e in enumerate(graph.edges):
        inc[nl + j, [e.source, e.target]] = True
    related: npt.NDArray[np.bool_] = (inc.astype(np.int64) @ inc.T.astype(np.int64)) > 0
    return related


def image_layout(graph: TourGraph) -> ImageLayout:
    """Where the images of ``graph`` are, as :mod:`server.vision.distinctiveness` takes it."""
    return ImageLayout(
        state=graph.image_state,
        along=graph.image_along,
        ends=graph.image_ends,
        n_place_images=graph.n_images - int(graph.edge_offsets[-1]),
        n_states=graph.n_states,
    )


def preferred(sims: tuple[Similarity, ...], summary: BeliefSummary) -> Similarity:
    """The similarity of the appearance model the belief now trusts most."""
    if len(summary.appearance) != len(sims):
        return sims[0]
    return sims[int(np.argmax(summary.appearance))]


def next_moving(v: FloatArray, w: FloatArray, eps: float = 1e-3) -> npt.NDArray[np.int64]:
    """``(n,)``: for each image, the first index at or after it with ``|v|`` or ``|w|`` above
    ``eps``, or -1 when none follows."""
    n = len(v)
    moving = (np.abs(v) > eps) | (np.abs(w) > eps)
    idx = np.where(moving, np.arange(n), n)
    nxt = np.minimum.accumulate(idx[::-1])[::-1]
    return np.where(nxt < n, nxt, -1).astype(np.int64)


FORWARD_V = 0.05
"""A taught image with a forward speed above this (m/s) was taken while driving forward."""


def _first_forward(v: FloatArray) -> int:
    """Index of the first image taught driving forward (0 when none was)."""
    forward = v > FORWARD_V
    return int(np.argmax(forward)) if np.any(forward) else 0


def _last_forward(v: FloatArray) -> int:
    """Index of the last image taught driving forward (0 when none was)."""
    forward = v > FORWARD_V
    return int(len(v) - 1 - np.argmax(forward[::-1])) if np.any(forward) else 0


def _at_locations(graph: TourGraph, model: BeliefModel) -> tuple[npt.NDArray[np.int64], ...]:
    """Fine states physically at each location: itself and the exit zones of edges into it."""
    at: list[list[int]] = [[k] for k in range(graph.n_locations)]
    for j, e in enumerate(graph.edges):
        end = graph.n_locations + int(graph.edge_offsets[j + 1])
        at[e.target].extend(range(end - int(model.exit_len[j]), end))
    return tuple(np.asarray(a, dtype=np.int64) for a in at)
