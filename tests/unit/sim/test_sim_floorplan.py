"""The floor plan is data: the packaged apartment loads, files that cannot be read fail clearly
(every problem of a readable plan: test_sim_plancheck.py)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from robot_client.sim.floorplan import (
    DEFAULT_PLAN,
    FloorPlan,
    PlanError,
    load_plan,
)


@pytest.fixture(scope="module")
def plan() -> FloorPlan:
    return load_plan()


@pytest.fixture()
def raw() -> dict:
    return json.loads(DEFAULT_PLAN.read_text())


def test_default_plan_has_named_places_rooms_and_aliasing(plan: FloorPlan) -> None:
    names = {p.name for p in plan.places}
    assert len(names) >= 7
    assert {"entry", "kitchen", "living room", "office", "bedroom", "bathroom", "hall"} <= names
    assert len(plan.rooms) >= 7 and len(plan.doors) >= 7 and len(plan.furniture) >= 20
    assert ("bedroom", "guest room") in plan.aliases
    for p in plan.places:
        assert plan.room_at(p.x, p.y) is not None


def test_doors_cut_gaps_in_the_wall_panels(plan: FloorPlan) -> None:
    walls = plan.walls()
    for d in plan.doors:
        for w in walls:
            on_line = (
                abs(w.y0 - w.y1) < 1e-9
                and abs(w.y0 - d.y) < plan.wall_thickness
                and min(w.x0, w.x1) < d.x < max(w.x0, w.x1)
            )
            on_col = (
                abs(w.x0 - w.x1) < 1e-9
                and abs(w.x0 - d.x) < plan.wall_thickness
                and min(w.y0, w.y1) < d.y < max(w.y0, w.y1)
            )
            assert not (on_line or on_col), f"wall {w} blocks door {d}"
    assert len(plan.lintels()) >= len(plan.doors)  # one lintel per room side a door is in


def test_moved_condition_displaces_only_marked_furniture(plan: FloorPlan) -> None:
    same = {f.name: f for f in plan.furniture_for("same")}
    moved = {f.name: f for f in plan.furniture_for("moved")}
    changed = [
        n
        for n in same
        if (same[n].x, same[n].y, same[n].yaw) != (moved[n].x, moved[n].y, moved[n].yaw)
    ]
    assert 3 <= len(changed) <= 8
    assert all(same[n].moved is not None for n in changed)
    assert all(math.dist((same[n].x, same[n].y), (moved[n].x, moved[n].y)) > 0.2 for n in changed)


def test_unknown_condition_is_rejected(plan: FloorPlan) -> None:
    with pytest.raises(PlanError, match="unknown condition 'night'"):
        plan.furniture_for("night")


def test_place_lookup_lists_known_names(plan: FloorPlan) -> None:
    assert plan.place("kitchen").name == "kitchen"
    with pytest.raises(KeyError, match="places are: entry"):
        plan.place("garage")


def test_load_plan_reports_missing_and_broken_files(tmp_path: Path) -> None:
    with pytest.raises(PlanError, match="not found"):
        load_plan(tmp_path / "nope.json")
    broken = tmp_path / "broken.json"
    broken.write_text("{rooms: ")
    with pytest.raises(PlanError, match="not valid JSON"):
        load_plan(broken)


def test_plan_round_trips_through_a_file(tmp_path: Path, raw: dict) -> None:
    path = tmp_path / "copy.json"
    path.write_text(json.dumps(raw))
    assert load_plan(path) == load_plan()
