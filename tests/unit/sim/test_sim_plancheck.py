"""Every problem a hand-written floor plan can have is found, at once, with its JSON path.

One test per kind of problem, each on a copy of a small two-room plan with one thing broken;
``load_plan`` (what ``demo`` and the benchmarks run) and ``teachrepeat sim check-plan`` say the
same.
"""

from __future__ import annotations

import copy
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from robot_client.sim.floorplan import PlanError, load_plan, plan_from_dict
from server.cli import main

PLANS = Path(__file__).resolve().parents[2] / "data" / "plans"
SHIPPED = sorted((Path(__file__).resolve().parents[3] / "robot_client" / "sim").glob("*.json"))
TWO_ROOMS = json.loads((PLANS / "two_rooms.json").read_text())


def problems(mutate: Callable[[dict[str, Any]], Any]) -> list[str]:
    data = copy.deepcopy(TWO_ROOMS)
    mutate(data)
    with pytest.raises(PlanError) as exc:
        plan_from_dict(data)
    return [str(p) for p in exc.value.problems]


def only(mutate: Callable[[dict[str, Any]], Any]) -> str:
    found = problems(mutate)
    assert len(found) == 1, found
    return found[0]


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.name)
def test_every_shipped_plan_passes_check_plan(
    path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["sim", "check-plan", str(path)]) == 0
    out = capsys.readouterr().out
    assert "is good" in out and "teaching route" in out


def test_the_test_plan_is_good() -> None:
    plan = load_plan(PLANS / "two_rooms.json")
    assert [p.name for p in plan.places] == ["desk", "sofa"]
    assert len(plan.sha256) == 64 and plan.source.endswith("two_rooms.json")


def test_rooms_overlapping() -> None:
    room = {"name": "annex", "x0": 1, "y0": 1, "x1": 3, "y1": 2}
    assert only(lambda d: d["rooms"].append(room)) == (
        "$.rooms[2]: room 'annex' overlaps $.rooms[0] ('west'); rooms may share a side but not "
        "floor"
    )


def test_door_on_an_outside_wall() -> None:
    message = only(lambda d: d["doors"].append({"x": 2.0, "y": 0.0}))
    assert message.startswith("$.doors[1]: door at (2.0, 0.0) is on an outside wall of 'west'")


def test_door_on_no_wall() -> None:
    message = only(lambda d: d["doors"].append({"x": 2.0, "y": 2.0}))
    assert message.startswith("$.doors[1]: door at (2.0, 2.0) is not on any room's wall")


def test_door_too_narrow_for_the_robot() -> None:
    found = problems(lambda d: d["doors"][0].update(width=0.4))
    assert found[0].startswith("$.doors[0].width: 0.4 m is too narrow for the robot")
    assert found[1].startswith("$.places[1]: 'sofa' cannot be reached from 'desk'")


def test_place_outside_every_room() -> None:
    message = only(lambda d: d["places"][1].update(x=9.0))
    assert message == "$.places[1]: 'sofa' at (9.0, 1.75) is outside every room"


def test_place_unreachable_behind_a_wall() -> None:
    def closet(d: dict[str, Any]) -> None:
        d["rooms"].append({"name": "closet", "x0": 8, "y0": 0, "x1": 10, "y1": 3.5})
        d["places"].append({"name": "closet", "x": 9.0, "y": 1.75})

    message = only(closet)
    assert message.startswith("$.places[2]: 'closet' cannot be reached from 'desk' keeping 0.30 m")
    assert "no door or passage wide enough joins its room" in message


def test_place_where_the_robot_does_not_fit() -> None:
    message = only(lambda d: d["places"][1].update(x=7.3))
    assert message.startswith("$.places[1]: 'sofa' is 0.00 m from 'east/sofa' ($.furniture[3])")


def test_furniture_leaving_a_doorway_too_narrow() -> None:
    crate = {"name": "crate", "kind": "box", "x": 4.4, "y": 1.6, "sx": 0.4, "sy": 0.6, "h": 1.0}
    found = problems(lambda d: d["furniture"].append(crate))
    assert found[0].startswith(
        "$.furniture[6]: 'crate' leaves the doorway at $.doors[0] (4.0, 1.75)"
    )
    assert "the robot needs 0.46 m" in found[0]
    # and so nothing beyond the door can be reached, because of the crate
    assert found[1].startswith("$.places[1]: 'sofa' cannot be reached from 'desk'")
    assert "'crate' ($.furniture[6]) narrows the passage" in found[1]


def test_moved_furniture_closing_a_passage() -> None:
    # across the west room: a wardrobe from the south wall, and a screen by the north wall
    # that leaves 0.8 m between them as taught and, moved south, 0.35 m and 0.39 m
    wardrobe = {
        "name": "wardrobe",
        "kind": "cabinet",
        "x": 3,
        "y": 0.9,
        "sx": 0.2,
        "sy": 1.8,
        "h": 2,
    }
    screen = {"name": "screen", "kind": "shelf", "x": 3, "y": 3.05, "sx": 0.2, "sy": 0.9, "h": 1.5}
    screen["moved"] = [0.0, -0.45, 0.0]
    message = only(lambda d: d["furniture"].extend([wardrobe, screen]))
    assert message.startswith(
        "$.places[1]: 'sofa' cannot be reached from 'desk' once the furniture has moved keeping "
        "0.23 m from walls and furniture (the robot's radius and margin): 'wardrobe' "
        "($.furniture[6]), 'screen' ($.furniture[7]) narrow the passage"
    )


def test_unknown_texture() -> None:
    message = only(lambda d: d["rooms"][0].update(wall="lava"))
    assert message.startswith("$.rooms[0].wall: unknown texture 'lava'")


def test_unknown_furniture_kind() -> None:
    message = only(lambda d: d["furniture"][0].update(kind="spaceship"))
    assert message.startswith("$.furniture[0].kind: unknown kind 'spaceship'; use one of bath")


def test_furniture_sticking_out_when_moved() -> None:
    message = only(lambda d: d["furniture"][2].update(moved=[5.0, 0.0, 0.0]))
    assert message == "$.furniture[2].moved: 'west/plant' sticks out of the home when moved"


def test_duplicate_names() -> None:
    message = only(lambda d: d["places"][1].update(name="desk"))
    assert message == (
        "$.places[1].name: 'desk' is also the name of $.places[0]; names must be unique"
    )


def test_empty_names() -> None:
    message = only(lambda d: d["furniture"][0].update(name=" "))
    assert message == "$.furniture[0].name: is empty; give it a name"


def test_aliases_naming_unknown_places() -> None:
    message = only(lambda d: d.update(aliases=[["desk", "attic"]]))
    assert message == "$.aliases[0][1]: names unknown place 'attic'"


def test_route_naming_unknown_places_and_missing_one() -> None:
    found = problems(lambda d: d.update(route=["desk", "attic", "attic"]))
    assert found == [
        "$.route[1]: names unknown place 'attic'",
        "$.route[2]: names unknown place 'attic'",
        "$.route: never visits 'sofa': every place must be taught (or leave 'route' out and "
        "the guide derives one)",
    ]


def test_fields_of_the_wrong_kind() -> None:
    found = problems(
        lambda d: (
            d["rooms"][0].update(colour="red"),
            d["places"][0].update(x="left"),
            d["doors"][0].pop("y"),
            d.update(garden=True),
        )
    )
    assert found == [
        "$.garden: unknown key; known keys: name, notes, wall_height, wall_thickness, "
        "door_height, rooms, doors, furniture, pictures, places, extra_walls, aliases, route",
        "$.rooms[0].colour: unknown field; room fields are name, x0, y0, x1, y1, floor, wall",
        "$.doors[0]: missing 'y'",
        '$.places[0].x: must be a number, not "left"',
    ]


def test_every_problem_is_listed_at_once() -> None:
    found = problems(
        lambda d: (
            d["rooms"][1].update(floor="lava"),
            d["places"][1].update(name="desk"),
            d["furniture"][0].update(kind="spaceship"),
            d.update(aliases=[["desk", "attic"]]),
        )
    )
    paths = [f.split(":")[0] for f in found]
    assert paths == [
        "$.places[1].name",
        "$.furniture[0].kind",
        "$.rooms[1].floor",
        "$.aliases[0][1]",
    ]


def test_check_plan_lists_every_problem_and_exits_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = copy.deepcopy(TWO_ROOMS)
    bad["rooms"][1]["floor"] = "lava"
    bad["doors"].append({"x": 2.0, "y": 0.0})
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(bad))
    with pytest.raises(SystemExit) as exc:
        main(["sim", "check-plan", str(path)])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "2 problems" in err
    assert "$.doors[1]: door at (2.0, 0.0) is on an outside wall" in err
    assert "$.rooms[1].floor: unknown texture 'lava'" in err


def test_check_plan_prints_the_route_and_draws_the_home(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "home.png"
    assert main(["sim", "check-plan", str(PLANS / "two_rooms.json"), "--png", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "2 legs" in printed and "1. desk -> sofa" in printed and "2. sofa -> desk" in printed
    import cv2

    for png in (out, tmp_path / "home_places.png"):
        image = cv2.imread(str(png))
        assert image is not None and image.shape[0] > 100 and image.std() > 10
