"""Helpers for the belief tests: hand-built graphs, a naive transition model, fake observations.

The naive model is written independently of :mod:`server.belief.model`: plain dicts and loops
over states, straight from the rules in the model's docstrings, so the vectorised/sparse
implementation can be checked against it on small graphs.
"""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np

from server.belief.model import Action, ActionKind, TransitionParams
from server.domain import Edge, Location, TourGraph

_next_id = [10_000]


def ids(n: int) -> tuple[int, ...]:
    start = _next_id[0]
    _next_id[0] += n
    return tuple(range(start, start + n))


def edge(source: int, target: int, n: int, *, dt: float = 0.5, v: float = 0.25) -> Edge:
    """An edge of ``n`` images taken every ``dt`` s at ``v`` m/s."""
    ts = np.arange(n, dtype=np.float64) * dt
    return Edge(source, target, ids(n), ts, np.full(n, v), np.zeros(n))


def location(name: str, n_images: int = 3) -> Location:
    return Location(name, ids(n_images))


def corridors_graph(n: int = 30) -> TourGraph:
    """A(0) -> B(1) and C(2) -> D(3): two corridors of ``n`` images (edges 0 and 1), plus the
    return edges B -> A (2) and D -> C (3)."""
    locs = tuple(location(x) for x in "ABCD")
    return TourGraph(locs, (edge(0, 1, n), edge(2, 3, n), edge(1, 0, n), edge(3, 2, n)))


def house_graph() -> TourGraph:
    """hall(0), kitchen(1), office(2), bedroom(3); edges both ways around a loop plus a chord.

    0: hall->kitchen 20 img, 1: kitchen->hall 20, 2: kitchen->office 24, 3: office->kitchen 24,
    4: office->bedroom 30, 5: bedroom->office 30, 6: bedroom->hall 16, 7: hall->office 40.
    """
    locs = tuple(location(x, 4) for x in ("hall", "kitchen", "office", "bedroom"))
    es = (
        edge(0, 1, 20),
        edge(1, 0, 20),
        edge(1, 2, 24),
        edge(2, 1, 24),
        edge(2, 3, 30),
        edge(3, 2, 30),
        edge(3, 0, 16),
        edge(0, 2, 40),
    )
    return TourGraph(locs, es)


def odd_graph() -> TourGraph:
    """Corner cases: parallel edges, a single-image edge, an edge with no images, a location
    with no images, shared origins and destinations, a self-loop."""
    locs = (location("a"), location("b"), Location("c", ()), location("d", 1))
    es = (
        edge(0, 1, 12),
        edge(0, 1, 9),  # parallel re-teach
        edge(1, 0, 7),
        edge(0, 2, 1),  # single image
        Edge(2, 3, (), np.zeros(0), np.zeros(0), np.zeros(0)),  # no images
        edge(3, 1, 5),
        edge(2, 1, 6),  # shares destination b
        edge(1, 1, 4),  # self-loop
    )
    return TourGraph(locs, es)


def route_graph(n: int = 10) -> TourGraph:
    """start(0) -> middle(1) -> end(2): a taught route that ends at a dead end (no edge leaves
    ``end``), ``n`` images per edge, as the localisation bench builds from a recorded route."""
    locs = tuple(location(x, 1) for x in ("start", "middle", "end"))
    return TourGraph(locs, (edge(0, 1, n), edge(1, 2, n)))


# ------------------------------------------------------------------------------------------
# naive reference model (dicts and loops)
# ------------------------------------------------------------------------------------------


def naive_transition(
    graph: TourGraph, params: TransitionParams, action: Action, advance: list[float]
) -> dict[tuple[int, int], float]:
    """``T[(s, s')]`` for fine states, without teleport. ``advance`` per edge (images)."""
    p = params
    L = graph.n_locations
    n_of = [e.n_images for e in graph.edges]
    first = [L + int(graph.edge_offsets[j]) for j in range(graph.n_edges)]
    ok = [n > 0 for n in n_of]

    def head(j: int) -> int:
        return min(n_of[j], max(1, math.ceil(p.entry_fraction * n_of[j] - 1e-9)))

    def tail(j: int) -> int:
        return max(1, math.ceil(p.exit_fraction * n_of[j] - 1e-9))

    outs = {k: [j for j, e in enumerate(graph.edges) if ok[j] and e.source == k] for k in range(L)}
    ins = {k: [j for j, e in enumerate(graph.edges) if ok[j] and e.target == k] for k in range(L)}

    def revs(j: int) -> list[int]:
        e = graph.edges[j]
        return [
            i
            for i, f in enumerate(graph.edges)
            if ok[i] and (f.source, f.target) == (e.target, e.source)
        ]

    def sibs(j: int) -> list[int]:
        e = graph.edges[j]
        out = []
        for i, f in enumerate(graph.edges):
            if i == j or not ok[i] or i in revs(j):
                continue
            if f.source == e.source or f.target == e.target:
                out.append(i)
        return out

    struct: dict[tuple[int, int], float] = defaultdict(float)

    def into(src: int, j: int, prob: float, mode: str) -> None:
        cells = range(head(j)) if mode == "head" else range(n_of[j])
        for k in cells:
            struct[(src, first[j] + k)] += prob / len(cells)

    def mirror(src_j: int, k: int, r: int, prob: float) -> None:
        n, nr = n_of[src_j], n_of[r]
        f = k / (n - 1) if n > 1 else 0.5
        c = round((1 - f) * (nr - 1))
        h = max(p.reverse_spread_images, math.ceil(0.5 * nr / n) - 1, 0)
        for d in range(-h, h + 1):
            struct[(first[src_j] + k, first[r] + min(max(c + d, 0), nr - 1))] += prob / (2 * h + 1)

    kind = action.kind
    g = action.edge
    for k in range(L):
        sent = 0.0
        if kind in (ActionKind.ROTATE_AND_FIND_EDGE, ActionKind.NAVIGATE):
            rot = kind is ActionKind.ROTATE_AND_FIND_EDGE
            to_goal = p.rotate_loc_to_goal_edge if rot else p.navigate_loc_to_active_edge
            to_other = p.rotate_loc_to_other_edges if rot else p.navigate_loc_to_other_edges
            others = [j for j in outs[k] if j != g] if g in outs[k] else outs[k]
            if g in outs[k]:
                into(k, g, to_goal, "head")
                sent += to_goal
            for j in others:
                into(k, j, to_other / len(others), "head")
            sent += to_other if others else 0.0
            if not rot and not outs[k] and p.navigate_dead_end > 0:
                valid = list(range(L)) + [L + j for j in range(len(graph.edges)) if n_of[j]]
                for st in valid:
                    share = p.navigate_dead_end / len(valid)
                    if st < L:
                        struct[(k, st)] += share
                    else:
                        into(k, st - L, share, "uniform")
                sent += p.navigate_dead_end
        elif kind is ActionKind.EXPLORE:
            for j in outs[k]:
                into(k, j, p.explore_loc_to_out_edges / len(outs[k]), "head")
            for j in ins[k]:
                into(k, j, p.explore_loc_to_in_edges / len(ins[k]), "uniform")
            sent += (p.explore_loc_to_out_edges if outs[k] else 0) + (
                p.explore_loc_to_in_edges if ins[k] else 0
            )
        struct[(k, k)] += 1 - sent
    for j, e in enumerate(graph.edges):
        n = n_of[j]
        for k in range(n):
            s = first[j] + k
            sent = 0.0
            if kind is ActionKind.ROTATE_AND_FIND_EDGE:
                if k < head(j):
                    struct[(s, e.source)] += p.rotate_head_to_origin
                    sent += p.rotate_head_to_origin
                related = revs(j) + sibs(j)
                if g in related:
                    if g in revs(j):
                        mirror(j, k, g, p.rotate_edge_to_goal)
                    else:
                        into(s, g, p.rotate_edge_to_goal, "uniform")
                    sent += p.rotate_edge_to_goal
                others = [i for i in related if i != g]
                for i in others:
                    share = p.rotate_edge_to_related / len(others)
                    if i in revs(j):
                        mirror(j, k, i, share)
                    else:
                        into(s, i, share, "uniform")
                    sent += share
            elif kind is ActionKind.NAVIGATE:
                if k >= n - tail(j):
                    struct[(s, e.target)] += p.navigate_exit
                    sent += p.navigate_exit
                for i in sibs(j):
                    into(s, i, p.navigate_edge_to_sibling / len(sibs(j)), "uniform")
                    sent += p.navigate_edge_to_sibling / len(sibs(j))
            elif kind is ActionKind.EXPLORE:
                ends = [e.source, e.target] if e.source != e.target else [e.source]
                for t in ends:
                    struct[(s, t)] += p.explore_edge_to_endpoints / len(ends)
                    sent += p.explore_edge_to_endpoints / len(ends)
                related = revs(j) + sibs(j)
                for i in related:
                    share = p.explore_edge_to_related / len(related)
                    if i in revs(j):
                        mirror(j, k, i, share)
                    else:
                        into(s, i, share, "uniform")
                    sent += share
            struct[(s, s)] += 1 - sent

    # motion inside edges (identity on locations)
    motion: dict[tuple[int, int], float] = defaultdict(float)
    for k in range(L):
        motion[(k, k)] = 1.0
    for j in range(graph.n_edges):
        a = max(0.0, advance[j])
        kernel = naive_kernel(p, kind, a)
        for k in range(n_of[j]):
            for d, w in kernel.items():
                dst = min(max(k + d, 0), n_of[j] - 1)
                motion[(first[j] + k, first[j] + dst)] += w
    total: dict[tuple[int, int], float] = defaultdict(float)
    for (s, m), w1 in struct.items():
        if w1 == 0:
            continue
        for d in range(graph.n_fine):
            w2 = motion.get((m, d), 0.0)
            if w2:
                total[(s, d)] += w1 * w2
    return dict(total)


def _gauss_kernel(centre: float, sigma: float, lo: int, hi: int) -> dict[int, float]:
    if sigma <= 1e-6:
        return {round(centre): 1.0}
    r = math.ceil(3 * sigma)  # truncated at +- ceil(3 sigma) around the centre
    w = {
        d: math.exp(-0.5 * ((d - centre) / sigma) ** 2)
        for d in range(lo, hi + 1)
        if abs(d - centre) <= r
    }
    z = sum(w.values())
    return {d: v / z for d, v in w.items()}


def naive_kernel(p: TransitionParams, kind: ActionKind, a: float) -> dict[int, float]:
    """Offsets (images) -> probability of the lower-layer motion of one edge."""
    if a <= 0 or kind in (ActionKind.ROTATE_AND_FIND_EDGE, ActionKind.DO_NOTHING):
        return {0: 1.0}
    if kind is ActionKind.EXPLORE:
        sigma = p.explore_spread * a
        r = math.ceil(3 * sigma) + 3
        return _gauss_kernel(0.0, sigma, -r, r)
    sigma = p.advance_spread_rel * a + p.advance_spread_abs * min(a, 1.0)
    base = math.floor(a)
    frac = a - base
    r = math.ceil(3 * sigma) + 3
    out: dict[int, float] = defaultdict(float)
    for b, wb in ((base, 1 - frac), (base + 1, frac)):
        if wb == 0:
            continue
        for d, w in _gauss_kernel(float(b), sigma, b - r, b + r).items():
            out[d] += (1 - p.navigate_stall) * wb * w
    out[0] += p.navigate_stall
    return dict(out)


def to_dense(t: dict[tuple[int, int], float], n: int) -> np.ndarray:
    m = np.zeros((n, n))
    for (s, d), w in t.items():
        m[s, d] += w
    return m


# ------------------------------------------------------------------------------------------
# fake observations
# ------------------------------------------------------------------------------------------


def observe(
    graph: TourGraph,
    true_fine: int,
    rng: np.random.Generator,
    *,
    alias: dict[int, int] | None = None,
    background: float = 0.15,
    width: float = 1.5,
    noise: float = 0.05,
) -> np.ndarray:
    """``(n_fine,)`` likelihood of a camera frame taken at fine state ``true_fine``.

    Images of the true edge near the true image match (Gaussian in image distance, ``width``);
    the true location matches fully; everything else gets ``background``; plus uniform noise.
    ``alias`` maps edge -> edge that looks identical (compared image by image).
    """
    L = graph.n_locations
    lik = np.full(graph.n_fine, background)
    alias = alias or {}
    if true_fine < L:
        lik[true_fine] = 1.0
    else:
        j = int(graph.fine_state[true_fine]) - L
        k = true_fine - L - int(graph.edge_offsets[j])
        looks = {j} | {a for a, b in alias.items() if b == j} | {alias.get(j, j)}
        for i in looks:
            lo, hi = int(graph.edge_offsets[i]), int(graph.edge_offsets[i + 1])
            pos = np.arange(hi - lo)
            kk = min(k, hi - lo - 1)
            lik[L + lo : L + hi] = np.maximum(
                lik[L + lo : L + hi], np.exp(-0.5 * ((pos - kk) / width) ** 2)
            )
    return lik + noise * rng.random(graph.n_fine)


def fine_of(graph: TourGraph, edge_index: int, image: int) -> int:
    return graph.n_locations + int(graph.edge_offsets[edge_index]) + image
