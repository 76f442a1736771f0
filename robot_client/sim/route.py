"""The teaching guide's walk through a home, from the plan.

A plan may name its route (``"route": [place names]``). When it does not, :func:`derive_route`
makes one: it starts at the first place, drives every pair of *neighbouring* places in both
directions and ends where it started. Two places are neighbours when they are in the same room,
or in rooms joined by a door, possibly through rooms that have no named place (a corridor
nobody named). Every neighbouring pair driven both ways is a set of directed legs in which each
place has as many legs out as in, so one closed walk drives each leg exactly once (an Euler
circuit); no covering walk is shorter, since every leg must be driven at least once.
"""

from __future__ import annotations

import itertools
from collections import deque
from collections.abc import Sequence

import networkx as nx

from robot_client.sim.floorplan import FloorPlan
from robot_client.sim.paths import GUIDE_CLEARANCE_M, NoPathError, path_length, shortest_path
from robot_client.sim.world import PlanGeometry


class RouteError(ValueError):
    """No teaching route can be made: some place has no neighbour joined to the others."""


def place_rooms(plan: FloorPlan) -> dict[str, int]:
    """Index of the room each place is in (places outside every room are left out)."""
    out = {}
    for p in plan.places:
        for i, r in enumerate(plan.rooms):
            if r.contains(p.x, p.y):
                out[p.name] = i
                break
    return out


def neighbour_pairs(plan: FloorPlan) -> list[tuple[str, str]]:
    """Unordered pairs of neighbouring places, each once, in the order of the plan's places.

    Neighbours: in the same room, or in rooms joined by doors through rooms with no place.
    """
    rooms = place_rooms(plan)
    named = set(rooms.values())
    joined: dict[int, set[int]] = {i: set() for i in range(len(plan.rooms))}
    for d in plan.doors:
        for a, b in itertools.combinations(plan.rooms_of_door(d), 2):
            joined[a].add(b)
            joined[b].add(a)
    near: dict[int, set[int]] = {}
    for start in named:
        seen, found = {start}, {start}
        queue = deque([start])
        while queue:
            for nxt in sorted(joined[queue.popleft()]):
                if nxt in seen:
                    continue
                seen.add(nxt)
                if nxt in named:
                    found.add(nxt)  # a room with places: a neighbour, not passed through
                else:
                    queue.append(nxt)
        near[start] = found
    names = [p.name for p in plan.places if p.name in rooms]
    return [(a, b) for a, b in itertools.combinations(names, 2) if rooms[b] in near[rooms[a]]]


def derive_route(plan: FloorPlan) -> tuple[str, ...]:
    """A shortest closed walk from the first place that drives every neighbouring pair both ways.

    Raises:
        RouteError: the neighbour graph does not join every place (the message names them).
    """
    if not plan.places:
        raise RouteError("the plan has no places")
    graph = nx.MultiDiGraph()
    graph.add_nodes_from(p.name for p in plan.places)
    for a, b in neighbour_pairs(plan):
        graph.add_edge(a, b)
        graph.add_edge(b, a)
    first = plan.places[0].name
    reach = nx.node_connected_component(graph.to_undirected(as_view=True), first)
    alone = [p.name for p in plan.places if p.name not in reach]
    if alone:
        raise RouteError(
            f"no teaching route joins {', '.join(repr(n) for n in alone)} to {first!r}: no door "
            "joins their rooms to the rooms of the other places"
        )
    if graph.number_of_edges() == 0:
        return (first,)
    return (first, *(v for _, v in nx.eulerian_circuit(graph, source=first)))


def teaching_route(plan: FloorPlan) -> tuple[str, ...]:
    """The plan's own route, or the derived one when it has none."""
    return plan.route if plan.route else derive_route(plan)


def leg_lengths_m(
    plan: FloorPlan, route: Sequence[str], *, clearance: float = GUIDE_CLEARANCE_M
) -> list[float]:
    """Length of the shortest path of each leg of ``route`` in the home as taught, metres.

    Raises:
        NoPathError: a leg has no path at that clearance.
    """
    geometry = PlanGeometry(plan)
    places = {p.name: p for p in plan.places}
    cache: dict[frozenset[str], float] = {}
    out = []
    for a, b in itertools.pairwise(route):
        key = frozenset((a, b))
        if key not in cache:
            pa, pb = places[a], places[b]
            try:
                cache[key] = path_length(
                    shortest_path(geometry, (pa.x, pa.y), (pb.x, pb.y), clearance=clearance)
                )
            except NoPathError as exc:
                raise NoPathError(f"the guide cannot walk from {a!r} to {b!r}: {exc}") from None
        out.append(cache[key])
    return out
