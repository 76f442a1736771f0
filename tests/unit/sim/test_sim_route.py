"""The teaching route from the plan: every neighbouring pair of places both ways, once each."""

from __future__ import annotations

import itertools
import re
from collections import Counter
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_client.sim.floorplan import FloorPlan, load_plan, plan_from_dict
from robot_client.sim.route import (
    RouteError,
    derive_route,
    leg_lengths_m,
    neighbour_pairs,
    teaching_route,
)


def rooms_in_a_row(places_per_room: list[int], doors: list[bool]) -> FloorPlan:
    """Rooms 3 m wide side by side; ``doors[k]`` joins room k and k+1; places along y."""
    rooms = [
        {"name": f"r{k}", "x0": 3.0 * k, "y0": 0, "x1": 3.0 * (k + 1), "y1": 4}
        for k in range(len(places_per_room))
    ]
    places = [
        {"name": f"p{k}.{j}", "x": 3.0 * k + 1.5, "y": 0.8 + 1.2 * j}
        for k, n in enumerate(places_per_room)
        for j in range(n)
    ]
    door_list = [{"x": 3.0 * (k + 1), "y": 2.0} for k, d in enumerate(doors) if d]
    data = {"rooms": rooms, "places": places, "doors": door_list}
    return plan_from_dict(data, check=False)


def legs(route: tuple[str, ...]) -> Counter[tuple[str, str]]:
    return Counter(itertools.pairwise(route))


def assert_covers_once(plan: FloorPlan, route: tuple[str, ...]) -> None:
    pairs = neighbour_pairs(plan)
    expected = Counter([(a, b) for a, b in pairs] + [(b, a) for a, b in pairs])
    assert route[0] == route[-1] == plan.places[0].name
    assert legs(route) == expected  # each neighbouring pair both ways, nothing else, once
    assert {p.name for p in plan.places} <= set(route)


def test_the_apartment_route_drives_every_neighbouring_pair_both_ways() -> None:
    plan = load_plan()
    pairs = set(neighbour_pairs(plan))
    # the hall (the corridor's place) neighbours every room off the corridor
    assert ("entry", "hall") in pairs and ("hall", "office") in pairs
    assert ("living room", "kitchen") in pairs  # a door between them
    assert ("bedroom", "guest room") not in pairs  # no door between them
    route = derive_route(plan)
    assert_covers_once(plan, route)
    assert len(route) - 1 == 2 * len(pairs) == 18
    assert teaching_route(plan) == route  # the apartment names no route of its own


def test_places_in_one_open_room_are_all_neighbours() -> None:
    plan = rooms_in_a_row([3], [])
    assert neighbour_pairs(plan) == [("p0.0", "p0.1"), ("p0.0", "p0.2"), ("p0.1", "p0.2")]
    assert_covers_once(plan, derive_route(plan))


def test_rooms_without_places_are_passed_through() -> None:
    # r0 - r1 (no place) - r2: p0 and p2 are neighbours through r1
    plan = rooms_in_a_row([1, 0, 1], [True, True])
    assert neighbour_pairs(plan) == [("p0.0", "p2.0")]
    assert derive_route(plan) == ("p0.0", "p2.0", "p0.0")


def test_rooms_with_places_are_not_passed_through() -> None:
    plan = rooms_in_a_row([1, 1, 1], [True, True])
    assert neighbour_pairs(plan) == [("p0.0", "p1.0"), ("p1.0", "p2.0")]
    assert_covers_once(plan, derive_route(plan))


def test_a_place_no_door_joins_cannot_be_taught() -> None:
    plan = rooms_in_a_row([1, 1, 1], [True, False])
    with pytest.raises(RouteError, match=re.escape("no teaching route joins 'p2.0' to 'p0.0'")):
        derive_route(plan)


def test_a_plan_s_own_route_is_used_as_it_is() -> None:
    data: dict[str, Any] = {
        "rooms": [{"name": "r", "x0": 0, "y0": 0, "x1": 4, "y1": 4}],
        "places": [{"name": "a", "x": 1, "y": 1}, {"name": "b", "x": 3, "y": 3}],
        "route": ["b", "a", "b"],
    }
    assert teaching_route(plan_from_dict(data)) == ("b", "a", "b")


def test_leg_lengths_are_shortest_paths_and_symmetric() -> None:
    plan = rooms_in_a_row([1, 1], [True])
    there, back = leg_lengths_m(plan, ("p0.0", "p1.0", "p0.0"))
    assert there == back >= 3.0  # straight through the door, 3 m apart


@settings(max_examples=60, deadline=None)
@given(
    counts=st.lists(st.integers(0, 3), min_size=1, max_size=5),
    data=st.data(),
)
def test_derived_routes_cover_every_pair_both_ways_once(counts: list[int], data: Any) -> None:
    if sum(counts) < 2 or counts[0] == 0:
        counts = [max(counts[0], 1), *counts[1:]]
        if sum(counts) < 2:
            counts = [2, *counts[1:]]
    doors = data.draw(st.lists(st.booleans(), min_size=len(counts) - 1, max_size=len(counts) - 1))
    plan = rooms_in_a_row(counts, doors)
    try:
        route = derive_route(plan)
    except RouteError:
        # only when some place's room is cut off from the first place's rooms by a missing door
        first_cut = next((k for k, d in enumerate(doors) if not d), None)
        assert first_cut is not None and sum(counts[first_cut + 1 :]) > 0
        return
    assert_covers_once(plan, route)
