"""Cost to the goal from every location (001 Sections 3.1 and 7), in seconds of execution time.

An edge costs its teaching duration (last timestamp minus first) plus the time to turn into it at
its origin; the cost of a location is the cheapest sum of edge costs to the goal, found with
``networkx`` Dijkstra on the reversed graph. Edges without images cannot be followed and are left
out. Parallel edges (the same pair taught twice) keep the cheaper one. Costs are time only: a
surcharge on look-alike images (least-ambiguous routes, seed 000) was measured with no gain and
removed (docs/ambiguity.md section 2).

This module imports NumPy, networkx and :mod:`server.domain` only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import networkx as nx
import numpy as np
import numpy.typing as npt

from server.domain import TourGraph

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "CostParams",
    "cost_to_goal",
    "edge_costs",
    "edge_remaining_s",
    "route_graph",
]


@dataclass(frozen=True)
class CostParams:
    """Robot properties used for costs (seconds).

    * ``rotation_s`` (8.0 s): time for a full 360 degree turn in place (a slow, careful spin of a
      cheap two-wheeled robot; 001 measures it on the robot).
    * ``turn_into_edge`` (0.5): expected fraction of a full turn needed to face an edge when
      arriving at a location (heading unknown -> half a turn on average).
    * ``turn_back`` (0.5): fraction of a full turn to turn round on an edge (180 degrees).
    * ``min_edge_s`` (1.0 s): lower bound of an edge's traversal time (edges taught with missing
      or degenerate timestamps still cost something).
    """

    rotation_s: float = 8.0
    turn_into_edge: float = 0.5
    turn_back: float = 0.5
    min_edge_s: float = 1.0

    def __post_init__(self) -> None:
        for name in ("rotation_s", "turn_into_edge", "turn_back", "min_edge_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"CostParams.{name} must be finite and >= 0, got {value}")

    @property
    def turn_into_edge_s(self) -> float:
        return self.turn_into_edge * self.rotation_s

    @property
    def turn_back_s(self) -> float:
        return self.turn_back * self.rotation_s


def edge_costs(graph: TourGraph, params: CostParams | None = None) -> FloatArray:
    """``(n_edges,)`` seconds to take each edge from its origin: turn into it, then follow it.

    ``inf`` for edges with no images (they cannot be followed).
    """
    p = params if params is not None else CostParams()
    out = np.full(graph.n_edges, np.inf)
    for j, e in enumerate(graph.edges):
        if e.n_images == 0:
            continue
        duration = e.duration if math.isfinite(e.duration) else 0.0
        out[j] = max(duration, p.min_edge_s) + p.turn_into_edge_s
    return out


def edge_remaining_s(graph: TourGraph, params: CostParams | None = None) -> FloatArray:
    """``(n_edge_images,)`` seconds from each edge image to the end of its edge (no turning).

    From the teaching timestamps; when they are missing or degenerate, proportional to the
    remaining fraction of the edge's (``min_edge_s``-bounded) duration.
    """
    p = params if params is not None else CostParams()
    parts: list[FloatArray] = []
    for e in graph.edges:
        n = e.n_images
        if n == 0:
            continue
        t = np.asarray(e.timestamps, dtype=np.float64)
        total = max(e.duration if math.isfinite(e.duration) else 0.0, p.min_edge_s)
        frac_left = (n - 1 - np.arange(n)) / max(n - 1, 1)
        good = len(t) == n and np.all(np.isfinite(t)) and t[-1] - t[0] >= p.min_edge_s
        rem = np.maximum(t[-1] - t, 0.0) if good else frac_left * total
        parts.append(rem.astype(np.float64))
    return np.concatenate(parts) if parts else np.zeros(0)


def route_graph(graph: TourGraph, params: CostParams | None = None) -> nx.DiGraph:
    """Directed graph of locations; attribute ``weight`` (s) and ``edge`` (cheapest edge index)."""
    costs = edge_costs(graph, params)
    g = nx.DiGraph()
    g.add_nodes_from(range(graph.n_locations))
    for j, e in enumerate(graph.edges):
        c = float(costs[j])
        if not math.isfinite(c):
            continue
        old = g.get_edge_data(e.source, e.target)
        if old is None or c < old["weight"]:
            g.add_edge(e.source, e.target, weight=c, edge=j)
    return g


def cost_to_goal(graph: TourGraph, goal: int, params: CostParams | None = None) -> FloatArray:
    """``(n_locations,) float64`` seconds from every location to ``goal`` (``inf`` unreachable).

    Shortest paths with ``networkx`` (Dijkstra from the goal on the reversed graph); 0 at the goal.
    """
    if not 0 <= goal < graph.n_locations:
        raise ValueError(f"goal {goal} is not a location index (0..{graph.n_locations - 1})")
    g = route_graph(graph, params)
    dist = nx.single_source_dijkstra_path_length(g.reverse(copy=False), goal, weight="weight")
    out = np.full(graph.n_locations, np.inf)
    for k, d in dist.items():
        out[int(k)] = float(d)
    return out
