"""Active disambiguation (seed 000, section VI): when the belief holds two or more separated
hypotheses, prefer the action whose expected next views tell them apart.

Mariottini & Roumeliotis move the robot along the least ambiguous path and let new views
decide between the candidate start places (and go back when the chosen one proves wrong). Here,
per frame, only when the belief is split:

1. **Hypotheses** (:func:`hypotheses`): the upper states holding at least ``floor`` of the
   belief, grouped into clusters of graph neighbours (a place and the edges at it are one
   region); clusters with at least ``min_mass`` are the hypotheses. Fewer than two, or one with
   ``max_leader`` or more: nothing to separate.
2. **Candidates**: the action the votes chose, and what the most likely state of each
   hypothesis can do: at a place, ``RotateAndFindEdge(e)`` for every edge leaving it; on an
   edge, ``Navigate`` on along it or ``RotateAndFindEdge`` onto its reverse edge; at most
   ``max_candidates``, those within ``max_detour_s`` of the expected extra time to the goal of
   the chosen action (:func:`detour`).
3. **Expected views**: each hypothesis' share of the belief is moved ``horizon_s`` ahead under the
   candidate, as the motion layer carries it out (:func:`next_views`, at ``speed_mps``); the
   view a robot would see where hypothesis h went is scored against where every hypothesis h'
   went, with the similarity profiles of the taught images
   (:mod:`server.vision.distinctiveness`): ``L[h, h'] = sum_s q_h(s) P[s] . u_h'``
   (:func:`view_likelihood`).
4. **Expected entropy** over the hypotheses after seeing those views
   (:func:`expected_entropy`, views weighted as ``sharpness`` frames of evidence); the candidate
   with the lowest wins if it beats the chosen action by at least ``min_gain`` nats.

Going back when the chosen hypothesis proves wrong needs nothing here: the belief moves, and the
votes of 001 section 7 turn the robot round on the edge it took.

This module imports NumPy, SciPy and the core only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from server.belief.model import Action, ActionKind, BeliefModel
from server.domain import TourGraph
from server.policy.costs import CostParams, edge_costs
from server.policy.voting import ROTATE0, VotePlan

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

__all__ = [
    "DisambiguationParams",
    "Hypotheses",
    "Separation",
    "adjacency",
    "detour",
    "disambiguate",
    "expected_entropy",
    "fine_profiles",
    "hypotheses",
    "next_views",
    "view_likelihood",
]


@dataclass(frozen=True)
class DisambiguationParams:
    """When and how the policy acts to separate hypotheses.

    * ``floor`` (0.02): upper states with less belief than this belong to no hypothesis.
    * ``min_mass`` (0.15): a cluster needs this much belief to be a hypothesis.
    * ``max_leader`` (0.75): a hypothesis holding this much or more is trusted: no separating.
    * ``horizon_s`` (4 s) and ``speed_mps`` (0.25 m/s): how far ahead the next views are
      predicted, at what speed (the motion layer's cruising speed).
    * ``sharpness`` (4): the expected views count as this many frames of evidence (as in
      ``DistinctivenessParams.sharpness``).
    * ``min_gain`` (0.1 nats): a candidate replaces the voted action only when its expected
      entropy is at least this much lower.
    * ``max_detour_s`` (20 s): a candidate may cost at most this many expected seconds to the
      goal more than the voted action (the bounded detour).
    * ``max_candidates`` (8): at most this many actions are weighed per frame (the least
      detour first).
    * ``match`` (0.5): a robot looking for an edge at another place drives off along that
      place's edge that looks at least this much like the edge's departure view
      (:func:`next_views`).
    """

    floor: float = 0.02
    min_mass: float = 0.15
    max_leader: float = 0.75
    horizon_s: float = 4.0
    speed_mps: float = 0.25
    sharpness: float = 4.0
    min_gain: float = 0.1
    max_detour_s: float = 20.0
    max_candidates: int = 8
    match: float = 0.5

    def __post_init__(self) -> None:
        if not 0 < self.min_mass <= self.max_leader <= 1 or not 0 <= self.floor < self.min_mass:
            raise ValueError("need 0 <= floor < min_mass <= max_leader <= 1")
        if self.max_candidates < 1:
            raise ValueError("max_candidates must be at least 1")
        if not 0 <= self.match <= 1:
            raise ValueError("match must lie in [0, 1]")
        for name in ("horizon_s", "speed_mps", "sharpness", "min_gain", "max_detour_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"DisambiguationParams.{name} must be finite and >= 0")


@dataclass(frozen=True)
class Hypotheses:
    """Separated regions of the belief: ``states[h]`` the upper states of hypothesis ``h``
    (most likely first), ``mass`` ``(H,)`` the belief each holds."""

    states: tuple[IntArray, ...]
    mass: FloatArray

    @property
    def leaders(self) -> tuple[tuple[int, float], ...]:
        """``(most likely state, hypothesis mass)`` of each hypothesis, most likely first."""
        return tuple((int(s[0]), float(m)) for s, m in zip(self.states, self.mass, strict=True))


@dataclass(frozen=True)
class Separation:
    """What :func:`disambiguate` found: the hypotheses, the action that separates them best,
    its expected entropy and that of the voted action (nats), and whether it differs from the
    voted action."""

    hypotheses: Hypotheses
    action: Action
    expected_entropy: float
    voted_entropy: float
    separating: bool


def adjacency(graph: TourGraph) -> sp.csr_array:
    """``(n_states, n_states)`` symmetric: a location and every edge at it are neighbours."""
    L = graph.n_locations
    rows: list[int] = []
    cols: list[int] = []
    for j, e in enumerate(graph.edges):
        for k in (e.source, e.target):
            rows += [k, L + j]
            cols += [L + j, k]
    n = graph.n_states
    return sp.csr_array((np.ones(len(rows)), (rows, cols)), shape=(n, n))


def hypotheses(
    state_mass: npt.ArrayLike,
    neighbours: sp.csr_array,
    *,
    floor: float = 0.02,
    min_mass: float = 0.15,
) -> Hypotheses:
    """The separated hypotheses of ``(n_states,)`` ``state_mass`` (sums to 1): connected
    components of the states with at least ``floor`` under ``neighbours``
    (:func:`adjacency`), those with at least ``min_mass``, most likely first."""
    b = np.asarray(state_mass, dtype=np.float64)
    live = np.flatnonzero(b >= floor)
    if len(live) == 0:
        return Hypotheses((), np.zeros(0))
    sub = neighbours[live][:, live]
    n, label = connected_components(sub, directed=False)
    mass = np.bincount(label, weights=b[live], minlength=n)
    keep = [c for c in np.argsort(-mass, kind="stable") if mass[c] >= min_mass]
    states = []
    for c in keep:
        members = live[label == c]
        states.append(members[np.argsort(-b[members], kind="stable")].astype(np.int64))
    return Hypotheses(tuple(states), mass[keep].astype(np.float64))


def expected_entropy(
    prior: npt.ArrayLike, likelihood: npt.ArrayLike, *, sharpness: float = 1.0
) -> float:
    """Expected entropy (nats) of the belief over ``H`` hypotheses after the next views.

    ``prior`` is ``(H,)`` (normalised here); ``likelihood`` ``(H, H)``: ``[h, h']`` how well
    the view seen when ``h`` is true fits hypothesis ``h'`` (>= 0). The view counts as
    ``sharpness`` frames: ``post_h(h') ~ prior(h') L[h, h'] ** sharpness``. Returns
    ``sum_h prior(h) H(post_h)``; equal to ``H(prior)`` when every row of ``L`` is constant.
    """
    p = np.asarray(prior, dtype=np.float64)
    p = p / p.sum()
    lik = np.asarray(likelihood, dtype=np.float64) ** sharpness
    post = p[None, :] * lik
    total = post.sum(axis=1, keepdims=True)
    post = np.divide(post, total, out=np.tile(p, (len(p), 1)), where=total > 0)
    logp = np.log(post, out=np.zeros_like(post), where=post > 0)
    return float(p @ -(post * logp).sum(axis=1))


def view_likelihood(
    predicted: npt.ArrayLike, fine_profile: npt.ArrayLike, fine_state: npt.ArrayLike
) -> FloatArray:
    """``(H, H)`` likelihood of each hypothesis given the view each would see.

    ``predicted`` is ``(H, n_fine)``: where each hypothesis' belief is after the action (rows
    with any mass); ``fine_profile`` ``(n_fine, n_states)``: the similarity of the view at each
    fine state to every upper state (:func:`fine_profiles`); ``fine_state`` ``(n_fine,)``.
    ``L[h, h'] = sum_S V_h(S) u_h'(S)`` with ``V_h = q_h @ profile`` (the expected view of h
    against each state) and ``u_h'`` the upper-state distribution of h' (both normalised).
    """
    q = np.asarray(predicted, dtype=np.float64)
    q = q / np.maximum(q.sum(axis=1, keepdims=True), 1e-300)
    profile = np.asarray(fine_profile, dtype=np.float64)
    fs = np.asarray(fine_state, dtype=np.int64)
    n_states = profile.shape[1]
    views = q @ profile
    upper = np.zeros((len(q), n_states))
    for h in range(len(q)):  # H <= a handful
        upper[h] = np.bincount(fs, weights=q[h], minlength=n_states)
    out: FloatArray = views @ upper.T
    return out


def fine_profiles(
    graph: TourGraph, profile: npt.ArrayLike, row_of: npt.ArrayLike
) -> npt.NDArray[np.float32]:
    """``(n_fine, n_states)`` the similarity profile of the view at each fine state: an edge
    image's own (its row of ``profile``), a location's the mean over its spin images (the
    robot may face any way). ``profile`` ``(m, n_states)`` and ``row_of`` ``(n_images,)`` as
    in :class:`server.vision.distinctiveness.Distinctiveness`."""
    prof = np.asarray(profile, dtype=np.float32)
    rows = np.asarray(row_of, dtype=np.int64)
    out = np.zeros((graph.n_fine, prof.shape[1]), dtype=np.float32)
    per_image = prof[rows]
    fine = graph.image_fine
    np.add.at(out, fine, per_image)
    counts = np.bincount(fine, minlength=graph.n_fine).astype(np.float32)
    out /= np.maximum(counts, 1.0)[:, None]
    return out


def detour(
    graph: TourGraph,
    plan: VotePlan,
    belief: npt.ArrayLike,
    action: Action,
    costs: npt.ArrayLike,
    ecost: npt.ArrayLike,
    *,
    rotation_s: float,
    horizon_s: float,
) -> float:
    """Expected extra seconds to the goal of doing ``action`` now, over the ``(n_fine,)``
    belief, against what each fine state votes for (``plan.cost``). ``costs`` is the
    ``(n_locations,)`` cost to the goal, ``ecost`` the ``(n_edges,)`` cost of taking each edge
    (:func:`server.policy.costs.edge_costs`).

    Where ``action`` is what the state would do anyway it costs nothing extra;
    ``RotateAndFindEdge(e)`` at the origin of ``e`` costs the edge and its target's cost to go,
    elsewhere a wasted turn (``rotation_s``); ``Navigate(e)`` on ``e`` costs driving on, at the
    origin of ``e`` the edge and its target, elsewhere ``horizon_s`` of wasted driving. Fine
    states from which the goal cannot be reached are left out.
    """
    b = np.asarray(belief, dtype=np.float64)
    base = plan.cost
    ok = np.isfinite(base) & (b > 0)
    if not np.any(ok):
        return 0.0
    L = graph.n_locations
    e = action.edge
    c = base.copy()
    if e is None or action.kind not in (ActionKind.ROTATE_AND_FIND_EDGE, ActionKind.NAVIGATE):
        return 0.0
    taking = float(np.asarray(ecost)[e] + np.asarray(costs)[graph.edges[e].target])
    if action.kind is ActionKind.ROTATE_AND_FIND_EDGE:
        c = c + rotation_s
        same = plan.vote == ROTATE0 + e
        c[same] = base[same]
    else:
        c = c + horizon_s
        lo, hi = L + int(plan.offsets[e]), L + int(plan.offsets[e + 1])
        c[lo:hi] = plan.go_on[lo:hi]
    c[graph.edges[e].source] = taking
    extra = np.where(ok, np.nan_to_num(c - base, posinf=1e9), 0.0)
    return float((b * extra).sum() / b[ok].sum())


def _candidates(
    graph: TourGraph, voted: Action, hyp: Hypotheses, model: BeliefModel
) -> list[Action]:
    """The voted action, then per hypothesis what its most likely state can do: from a place,
    find any edge leaving it; on an edge, drive on, or turn round onto its reverse edge (no
    repeats)."""
    L = graph.n_locations
    out = [voted]
    for states in hyp.states:
        s = int(states[0])
        if s < L:
            out += [Action.rotate(j) for j in model.out_edges[s]]
        elif model.valid_edge[s - L]:
            out.append(Action.navigate(s - L))
            out += [Action.rotate(r) for r in model.reverse[s - L]]
    return list(dict.fromkeys(out))


def next_views(
    model: BeliefModel,
    rows: npt.ArrayLike,
    action: Action,
    advance: npt.ArrayLike,
    fine_profile: npt.ArrayLike,
    *,
    match: float = 0.5,
) -> FloatArray:
    """Where each of ``(H, n_fine)`` ``rows`` of belief would see its next views under
    ``action``, ``advance`` ``(n_edges,)`` images ahead (the motion layer's view of an action,
    not the tracker's transition model, which keeps a spinning robot's mass at its place
    until the edge's start is in sight):

    * at the origin of ``action.edge`` (RotateAndFindEdge or Navigate), the robot faces the
      edge's departure view and drives off: the edge's first ``advance`` + 1 images;
    * at another place, it turns until it sees something like that departure view and drives
      off there: along the edge leaving that place whose images look most like the departure
      view (``fine_profile`` at least ``match``), else it stays (its views are its place's);
    * on an edge, under Navigate it drives on ``advance`` images; under
      ``RotateAndFindEdge(e)`` with ``e`` its reverse edge, it turns round onto ``e`` at the
      mirrored image; otherwise it stays.
    """
    b = np.asarray(rows, dtype=np.float64)
    adv = np.rint(np.broadcast_to(np.asarray(advance, dtype=np.float64), (model.n_edges,)))
    L = model.n_locations
    out = b.copy()
    e = action.edge
    if e is None or action.kind not in (ActionKind.ROTATE_AND_FIND_EDGE, ActionKind.NAVIGATE):
        return out
    e_lo, n_e = L + int(model.offsets[e]), int(model.edge_len[e])
    if n_e == 0:
        return out
    departure = np.asarray(fine_profile)[e_lo]
    for k in range(L):
        outs = model.out_edges[k]
        if not outs or not np.any(b[:, k] > 0):
            continue
        look = departure[[L + j for j in outs]]
        if e not in outs and look.max() < match:
            continue
        j = e if e in outs else outs[int(np.argmax(look))]
        lo = L + int(model.offsets[j])
        head = min(int(adv[j]) + 1, int(model.edge_len[j]))
        out[:, lo : lo + head] += b[:, k : k + 1] / head
        out[:, k] = 0.0
    if model.n_edge_images == 0:
        return out
    pos, row_edge = model.row_pos, model.row_edge
    last = model.edge_len[row_edge] - 1
    if action.kind is ActionKind.NAVIGATE:
        target = (
            L + model.offsets[row_edge] + np.minimum(pos + adv[row_edge].astype(np.int64), last)
        )
        moved = np.zeros_like(out[:, L:])
        np.add.at(moved, (slice(None), target - L), out[:, L:])  # type: ignore[arg-type]
        out[:, L:] = moved
        return out
    turning = np.flatnonzero([e in model.reverse[j] for j in range(model.n_edges)])
    for j in turning.tolist():
        a, n_j = L + int(model.offsets[j]), int(model.edge_len[j])
        frac = np.arange(n_j) / max(n_j - 1, 1)
        mirror = e_lo + np.rint((1.0 - frac) * (n_e - 1)).astype(np.int64)
        np.add.at(out, (slice(None), mirror), out[:, a : a + n_j])  # type: ignore[arg-type]
        out[:, a : a + n_j] = 0.0
    return out


def disambiguate(
    graph: TourGraph,
    model: BeliefModel,
    belief: npt.ArrayLike,
    plan: VotePlan,
    voted: Action,
    costs: npt.ArrayLike,
    fine_profile: npt.ArrayLike,
    params: DisambiguationParams | None = None,
    cost_params: CostParams | None = None,
) -> Separation | None:
    """The action that best separates the hypotheses of ``(n_fine,)`` ``belief`` (module
    docstring), or ``None`` when the belief holds fewer than two hypotheses or trusts one.

    ``plan`` and ``voted`` are the votes and the action they chose, ``costs`` the
    ``(n_locations,)`` cost to the goal, ``fine_profile`` from :func:`fine_profiles`.
    """
    p = params if params is not None else DisambiguationParams()
    cp = cost_params if cost_params is not None else CostParams()
    b = np.asarray(belief, dtype=np.float64)
    b = b / b.sum()
    hyp = hypotheses(model.upper_mass(b), adjacency(graph), floor=p.floor, min_mass=p.min_mass)
    if len(hyp.mass) < 2 or float(hyp.mass[0]) >= p.max_leader:
        return None
    rows = np.zeros((len(hyp.mass), graph.n_fine))
    for h, states in enumerate(hyp.states):
        mine = np.isin(model.fine_state, states)
        rows[h, mine] = b[mine]
    prior = hyp.mass / hyp.mass.sum()
    actions = _candidates(graph, voted, hyp, model)
    ecost = edge_costs(graph, cp)
    extra = [
        detour(graph, plan, b, a, costs, ecost, rotation_s=cp.rotation_s, horizon_s=p.horizon_s)
        for a in actions
    ]
    within = [k for k in range(1, len(actions)) if extra[k] <= extra[0] + p.max_detour_s]
    within.sort(key=lambda k: extra[k])
    candidates = [voted] + [actions[k] for k in within[: p.max_candidates - 1]]
    entropies = []
    advance = model.expected_advance(v=p.speed_mps, dt=p.horizon_s)
    for action in candidates:
        q = next_views(model, rows, action, advance, fine_profile, match=p.match)
        lik = view_likelihood(q, fine_profile, model.fine_state)
        entropies.append(expected_entropy(prior, lik, sharpness=p.sharpness))
    best = int(np.argmin(entropies))
    separating = best != 0 and entropies[0] - entropies[best] >= p.min_gain
    chosen = candidates[best] if separating else voted
    return Separation(
        hypotheses=hyp,
        action=chosen,
        expected_entropy=float(entropies[best] if separating else entropies[0]),
        voted_entropy=float(entropies[0]),
        separating=separating,
    )
