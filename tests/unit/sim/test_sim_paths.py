"""Shortest paths on the floor plan and the scripted guide that drives along them."""

from __future__ import annotations

import itertools
import math

import pytest

from robot_client.sim.floorplan import FloorPlan, load_plan
from robot_client.sim.paths import NoPathError, path_length, shortest_path
from robot_client.sim.world import PlanGeometry


@pytest.fixture(scope="module")
def plan() -> FloorPlan:
    return load_plan()


@pytest.mark.parametrize("condition", ["same", "moved"])
def test_every_place_is_reachable_from_every_other(plan: FloorPlan, condition: str) -> None:
    geometry = PlanGeometry(plan, condition=condition)
    clearance = 0.25
    for a, b in itertools.permutations(plan.places, 2):
        path = shortest_path(geometry, (a.x, a.y), (b.x, b.y), clearance=clearance)
        assert path[0] == (a.x, a.y) and path[-1] == (b.x, b.y)
        assert path_length(path) >= math.dist((a.x, a.y), (b.x, b.y)) - 1e-9
        # every point of the path keeps (nearly) the clearance
        for p, q in itertools.pairwise(path):
            for t in (0.0, 0.25, 0.5, 0.75, 1.0):
                x, y = p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])
                assert geometry.clearance(x, y) >= clearance - 0.06, (a.name, b.name, x, y)


def test_paths_are_deterministic_and_shortish(plan: FloorPlan) -> None:
    a, b = plan.place("bedroom"), plan.place("kitchen")
    p1 = shortest_path(plan, (a.x, a.y), (b.x, b.y))
    p2 = shortest_path(PlanGeometry(plan), (a.x, a.y), (b.x, b.y))
    assert p1 == p2
    # bedroom (1.9, 6.5) -> kitchen (10.2, 1.7) via the corridor: Manhattan-ish length
    assert 9.6 < path_length(p1) < 14.0
    assert len(p1) <= 10


def test_path_length() -> None:
    assert path_length([(0, 0), (3, 4), (3, 5)]) == pytest.approx(6.0)
    assert path_length([(1, 1)]) == 0.0


def test_no_path_into_furniture_or_outside(plan: FloorPlan) -> None:
    bed = next(f for f in plan.furniture if f.name == "bedroom/bed")
    with pytest.raises(NoPathError, match="inside an obstacle"):
        shortest_path(plan, (plan.places[0].x, plan.places[0].y), (bed.x, bed.y))
    with pytest.raises(NoPathError):
        shortest_path(plan, (1.5, 1.2), (1.5, 1.2 + 20.0))
