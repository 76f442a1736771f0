"""``teachrepeat bench carried``: a robot carried off a place of a short tour, over simulator
seeds (the scenario file, the arguments and the summary; one real trial of the default
scenario runs in ``tests/integration/test_faults.py``)."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import pytest

from robot_client.sim import load_plan
from server.bench.carried import DEFAULT_SCENARIO, Scenario, check, summarise
from server.cli import main


def row(success: bool, time_s: float, wrong: bool = False) -> dict:
    return {"success": success, "time_s": time_s, "wrong_arrival": wrong}


def test_summary_counts_arrivals_and_wrong_ones_and_the_median_time_of_the_arrived() -> None:
    rows = [row(True, 30.0), row(False, 90.0), row(False, 60.0, wrong=True), row(True, 50.0)]
    assert summarise(rows) == {"trials": 4, "arrived": 2, "wrong": 1, "median_time_s": 40.0}
    none = summarise([row(False, 90.0)])
    assert none["arrived"] == 0 and math.isnan(none["median_time_s"])


def test_the_shipped_scenario_names_places_of_its_plan_and_a_free_start() -> None:
    scenario = Scenario.load(DEFAULT_SCENARIO)
    plan = load_plan(scenario.plan)
    names = {p.name for p in plan.places}
    assert set(scenario.route) <= names and scenario.goal in names
    args = argparse.Namespace(
        scenario=DEFAULT_SCENARIO, seeds=1, max_steps=10, settings=[], condition="same"
    )
    assert check(args) == (scenario, None)
    from robot_client.sim.world import SimWorld

    with SimWorld(plan) as world:
        assert not world.collides(scenario.start[0], scenario.start[1], 0.2)


def write(tmp_path: Path, **fields: object) -> Path:
    data = {
        "plan": str(DEFAULT_SCENARIO.parent.parent.parent / "robot_client/sim/apartment.json"),
        "route": ["hall", "office"],
        "start": [6.0, 4.75, 0.0],
        "goal": "office",
        **fields,
    }
    path = tmp_path / "scenario.json"
    path.write_text(json.dumps({k: v for k, v in data.items() if v is not None}))
    return path


@pytest.mark.parametrize(
    ("fields", "argv", "message"),
    [
        ({}, ["--seeds", "0"], "--seeds must be at least 1"),
        ({}, ["--max-steps", "0"], "--max-steps must be at least 1"),
        ({}, ["--set", "no_such=1"], "--set: NavigationParams has no setting 'no_such'"),
        ({"goal": "attic"}, [], "no place 'attic' in the plan; its places: bathroom"),
        ({"route": ["hall", "cellar"]}, [], "no place 'cellar'"),
        ({"route": ["hall"]}, [], "the route needs at least two places"),
        ({"start": [1.0, 2.0]}, [], "start must be three finite numbers"),
        ({"goal": None}, [], "a scenario needs plan, route (places), start [x, y, theta] and goal"),
        ({"plan": "nowhere.json"}, [], "--scenario:"),
    ],
)
def test_bad_arguments_say_what_to_fix_before_any_server_starts(
    tmp_path: Path,
    fields: dict,
    argv: list[str],
    message: str,
    capsys: pytest.CaptureFixture[str],
) -> None:
    path = write(tmp_path, **fields)
    assert main(["bench", "carried", "--scenario", str(path), *argv]) == 2
    assert message in capsys.readouterr().out
