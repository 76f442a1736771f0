"""The voting policy of 001 Section 7: every fine state votes for its best action, weighted by
its belief; the action with the most vote mass wins (ties go to Navigate).

* a location votes ``RotateAndFindEdge(e)`` for the outgoing edge ``e`` minimising
  ``edge cost + cost(target of e)``; ``Explore`` when no outgoing edge reaches the goal;
* the goal location votes ``DoNothing`` - unless ``hold_goal`` is False, when it votes like any
  other location, for its cheapest round trip out and back in (beyond 001: the session asks for
  that until the robot has come into the goal along a taught edge, see
  :attr:`server.navigation.NavigationParams.approach_s`); the first ``round_trip_m`` of every edge
  leaving the goal then vote ``Navigate``, so the robot goes out far enough to come back in
  along a stretch of taught path;
* an edge image votes ``Navigate`` if going on (rest of the edge + cost of its target) is not
  dearer than turning back (half a turn + the reverse edge from the mirrored image + cost of the
  origin), else ``RotateAndFindEdge(reverse edge)``; an edge with no reverse edge can only go on;
  ``Explore`` if neither reaches the goal;
* ``Explore`` overall when the belief over upper states is too flat.

The per-fine-state votes depend only on the goal and the costs: :func:`build_vote_plan` computes
them once (cached per graph / goal / costs / params), then :func:`decide` is two ``np.bincount``
calls and a few argmaxes per step, with no loop over states.

Actions are distinct by parameter (``RotateAndFindEdge(3)`` and ``RotateAndFindEdge(5)`` are two
candidates, as in 001); :attr:`Decision.votes` reports the mass per action *kind*.

This module imports NumPy, networkx (via costs) and the core modules only.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from server.belief.model import Action, ActionKind, reverse_edges
from server.domain import TourGraph
from server.policy.costs import CostParams, edge_costs, edge_remaining_s

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

__all__ = ["Decision", "PolicyParams", "VotePlan", "build_vote_plan", "decide", "plan_for"]

# vote codes: 0 Navigate, 1 DoNothing, 2 Explore, 3 + e RotateAndFindEdge(e)
NAVIGATE, DO_NOTHING, EXPLORE, ROTATE0 = 0, 1, 2, 3


@dataclass(frozen=True)
class PolicyParams:
    """Policy settings.

    * ``explore_entropy`` (0.8): Explore when the entropy of ``b(s)`` divided by its maximum
      ``log(number of upper states)`` is at least this (1 = uniform; a belief split evenly over
      two places of a 10-state tour is 0.3, over half the states ~0.7).
    * ``tie_tolerance`` (1e-9): vote masses closer than this count as tied; ties go to Navigate,
      then RotateAndFindEdge, then DoNothing, then Explore.
    * ``round_trip_m`` (1.5 m): with ``hold_goal`` False, images of an edge leaving the goal
      taught less than this far (by the taught speeds) from where the edge starts vote
      ``Navigate`` rather than turning back. Turning back as soon as it is cheapest (at once,
      just outside the goal) left no taught path to come back in along: in the simulated home
      the robot drove a few frames out, turned round, found itself at the goal again, and set
      off once more, for the rest of the trial.
    * ``costs``: robot timing used for turning back on an edge (:class:`CostParams`).
    """

    explore_entropy: float = 0.8
    tie_tolerance: float = 1e-9
    round_trip_m: float = 1.5
    costs: CostParams = field(default_factory=CostParams)


@dataclass(frozen=True)
class Decision:
    """The chosen action and why.

    * ``action``: the action (its ``edge`` is the edge to find, or the active edge of Navigate).
    * ``target_image``: for Navigate, the index along the active edge of the image after the
      most likely one (001 Section 7.2); otherwise None.
    * ``votes``: vote mass per action kind (sums to 1 over the four kinds).
    * ``active_edge``: for Navigate, the edge with the most belief among Navigate voters.
    """

    action: Action
    target_image: int | None
    votes: dict[ActionKind, float]
    active_edge: int | None


@dataclass(frozen=True)
class VotePlan:
    """Per-fine-state votes for one goal: ``vote`` is ``(n_fine,) int`` codes
    (0 Navigate, 1 DoNothing, 2 Explore, 3 + e RotateAndFindEdge(e))."""

    goal: int
    vote: IntArray
    fine_state: IntArray
    n_locations: int
    n_edges: int
    offsets: IntArray
    n_valid_states: int


def build_vote_plan(
    graph: TourGraph,
    goal: int,
    costs: npt.ArrayLike,
    params: PolicyParams | None = None,
    *,
    hold_goal: bool = True,
) -> VotePlan:
    """Votes of every fine state for ``goal`` given ``(n_locations,)`` ``costs`` (seconds).

    ``hold_goal`` False: the goal location votes RotateAndFindEdge for the outgoing edge of the
    cheapest round trip (edge cost + cost back from its target) instead of DoNothing; a goal
    without such an edge still votes DoNothing. The images of edges leaving the goal within
    ``params.round_trip_m`` of their start then cannot turn back (they vote Navigate).
    """
    p = params if params is not None else PolicyParams()
    cost = np.asarray(costs, dtype=np.float64)
    L = graph.n_locations
    if cost.shape != (L,):
        raise ValueError(f"costs has shape {cost.shape}, expected ({L},) (cost_to_goal output)")
    if not 0 <= goal < L:
        raise ValueError(f"goal {goal} is not a location index (0..{L - 1})")
    ecost = edge_costs(graph, p.costs)
    offsets = np.asarray(graph.edge_offsets, dtype=np.int64)
    remaining = edge_remaining_s(graph, p.costs)
    revs = reverse_edges(graph)
    vote = np.full(graph.n_fine, EXPLORE, dtype=np.int64)
    # locations
    for k in range(L):
        if k == goal:
            vote[k] = DO_NOTHING
            if hold_goal:
                continue
        best, best_c = -1, math.inf
        for j, e in enumerate(graph.edges):
            if e.source == k and e.n_images > 0:
                c = float(ecost[j] + cost[e.target])
                if c < best_c:
                    best, best_c = j, c
        if best >= 0:
            vote[k] = ROTATE0 + best
    # edge images
    for j, e in enumerate(graph.edges):
        n = e.n_images
        if n == 0:
            continue
        lo, hi = int(offsets[j]), int(offsets[j + 1])
        go_on = remaining[lo:hi] + cost[e.target]
        back = np.full(n, np.inf)
        back_edge = np.full(n, -1, dtype=np.int64)
        frac = np.arange(n) / (n - 1) if n > 1 else np.full(n, 0.5)
        for r in revs[j]:
            nr = graph.edges[r].n_images
            mirror = np.rint((1.0 - frac) * (nr - 1)).astype(np.int64)
            rem_r = remaining[int(offsets[r]) + mirror]
            c = p.costs.turn_back_s + rem_r + cost[graph.edges[r].target]
            better = c < back
            back = np.where(better, c, back)
            back_edge = np.where(better, r, back_edge)
        if not hold_goal and e.source == goal:
            back = np.where(e.metres_along() < p.round_trip_m, np.inf, back)
        v = np.where(go_on <= back, NAVIGATE, ROTATE0 + back_edge)
        v = np.where(np.isinf(go_on) & np.isinf(back), EXPLORE, v)
        vote[L + lo : L + hi] = v
    n_valid = L + sum(1 for e in graph.edges if e.n_images > 0)
    return VotePlan(
        goal=goal,
        vote=vote,
        fine_state=np.asarray(graph.fine_state, dtype=np.int64),
        n_locations=L,
        n_edges=graph.n_edges,
        offsets=offsets,
        n_valid_states=n_valid,
    )


_PLANS: dict[
    tuple[int, bool], tuple[weakref.ref[TourGraph], int, bytes, PolicyParams, VotePlan]
] = {}


def plan_for(
    graph: TourGraph,
    goal: int,
    costs: npt.ArrayLike,
    params: PolicyParams | None = None,
    *,
    hold_goal: bool = True,
) -> VotePlan:
    """The vote plan :func:`decide` uses (built once per graph, goal, costs, params and
    ``hold_goal``, then cached)."""
    p = params if params is not None else PolicyParams()
    return _plan_for(graph, goal, np.asarray(costs, dtype=np.float64), p, hold_goal)


def _plan_for(
    graph: TourGraph, goal: int, costs: FloatArray, params: PolicyParams, hold_goal: bool
) -> VotePlan:
    key = (id(graph), hold_goal)
    hit = _PLANS.get(key)
    cbytes = costs.tobytes()
    if hit is not None:
        ref, g, cb, pp, plan = hit
        if ref() is graph and g == goal and cb == cbytes and pp == params:
            return plan
    plan = build_vote_plan(graph, goal, costs, params, hold_goal=hold_goal)
    if len(_PLANS) > 64:
        _PLANS.clear()
    _PLANS[key] = (weakref.ref(graph), goal, cbytes, params, plan)
    return plan


def decide(
    graph: TourGraph,
    belief_fine: npt.ArrayLike,
    goal: int,
    costs: npt.ArrayLike,
    params: PolicyParams | None = None,
    *,
    plan: VotePlan | None = None,
    hold_goal: bool = True,
) -> Decision:
    """Pick the action for ``(n_fine,)`` belief ``belief_fine`` (sums to 1) toward ``goal``.

    ``costs`` is ``cost_to_goal(graph, goal, ...)``. The vote plan is cached per graph, goal,
    costs, params and ``hold_goal`` (see :func:`build_vote_plan`), or pass ``plan``.
    """
    p = params if params is not None else PolicyParams()
    b = np.asarray(belief_fine, dtype=np.float64)
    if b.shape != (graph.n_fine,):
        raise ValueError(f"belief has shape {b.shape}, expected ({graph.n_fine},)")
    cost = np.asarray(costs, dtype=np.float64)
    if plan is None:
        plan = _plan_for(graph, goal, cost, p, hold_goal)
    elif plan.goal != goal:
        raise ValueError(f"the vote plan is for goal {plan.goal}, not {goal}")
    total = float(b.sum())
    if not (total > 0 and math.isfinite(total)):
        raise ValueError("belief must have positive, finite mass")
    b = b / total
    n_codes = ROTATE0 + plan.n_edges
    mass = np.bincount(plan.vote, weights=b, minlength=n_codes)
    votes = {
        ActionKind.NAVIGATE: float(mass[NAVIGATE]),
        ActionKind.ROTATE_AND_FIND_EDGE: float(mass[ROTATE0:].sum()),
        ActionKind.DO_NOTHING: float(mass[DO_NOTHING]),
        ActionKind.EXPLORE: float(mass[EXPLORE]),
    }
    # too flat -> Explore
    upper = np.bincount(plan.fine_state, weights=b, minlength=plan.n_locations + plan.n_edges)
    nz = upper[upper > 0]
    entropy = float(-(nz * np.log(nz)).sum())
    max_entropy = math.log(plan.n_valid_states) if plan.n_valid_states > 1 else 1.0
    if plan.n_valid_states > 1 and entropy / max_entropy >= p.explore_entropy:
        return Decision(Action.explore(), None, votes, None)
    # highest vote mass, ties: Navigate > Rotate(e) (lowest e) > DoNothing > Explore
    order = np.concatenate([[NAVIGATE], np.arange(ROTATE0, n_codes), [DO_NOTHING, EXPLORE]])
    ranked = mass[order]
    winner = int(order[int(np.argmax(ranked >= ranked.max() - p.tie_tolerance))])
    if winner == NAVIGATE:
        L = plan.n_locations
        nav = np.where(plan.vote[L:] == NAVIGATE, b[L:], 0.0)
        edge_of = plan.fine_state[L:] - L
        per_edge = np.bincount(edge_of, weights=nav, minlength=plan.n_edges)
        active = int(np.argmax(per_edge))
        lo, hi = int(plan.offsets[active]), int(plan.offsets[active + 1])
        best = int(np.argmax(b[L + lo : L + hi]))
        target = min(best + 1, hi - lo - 1)
        return Decision(Action.navigate(active), target, votes, active)
    if winner == DO_NOTHING:
        return Decision(Action.do_nothing(), None, votes, None)
    if winner == EXPLORE:
        return Decision(Action.explore(), None, votes, None)
    return Decision(Action.rotate(winner - ROTATE0), None, votes, None)
