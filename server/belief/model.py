"""Transition model of the hierarchical POMDP (001 Sections 3.1 and 3.2), built from a tour graph.

The belief is one flat vector over the *fine states* of :mod:`server.domain` (each location,
then each image of each edge), so ``b(s)`` and ``b(i | e)`` are groupings of it.

One prediction step for action ``a`` is, in this order (001 Section 3.2):

1. **Structure** (upper layer): every fine state keeps its mass with a "stay" probability and
   sends the rest along graph relations (origin / target of an edge, edges leaving / entering a
   location, shared origin, shared destination, reverse edge). Mass entering an edge from a
   location lands uniformly on its first ``entry_fraction`` of images; mass entering from another
   edge spreads uniformly over it, except from the reverse edge, where it lands near the mirrored
   position (beyond 001: turning round mid-corridor does not teleport you to its start). Under
   ``Navigate`` mass in an edge's last ``exit_fraction`` of images moves into its target location;
   under ``RotateAndFindEdge`` mass in an edge's first images flows back to its origin (beyond
   001: a spinning robot faces an edge's start only for a moment).
2. **Motion** (lower layer): inside every edge, mass moves forward by the expected number of images
   ``advance`` (from the reported speed and the teaching timestamps, :func:`expected_advance`),
   spread by a small kernel; standing still (``advance == 0``) keeps it.
3. **Kidnap mixing**: a fraction ``teleport`` of the mass is redistributed like the prior (uniform
   over upper states, uniform inside edges), so recovery from a wrong belief is always possible.

Steps 1-2 are sparse (:meth:`TransitionOperator.apply` is two sparse mat-vecs); step 3 is a rank-1
term, so the explicit matrix from :meth:`BeliefModel.transition` leaves it out and
:meth:`BeliefModel.predict` adds it. Position-independent flows (uniform injection) are kept
factored through the upper states, so no ``(n_images_e x n_images_e')`` dense block is ever built.

Transition matrices are *row-stochastic*: ``T[s, s'] = tr(s, a, s')``; the prediction is
``b' = T.T @ b``.

This module imports NumPy, SciPy and :mod:`server.domain` only.
"""

from __future__ import annotations

import enum
import math
import threading
from collections import OrderedDict
from dataclasses import dataclass, fields
from typing import Literal

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp

from server.domain import TourGraph

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

__all__ = [
    "Action",
    "ActionKind",
    "BeliefModel",
    "TransitionOperator",
    "TransitionParams",
    "build_model",
    "expected_advance",
    "reverse_edges",
]


class ActionKind(enum.StrEnum):
    """The high-level commands of 001 Section 3.1 (a ``str`` enum: ``ActionKind("navigate")``)."""

    ROTATE_AND_FIND_EDGE = "rotate_and_find_edge"
    NAVIGATE = "navigate"
    EXPLORE = "explore"
    DO_NOTHING = "do_nothing"


@dataclass(frozen=True)
class Action:
    """An action with its parameter.

    ``edge`` is an index into ``graph.edges``: the edge to find for ``ROTATE_AND_FIND_EDGE``,
    the active edge for ``NAVIGATE`` (optional), ``None`` otherwise.
    """

    kind: ActionKind
    edge: int | None = None

    @classmethod
    def rotate(cls, edge: int) -> Action:
        return cls(ActionKind.ROTATE_AND_FIND_EDGE, edge)

    @classmethod
    def navigate(cls, edge: int | None = None) -> Action:
        return cls(ActionKind.NAVIGATE, edge)

    @classmethod
    def explore(cls) -> Action:
        return cls(ActionKind.EXPLORE)

    @classmethod
    def do_nothing(cls) -> Action:
        return cls(ActionKind.DO_NOTHING)


@dataclass(frozen=True)
class TransitionParams:
    """Every probability of the transition model, per step (one camera frame).

    Unless said otherwise a value is the probability, per step, that mass of one source state
    moves along one relation; a "total" is split uniformly among the targets of that relation
    (and stays put when there are none). Whatever a source does not send away stays where it is.
    Defaults are hand-tuned (001 Section 3.1 does the same) for ~2-10 frames per second.
    """

    # -- zones of an edge (fractions of its images, at least one image) --
    entry_fraction: float = 0.05
    """Mass entering an edge from its origin location lands on this first fraction (001 3.2)."""
    exit_fraction: float = 0.05
    """Under Navigate, mass in this last fraction of an edge may move into its target (001 7.2)."""

    # -- RotateAndFindEdge(g): spinning in place looking for edge g --
    rotate_loc_to_goal_edge: float = 0.03
    """Location -> the sought edge ``g`` when it leaves this location. 001 3.1 makes this larger
    than staying, which lets the spin itself push the belief into the edge; here the motion
    layer drives onto the edge only once the camera sees its start (then the action is
    Navigate), so spinning moves little mass. A large value also made look-alike places
    ping-pong: the action pulled mass out of whichever place it was acting on."""
    rotate_loc_to_other_edges: float = 0.02
    """Location -> its other outgoing edges (total)."""
    rotate_edge_to_goal: float = 0.4
    """Edge -> ``g`` when ``g`` is its reverse or shares its origin or destination."""
    rotate_edge_to_related: float = 0.05
    """Edge -> its other reverse / shared-origin / shared-destination edges (total)."""
    rotate_head_to_origin: float = 0.5
    """Edge image in the entry zone -> the edge's origin location (beyond 001): facing the start
    of an edge is a passing moment of a spin; rotating on turns away from it again. Without this
    a weak similarity engine lets a spinning robot's belief drift into the edge and Navigate."""

    # -- Navigate: drive forward along the edge --
    navigate_exit: float = 0.3
    """Edge image in the exit zone -> the edge's target location (001 7.2)."""
    navigate_loc_to_active_edge: float = 0.2
    """Location -> the active edge when it leaves this location."""
    navigate_loc_to_other_edges: float = 0.05
    """Location -> its other outgoing edges (total)."""
    navigate_dead_end: float = 0.2
    """Location without an outgoing edge -> everywhere, spread like the prior (total; beyond
    001). Driving on from where the tour ends leads somewhere it does not cover; without this,
    such a location keeps all its mass under Navigate and collects every stray bit of it (on
    Nordland the route's last location held the belief, wrongly, for up to 17 frames)."""
    navigate_edge_to_sibling: float = 0.01
    """Edge -> edges sharing its origin or its destination (total, spread uniformly)."""
    navigate_stall: float = 0.1
    """Probability that the robot did not advance this step (wheel slip, obstacle)."""

    # -- Explore: heuristic motion toward open space --
    explore_loc_to_out_edges: float = 0.1
    """Location -> its outgoing edges (total, entering at their first images)."""
    explore_loc_to_in_edges: float = 0.05
    """Location -> edges entering it (total, spread uniformly)."""
    explore_edge_to_endpoints: float = 0.1
    """Edge -> its origin and its target location (total)."""
    explore_edge_to_related: float = 0.05
    """Edge -> reverse / shared-origin / shared-destination edges (total)."""

    # -- lower layer (units: images) --
    advance_spread_rel: float = 0.2
    """Std of the forward-motion kernel per image of expected advance (images / image)."""
    advance_spread_abs: float = 0.3
    """Extra std (images) of the forward kernel once moving (scaled down for advance < 1)."""
    explore_spread: float = 1.0
    """Explore moves along an edge in either direction: kernel std = this x advance (images)."""
    reverse_spread_images: int = 2
    """Mass moved onto a reverse edge spreads over +- this many images around the mirror point."""
    advance_quantum: float = 0.05
    """The advance is rounded to this many images so motion matrices can be cached (0 = exact)."""
    turn_radius_m: float = 0.15
    """Turning counts as progress along an edge: the progress speed is ``|v| + r |w|`` (m/s),
    for the teaching run and the repeat alike. Without it an edge taught with turns on the spot
    (``v = 0``) would hold the belief still while the robot replays the turn."""

    # -- kidnapping --
    teleport: float = 1e-3
    """Every step this fraction of the mass is redistributed like the prior (kidnap recovery)."""

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in ("reverse_spread_images",):
                if int(value) < 0:
                    raise ValueError("reverse_spread_images must be >= 0")
                continue
            if not math.isfinite(value) or value < 0:
                raise ValueError(f"TransitionParams.{f.name} must be finite and >= 0, got {value}")
        probs = {
            "entry_fraction": self.entry_fraction,
            "exit_fraction": self.exit_fraction,
            "navigate_stall": self.navigate_stall,
            "teleport": self.teleport,
        }
        for name, value in probs.items():
            if value > 1:
                raise ValueError(f"TransitionParams.{name} must be <= 1, got {value}")
        totals = {
            "rotate (location)": self.rotate_loc_to_goal_edge + self.rotate_loc_to_other_edges,
            "rotate (edge)": self.rotate_edge_to_goal
            + self.rotate_edge_to_related
            + self.rotate_head_to_origin,
            "navigate (location)": self.navigate_loc_to_active_edge
            + self.navigate_loc_to_other_edges,
            "navigate (dead end)": self.navigate_dead_end,
            "navigate (edge)": self.navigate_exit + self.navigate_edge_to_sibling,
            "explore (location)": self.explore_loc_to_out_edges + self.explore_loc_to_in_edges,
            "explore (edge)": self.explore_edge_to_endpoints + self.explore_edge_to_related,
        }
        for name, total in totals.items():
            if total > 1 + 1e-12:
                raise ValueError(
                    f"outgoing probabilities of {name} sum to {total} > 1; lower them so that "
                    "a state keeps a non-negative probability of staying"
                )


# --------------------------------------------------------------------------------------------
# graph relations
# --------------------------------------------------------------------------------------------


def reverse_edges(graph: TourGraph) -> tuple[tuple[int, ...], ...]:
    """For every edge, the edges going the other way (target -> source) that have images."""
    by_pair: dict[tuple[int, int], list[int]] = {}
    for j, e in enumerate(graph.edges):
        if e.n_images > 0:
            by_pair.setdefault((e.source, e.target), []).append(j)
    return tuple(tuple(by_pair.get((e.target, e.source), ())) for e in graph.edges)


def _edge_distances(graph: TourGraph, turn_radius: float = 0.0) -> tuple[FloatArray, FloatArray]:
    """Per edge: progress metres (``|v| + turn_radius |w|``) per image and seconds per image
    of the teaching run (0 when unknown)."""
    mpi = np.zeros(graph.n_edges)
    spi = np.zeros(graph.n_edges)
    for j, e in enumerate(graph.edges):
        n = e.n_images
        if n < 2:
            continue
        t = np.asarray(e.timestamps, dtype=np.float64)
        v = np.asarray(e.v, dtype=np.float64)
        if len(t) != n:
            continue
        dts = np.diff(t)
        dts = np.where(np.isfinite(dts) & (dts > 0), dts, 0.0)
        spi[j] = float(dts.sum()) / (n - 1)
        if len(v) == n:
            speed = np.abs(np.where(np.isfinite(v[:-1]), v[:-1], 0.0))
            w = np.asarray(e.w, dtype=np.float64)
            if turn_radius > 0 and len(w) == n:
                speed = speed + turn_radius * np.abs(np.where(np.isfinite(w[:-1]), w[:-1], 0.0))
            mpi[j] = float((speed * dts).sum()) / (n - 1)
    return mpi, spi


def _advance_from(mpi: FloatArray, spi: FloatArray, v: float, dt: float) -> FloatArray:
    out = np.zeros(len(mpi))
    if not (math.isfinite(dt) and dt > 0):
        return out
    speed_known = math.isfinite(v)
    speed = abs(v) if speed_known else 0.0
    by_dist = mpi > 0
    out[by_dist] = speed * dt / mpi[by_dist]
    by_time = ~by_dist & (spi > 0)
    if not speed_known or speed > 0:
        out[by_time] = dt / spi[by_time]
    return out


def expected_advance(
    graph: TourGraph, *, v: float, dt: float, w: float = 0.0, turn_radius: float = 0.0
) -> FloatArray:
    """Expected forward motion along every edge this step, in images.

    ``v`` is the current forward speed (m/s, its magnitude is used; ``nan`` = unknown) and
    ``dt`` the time since the previous frame (s). For an edge whose teaching run recorded a speed,
    the advance is ``|v| * dt / metres_per_image`` with ``metres_per_image = sum(v_k * dt_k) /
    (n - 1)`` over the teaching timestamps. When the teaching speed is unknown or zero the advance
    is time based, ``dt / seconds_per_image``, unless the robot reports ``v == 0`` (stopped).
    Edges with fewer than two images, or without usable timestamps, get 0.

    With ``turn_radius`` > 0, turning counts as progress: ``|v|`` becomes ``|v| + turn_radius
    |w|`` here and in the teaching run (see :attr:`TransitionParams.turn_radius_m`).

    Returns ``(n_edges,) float64 >= 0``.
    """
    mpi, spi = _edge_distances(graph, turn_radius)
    speed = abs(float(v)) + turn_radius * abs(float(w)) if math.isfinite(v) else float(v)
    return _advance_from(mpi, spi, speed, float(dt))


# --------------------------------------------------------------------------------------------
# the factored transition operator
# --------------------------------------------------------------------------------------------

MotionKind = Literal["none", "forward", "symmetric"]


@dataclass(frozen=True)
class _Structure:
    """Upper-layer part of one action (advance-independent, cached per action).

    ``forward`` is ``(n_fine, n_fine + n_states)``: ``x = forward @ concat(b, A @ b)`` where
    ``A @ b`` is the upper-state mass. ``local`` (``(n_fine, n_fine)``, row = source) holds the
    position-dependent moves and the stays; ``flow`` (``(n_states, n_fine)``) is the upper-level
    flows composed with their injection patterns, so that ``T_struct = local + A.T @ flow``.
    """

    local: sp.csr_array
    flow: sp.csr_array
    forward: sp.csr_array
    motion: MotionKind


@dataclass(frozen=True)
class _Motion:
    """Lower-layer motion for one quantised advance: ``(n_edge_images, n_edge_images)``.

    ``to_target`` is ``M.T`` in CSR (row = target image), so ``x_edge' = to_target @ x_edge``;
    ``M`` (row-stochastic, row = source) is ``to_target.T``. ``weights`` is the ``(n_edges, K)``
    kernel over offsets ``lo .. lo + K - 1`` images.
    """

    to_target: sp.csr_array
    weights: FloatArray
    lo: int


@dataclass(frozen=True)
class TransitionOperator:
    """The sparse part of one prediction step (structure, then motion), in factored form.

    Apply with :meth:`apply` (``b -> T.T @ b``) or :meth:`apply_transpose` (``x -> T @ x``, for
    smoothing); :meth:`to_csr` builds the explicit ``(n_fine, n_fine)`` row-stochastic matrix.
    Teleport mixing is not included (see :meth:`BeliefModel.predict`).
    """

    model: BeliefModel
    structure: _Structure
    motion: _Motion | None

    def apply(self, belief: FloatArray) -> FloatArray:
        """``(n_fine,) -> (n_fine,)``: mass after this step, ``T.T @ belief``."""
        m = self.model
        b = np.asarray(belief, dtype=np.float64)
        x = self.structure.forward @ np.concatenate([b, m.upper_mass(b)])
        if self.motion is not None:
            L = m.n_locations
            x[L:] = self.motion.to_target @ x[L:]
        return np.asarray(x, dtype=np.float64)

    def apply_transpose(self, x: FloatArray) -> FloatArray:
        """``(n_fine,) -> (n_fine,)``: ``T @ x`` (the backward message of a smoother)."""
        m = self.model
        y = np.array(x, dtype=np.float64)
        if self.motion is not None:
            L = m.n_locations
            y[L:] = self.motion.to_target.T @ y[L:]
        s = self.structure
        out = s.local @ y + (s.flow @ y)[m.fine_state]
        return np.asarray(out, dtype=np.float64)

    def to_csr(self) -> sp.csr_array:
        """Explicit ``(n_fine, n_fine)`` row-stochastic matrix ``T[s, s']`` (may be large)."""
        m = self.model
        s = self.structure
        struct = sp.csr_array(s.local + m.aggregate.T @ s.flow)
        if self.motion is not None:
            full = sp.block_diag([sp.identity(m.n_locations), self.motion.to_target.T], "csr")
            struct = sp.csr_array(struct @ full)
        struct.sum_duplicates()
        struct.eliminate_zeros()
        return struct


class BeliefModel:
    """Transition model of one tour graph; build once per graph, reuse for every step.

    ``BeliefModel(graph, params)``. Attributes: ``n_fine``, ``n_states``, ``fine_state``
    (``(n_fine,)`` upper state of each fine state), ``prior`` (``(n_fine,)``, sums to 1),
    ``reverse`` (reverse edges of every edge), ``valid_edge`` (edges with images).
    Edges with no images have no fine states; the model never moves mass into them.
    """

    MOTION_CACHE = 16
    """How many lower-layer motion matrices (one per quantised advance) are kept."""
    STRUCTURE_CACHE = 16
    """How many per-action structure matrices are kept (~2 MB each at 10 000 images)."""
    # motion matrices are ~1 MB each at 10 000 images

    def __init__(self, graph: TourGraph, params: TransitionParams | None = None) -> None:
        self.graph = graph
        self.params = params if params is not None else TransitionParams()
        p = self.params
        self.n_locations = graph.n_locations
        self.n_edges = graph.n_edges
        self.n_states = graph.n_states
        self.n_fine = graph.n_fine
        self.fine_state: IntArray = np.asarray(graph.fine_state, dtype=np.int64)
        self.offsets: IntArray = np.asarray(graph.edge_offsets, dtype=np.int64)
        self.edge_len: IntArray = np.diff(self.offsets)
        self.valid_edge = self.edge_len > 0
        self.n_edge_images = int(self.offsets[-1])
        # per edge-image row (rows of the edge part of the fine vector)
        self.row_edge: IntArray = self.fine_state[self.n_locations :] - self.n_locations
        self.row_pos: IntArray = (
            np.arange(self.n_edge_images, dtype=np.int64) - self.offsets[self.row_edge]
        )
        self.head_len: IntArray = np.maximum(
            1, np.ceil(p.entry_fraction * self.edge_len - 1e-9).astype(np.int64)
        )
        self.head_len = np.minimum(self.head_len, np.maximum(self.edge_len, 1))
        self.exit_len: IntArray = np.maximum(
            1, np.ceil(p.exit_fraction * self.edge_len - 1e-9).astype(np.int64)
        )
        self._valid_idx: IntArray = np.flatnonzero(self.valid_edge).astype(np.int64)
        self._valid_starts: IntArray = self.offsets[self._valid_idx]
        # relations
        self.reverse = reverse_edges(graph)
        valid = [j for j in range(self.n_edges) if self.valid_edge[j]]
        self.out_edges: tuple[tuple[int, ...], ...] = tuple(
            tuple(j for j in valid if graph.edges[j].source == k) for k in range(self.n_locations)
        )
        self.in_edges: tuple[tuple[int, ...], ...] = tuple(
            tuple(j for j in valid if graph.edges[j].target == k) for k in range(self.n_locations)
        )
        self.shared_origin: tuple[tuple[int, ...], ...] = tuple(
            tuple(i for i in self.out_edges[e.source] if i != j) for j, e in enumerate(graph.edges)
        )
        self.shared_destination: tuple[tuple[int, ...], ...] = tuple(
            tuple(i for i in self.in_edges[e.target] if i != j) for j, e in enumerate(graph.edges)
        )
        # aggregation (n_states, n_fine) and the prior
        self.aggregate = sp.csr_array(
            (np.ones(self.n_fine), (self.fine_state, np.arange(self.n_fine))),
            shape=(self.n_states, self.n_fine),
        )
        state_ok = np.concatenate([np.ones(self.n_locations, bool), self.valid_edge])
        n_ok = int(state_ok.sum())
        if n_ok == 0:
            raise ValueError("the tour graph has no locations and no edges with images")
        per_state = np.where(state_ok, 1.0 / n_ok, 0.0)
        sizes = np.concatenate([np.ones(self.n_locations), np.maximum(self.edge_len, 1)])
        self.prior: FloatArray = (per_state / sizes)[self.fine_state]
        self.n_valid_states = n_ok
        self._valid_states: IntArray = np.flatnonzero(state_ok).astype(np.int64)
        # teaching-run distances per image
        self.metres_per_image, self.seconds_per_image = _edge_distances(
            graph, self.params.turn_radius_m
        )
        # caches
        self._structures: OrderedDict[Action, _Structure] = OrderedDict()
        self._lock = threading.Lock()  # caches are shared by the robots of one tour
        self._motions: OrderedDict[tuple[str, bytes], _Motion] = OrderedDict()
        self._patterns: dict[tuple[int, int], tuple[IntArray, IntArray, IntArray]] = {}
        self._explicit: OrderedDict[tuple[Action, bytes], sp.csr_array] = OrderedDict()

    # ---------------------------------------------------------------- public API

    def upper_mass(self, belief: FloatArray) -> FloatArray:
        """``(n_fine,) -> (n_states,)``: mass of every upper state, ``b(s)`` (segment sums)."""
        L = self.n_locations
        out = np.zeros(self.n_states)
        out[:L] = belief[:L]
        if self._valid_idx.size:
            out[L + self._valid_idx] = np.add.reduceat(belief[L:], self._valid_starts)
        return out

    def expected_advance(self, *, v: float, dt: float, w: float = 0.0) -> FloatArray:
        """Like :func:`expected_advance`, from cached per-edge distances. ``(n_edges,)`` images."""
        return _advance_from(
            self.metres_per_image, self.seconds_per_image, self.progress_speed(v, w), float(dt)
        )

    def progress_speed(self, v: float, w: float = 0.0) -> float:
        """``|v| + turn_radius_m |w|`` (m/s); ``nan`` stays ``nan`` (speed unknown)."""
        if not math.isfinite(v):
            return float(v)
        return abs(float(v)) + self.params.turn_radius_m * abs(float(w))

    def operator(
        self, action: Action, *, advance: float | npt.ArrayLike = 0.0
    ) -> TransitionOperator:
        """The factored sparse transition of ``action`` with ``advance`` images per edge.

        ``advance`` is a scalar or ``(n_edges,)`` (images moved forward this step, >= 0).
        """
        self._check_action(action)
        structure = self._structure(action)
        return TransitionOperator(self, structure, self._motion(structure.motion, advance))

    def warm_up(self, actions: tuple[Action, ...] | None = None) -> None:
        """Build the structure of ``actions`` now (default: DoNothing, Explore, Navigate()), so
        the first frames after a tour is loaded do not pay the ~10 ms build at 10 000 images."""
        default = (Action.do_nothing(), Action.explore(), Action.navigate())
        for action in actions if actions is not None else default:
            self._check_action(action)
            self._structure(action)

    def transition(self, action: Action, *, advance: float | npt.ArrayLike = 0.0) -> sp.csr_array:
        """Explicit ``(n_fine, n_fine)`` row-stochastic matrix ``T[s, s'] = tr(s, a, s')``.

        Without the teleport term. Cached (LRU of 32) per action and exact advance. Meant for
        tests, inspection and small graphs; the tracker uses :meth:`predict` (factored, faster).
        """
        adv = np.broadcast_to(np.asarray(advance, dtype=np.float64), (self.n_edges,))
        key = (action, adv.tobytes())
        with self._lock:
            hit = self._explicit.get(key)
            if hit is not None:
                self._explicit.move_to_end(key)
                return hit
        mat = self.operator(action, advance=adv).to_csr()
        with self._lock:
            self._explicit[key] = mat
            if len(self._explicit) > 32:
                self._explicit.popitem(last=False)
        return mat

    def predict(
        self,
        belief: npt.ArrayLike,
        action: Action,
        *,
        advance: float | npt.ArrayLike = 0.0,
        teleport: float | None = None,
    ) -> FloatArray:
        """One full prediction: ``(1 - eps) * T.T @ b + eps * prior``, eps = ``teleport``.

        ``teleport`` defaults to ``params.teleport``. Returns a new ``(n_fine,)`` array.
        """
        eps = self.params.teleport if teleport is None else float(teleport)
        x = self.operator(action, advance=advance).apply(np.asarray(belief, dtype=np.float64))
        return mix_prior(x, self.prior, eps)

    # ---------------------------------------------------------------- structure

    def _check_action(self, action: Action) -> None:
        if not isinstance(action.kind, ActionKind):
            raise ValueError(f"unknown action kind {action.kind!r}")
        if action.edge is not None and not 0 <= action.edge < self.n_edges:
            raise ValueError(
                f"action edge {action.edge} is not an edge index of this graph "
                f"(0..{self.n_edges - 1})"
            )
        if action.kind is ActionKind.ROTATE_AND_FIND_EDGE and action.edge is None:
            raise ValueError("RotateAndFindEdge needs the edge to find (Action.rotate(edge))")

    def _structure(self, action: Action) -> _Structure:
        key = action
        if action.kind in (ActionKind.EXPLORE, ActionKind.DO_NOTHING):
            key = Action(action.kind)
        with self._lock:
            s = self._structures.get(key)
            if s is not None:
                self._structures.move_to_end(key)
                return s
        s = self._build_structure(key)
        with self._lock:
            self._structures[key] = s
            if len(self._structures) > self.STRUCTURE_CACHE:
                self._structures.popitem(last=False)
        return s

    def _location_moves(self, action: Action, k: int) -> list[tuple[int, float, str]]:
        """(target upper state, probability, "head" | "uniform") moves of location ``k``."""
        p = self.params
        L = self.n_locations
        outs = self.out_edges[k]
        moves: list[tuple[int, float, str]] = []

        def split(targets: tuple[int, ...] | list[int], total: float, mode: str) -> None:
            if targets and total > 0:
                for j in targets:
                    moves.append((L + j, total / len(targets), mode))

        kind = action.kind
        if kind is ActionKind.ROTATE_AND_FIND_EDGE or kind is ActionKind.NAVIGATE:
            if kind is ActionKind.ROTATE_AND_FIND_EDGE:
                to_goal, to_other = p.rotate_loc_to_goal_edge, p.rotate_loc_to_other_edges
            else:
                to_goal, to_other = p.navigate_loc_to_active_edge, p.navigate_loc_to_other_edges
            g = action.edge
            if g is not None and g in outs:
                moves.append((L + g, to_goal, "head"))
                split([j for j in outs if j != g], to_other, "head")
            else:
                split(outs, to_other, "head")
            if kind is ActionKind.NAVIGATE and not outs and p.navigate_dead_end > 0:
                # a dead end: the mass that drives on goes anywhere, like the prior
                valid = self._valid_states
                moves.extend((int(s), p.navigate_dead_end / len(valid), "uniform") for s in valid)
        elif kind is ActionKind.EXPLORE:
            split(outs, p.explore_loc_to_out_edges, "head")
            split(self.in_edges[k], p.explore_loc_to_in_edges, "uniform")
        return moves

    def _edge_moves(
        self, action: Action, j: int
    ) -> tuple[list[tuple[int, float]], list[tuple[int, float]], float]:
        """Moves of edge ``j``: (uniform [(state, prob)], mirror [(edge, prob)], exit prob)."""
        p = self.params
        L = self.n_locations
        e = self.graph.edges[j]
        revs = self.reverse[j]
        sibs = tuple(dict.fromkeys(self.shared_origin[j] + self.shared_destination[j]))
        sibs = tuple(i for i in sibs if i not in revs)
        uniform: list[tuple[int, float]] = []
        mirror: list[tuple[int, float]] = []
        exit_p = 0.0

        def send(targets: list[int], total: float) -> None:
            """Split ``total`` evenly over edge ``targets``: onto a reverse edge near the mirrored
            image, onto any other edge uniformly."""
            for i in targets:
                if i in revs:
                    mirror.append((i, total / len(targets)))
                else:
                    uniform.append((L + i, total / len(targets)))

        kind = action.kind
        if kind is ActionKind.ROTATE_AND_FIND_EDGE:
            g = -1 if action.edge is None else action.edge
            related = list(revs) + list(sibs)
            if g in related:
                send([g], p.rotate_edge_to_goal)
            send([i for i in related if i != g], p.rotate_edge_to_related)
        elif kind is ActionKind.NAVIGATE:
            exit_p = p.navigate_exit
            if p.navigate_edge_to_sibling > 0:
                send(list(sibs), p.navigate_edge_to_sibling)
        elif kind is ActionKind.EXPLORE:
            ends = [e.source, e.target] if e.source != e.target else [e.source]
            uniform.extend((k, p.explore_edge_to_endpoints / len(ends)) for k in ends)
            send(list(revs) + list(sibs), p.explore_edge_to_related)
        return uniform, mirror, exit_p

    def _build_structure(self, action: Action) -> _Structure:
        L, S, F = self.n_locations, self.n_states, self.n_fine
        rows: list[IntArray] = []
        cols: list[IntArray] = []
        vals: list[FloatArray] = []
        flow_rows: list[int] = []
        flow_cols: list[int] = []
        flow_vals: list[float] = []
        # pattern (state -> fine) of "head" and "uniform" injection, per target state
        stay = np.ones(F)

        def inject(src_state: int, dst_state: int, prob: float, mode: str) -> None:
            if prob <= 0:
                return
            if dst_state < L:
                flow_rows.append(src_state)
                flow_cols.append(dst_state)
                flow_vals.append(prob)
                return
            j = dst_state - L
            start = L + int(self.offsets[j])
            n = int(self.head_len[j]) if mode == "head" else int(self.edge_len[j])
            flow_rows.extend([src_state] * n)
            flow_cols.extend(range(start, start + n))
            flow_vals.extend([prob / n] * n)

        for k in range(L):
            for dst, prob, mode in self._location_moves(action, k):
                inject(k, dst, prob, mode)
                stay[k] -= prob
        for j in range(self.n_edges):
            n = int(self.edge_len[j])
            if n == 0:
                continue
            start = L + int(self.offsets[j])
            uniform, mirror, exit_p = self._edge_moves(action, j)
            for dst, prob in uniform:
                inject(L + j, dst, prob, "uniform")
                stay[start : start + n] -= prob
            for r, prob in mirror:
                rr, cc, vv = self._mirror_block(j, r, prob)
                rows.append(rr)
                cols.append(cc)
                vals.append(vv)
                stay[start : start + n] -= prob
            if exit_p > 0:
                ne = int(self.exit_len[j])
                ex_rows = np.arange(start + n - ne, start + n, dtype=np.int64)
                rows.append(ex_rows)
                cols.append(np.full(ne, self.graph.edges[j].target, dtype=np.int64))
                vals.append(np.full(ne, exit_p))
                stay[ex_rows] -= exit_p
            back = self.params.rotate_head_to_origin
            if action.kind is ActionKind.ROTATE_AND_FIND_EDGE and back > 0:
                nh = int(self.head_len[j])
                hd_rows = np.arange(start, start + nh, dtype=np.int64)
                rows.append(hd_rows)
                cols.append(np.full(nh, self.graph.edges[j].source, dtype=np.int64))
                vals.append(np.full(nh, back))
                stay[hd_rows] -= back
        if np.any(stay < -1e-9):
            raise ValueError("transition probabilities of a state sum to more than 1")
        stay = np.clip(stay, 0.0, 1.0)
        rows.append(np.arange(F, dtype=np.int64))
        cols.append(np.arange(F, dtype=np.int64))
        vals.append(stay)
        local = sp.csr_array(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(F, F)
        )
        local.sum_duplicates()
        flow = sp.csr_array(
            (np.asarray(flow_vals, dtype=np.float64), (flow_rows, flow_cols)), shape=(S, F)
        )
        flow.sum_duplicates()
        # x = local.T @ b + flow.T @ (A @ b)  ==  [local.T | flow.T] @ [b; A b]
        forward = sp.csr_array(sp.hstack([local.T, flow.T], format="csr"))
        motion: MotionKind = "none"
        if action.kind is ActionKind.NAVIGATE:
            motion = "forward"
        elif action.kind is ActionKind.EXPLORE:
            motion = "symmetric"
        return _Structure(local=local, flow=flow, forward=forward, motion=motion)

    def _mirror_block(self, j: int, r: int, prob: float) -> tuple[IntArray, IntArray, FloatArray]:
        """Entries moving mass from edge ``j`` to its reverse ``r`` near the mirrored image."""
        L = self.n_locations
        n, nr = int(self.edge_len[j]), int(self.edge_len[r])
        pos = np.arange(n, dtype=np.float64)
        frac = pos / (n - 1) if n > 1 else np.full(n, 0.5)
        centre = np.rint((1.0 - frac) * (nr - 1)).astype(np.int64)
        h = max(int(self.params.reverse_spread_images), math.ceil(0.5 * nr / n) - 1, 0)
        taps = np.arange(-h, h + 1, dtype=np.int64)
        cols = np.clip(centre[:, None] + taps[None, :], 0, nr - 1) + L + int(self.offsets[r])
        rows = np.repeat(np.arange(n, dtype=np.int64) + L + int(self.offsets[j]), len(taps))
        vals = np.full(rows.shape, prob / len(taps))
        return rows, cols.ravel(), vals

    # ---------------------------------------------------------------- lower-layer motion

    def _motion_weights(
        self, motion: MotionKind, advance: float | npt.ArrayLike
    ) -> tuple[FloatArray | None, int]:
        """Kernel ``(n_edges, K)`` over offsets ``lo .. lo + K - 1`` (images), or None."""
        if motion == "none" or self.n_edges == 0:
            return None, 0
        a = np.broadcast_to(np.asarray(advance, dtype=np.float64), (self.n_edges,))
        if not np.all(np.isfinite(a)):
            raise ValueError("advance must be finite (images per step)")
        a = np.maximum(a, 0.0)
        if not np.any(a > 0):
            return None, 0
        p = self.params
        if motion == "forward":
            sigma = p.advance_spread_rel * a + p.advance_spread_abs * np.minimum(a, 1.0)
            base = np.floor(a)
            frac = a - base
            reach = np.ceil(3.0 * sigma)
            lo = min(0, int(np.min(base - reach)))
            hi = max(1, int(np.max(base + 1 + reach)))
            d = np.arange(lo, hi + 1, dtype=np.float64)[None, :]
            w = (1.0 - frac)[:, None] * _gauss(d - base[:, None], sigma) + frac[:, None] * _gauss(
                d - base[:, None] - 1.0, sigma
            )
            stall = np.zeros_like(d)
            stall[0, -lo] = 1.0
            w = (1.0 - p.navigate_stall) * w + p.navigate_stall * stall
        else:
            sigma = p.explore_spread * a
            reach = np.ceil(3.0 * sigma)
            lo = -int(np.max(reach))
            d = np.arange(lo, -lo + 1, dtype=np.float64)[None, :]
            w = _gauss(d, sigma)
        return np.ascontiguousarray(w), lo

    def _motion_pattern(self, lo: int, k: int) -> tuple[IntArray, IntArray, IntArray]:
        """Target-oriented CSR pattern of the motion with offsets ``lo .. lo + k - 1``.

        Returns ``(indices, indptr, widx)``: row ``i`` (target image) takes mass from source
        images ``indices[indptr[i]:indptr[i + 1]]`` with weights ``W.ravel()[widx[...]]`` where
        ``W`` is the ``(n_edges, k)`` kernel. Offsets past an edge's ends clip to its first / last
        image (duplicate entries, summed by the mat-vec). Cached per ``(lo, k)``.
        """
        key = (lo, k)
        with self._lock:
            hit = self._patterns.get(key)
        if hit is not None:
            return hit
        n = self.n_edge_images
        taps = np.arange(lo, lo + k, dtype=np.int64)
        last = self.edge_len[self.row_edge] - 1
        pos = np.clip(self.row_pos[:, None] + taps[None, :], 0, last[:, None])
        tgt = (pos + self.offsets[self.row_edge][:, None]).ravel()
        src = np.repeat(np.arange(n, dtype=np.int64), k)
        widx = (self.row_edge[:, None] * k + np.arange(k)[None, :]).ravel()
        order = np.lexsort((src, tgt))
        indptr = np.concatenate([[0], np.cumsum(np.bincount(tgt, minlength=n))]).astype(np.int64)
        pattern = (src[order], indptr, widx[order])
        with self._lock:
            self._patterns[key] = pattern
            if len(self._patterns) > 8:
                self._patterns.pop(next(iter(self._patterns)))
        return pattern

    def _motion(self, motion: MotionKind, advance: float | npt.ArrayLike) -> _Motion | None:
        """The cached motion for ``advance`` quantised to ``advance_quantum`` images."""
        if motion == "none" or self.n_edges == 0:
            return None
        a = np.broadcast_to(np.asarray(advance, dtype=np.float64), (self.n_edges,))
        if not np.all(np.isfinite(a)):
            raise ValueError("advance must be finite (images per step)")
        q = self.params.advance_quantum
        steps = np.rint(np.maximum(a, 0.0) / q).astype(np.int64) if q > 0 else None
        if steps is not None and not np.any(steps):
            return None
        key = (motion, steps.tobytes() if steps is not None else a.tobytes())
        with self._lock:
            hit = self._motions.get(key)
            if hit is not None:
                self._motions.move_to_end(key)
                return hit
        aq = steps * q if steps is not None else np.maximum(a, 0.0)
        weights, lo = self._motion_weights(motion, aq)
        if weights is None:
            return None
        k = weights.shape[1]
        indices, indptr, widx = self._motion_pattern(lo, k)
        n = self.n_edge_images
        to_target = sp.csr_array((weights.ravel()[widx], indices, indptr), shape=(n, n))
        out = _Motion(to_target=to_target, weights=weights, lo=lo)
        with self._lock:
            self._motions[key] = out
            if len(self._motions) > self.MOTION_CACHE:
                self._motions.popitem(last=False)
        return out


def _gauss(d: FloatArray, sigma: FloatArray) -> FloatArray:
    """Discrete Gaussian over integer offsets ``d``, one row per ``sigma``.

    Truncated at ``|d| <= ceil(3 sigma)`` and normalised per row; a delta at 0 when sigma ~ 0.
    """
    s = np.asarray(sigma, dtype=np.float64)[:, None]
    safe = np.where(s > 1e-6, s, 1.0)
    inside = np.abs(d) <= np.ceil(3.0 * s)
    w = np.where(
        s > 1e-6, np.where(inside, np.exp(-0.5 * (d / safe) ** 2), 0.0), (np.abs(d) < 0.5) * 1.0
    )
    out: FloatArray = w / w.sum(axis=1, keepdims=True)
    return out


def mix_prior(x: FloatArray, prior: FloatArray, eps: float) -> FloatArray:
    """``(1 - eps) * x + eps * sum(x) * prior``: kidnap mixing that preserves total mass."""
    if eps <= 0:
        return x
    total = float(x.sum())
    out: FloatArray = (1.0 - eps) * x + (eps * total) * prior
    return out


def build_model(graph: TourGraph, params: TransitionParams | None = None) -> BeliefModel:
    """Build the transition model of ``graph`` (same as ``BeliefModel(graph, params)``)."""
    return BeliefModel(graph, params)
