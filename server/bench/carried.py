"""``teachrepeat bench carried``: a robot carried off a place of a short tour, sent elsewhere.

A scenario file (``--scenario``) names a floor plan, the route a tour is taught along, where
the robot is carried to and the place it is sent to; each trial, one per simulator seed (the
seed of the world's noise and of the robot's odometry), teaches that tour on a server of its
own with a fresh database, carries the robot and sends it. The default, ``carried.json`` here,
is the closed-loop fault test's scenario (``tests/integration/test_faults.py``) without the
fault: in the simulated apartment a tour of three places, the robot carried 0.8 m west of the
first place's taught spot, facing west down the corridor. A tour of few places leaves the
belief few places to weigh against the edges' images, and a start beside a place in a corridor
that looks alike both ways tests how the robot finds which way to go: weighing the places by
the heading kept at each (an option since removed) arrived less often here than without it
(docs/navigation.md section 6).

Per seed: the outcome, the robot time and the distance from the goal at the end; in all: the
arrivals, the wrong arrivals and the median time of the arrived trials.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from server.bench.common import write_json
from server.bench.navigate import navigation_env
from server.tuning import add_set_argument

DEFAULT_SCENARIO = Path(__file__).with_name("carried.json")


@dataclass(frozen=True)
class Scenario:
    """A scenario file: ``plan`` (a floor plan, relative to the file), the ``route`` the tour
    is taught along (place names, in order), the ``start`` pose the robot is carried to
    (metres, metres, radians) and the ``goal`` place."""

    plan: Path
    route: tuple[str, ...]
    start: tuple[float, float, float]
    goal: str

    @classmethod
    def load(cls, path: Path) -> Scenario:
        """Read ``path``; ``ValueError`` saying what is missing or wrong."""
        try:
            data = json.loads(path.read_text())
            start = tuple(float(x) for x in data["start"])
            if len(start) != 3 or not all(math.isfinite(x) for x in start):
                raise ValueError("start must be three finite numbers [x, y, theta]")
            scenario = cls(
                plan=(path.parent / data["plan"]).resolve(),
                route=tuple(str(n) for n in data["route"]),
                start=(start[0], start[1], start[2]),
                goal=str(data["goal"]),
            )
        except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError, IndexError) as exc:
            raise ValueError(
                f"{path}: a scenario needs plan, route (places), start [x, y, theta] and goal "
                f"({type(exc).__name__}: {exc})"
            ) from None
        return scenario


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--scenario",
        type=Path,
        default=DEFAULT_SCENARIO,
        help="the scenario: plan, route, start and goal (default: the fault test's, "
        "server/bench/carried.json)",
    )
    parser.add_argument(
        "--seeds", type=int, default=7, help="trials, one per simulator seed 1..N (default 7)"
    )
    parser.add_argument(
        "--condition",
        default="same",
        choices=("same", "moved", "lighting"),
        help="the home as taught, with furniture moved, or in changed light (default same)",
    )
    parser.add_argument(
        "--max-steps", type=int, default=900, help="frames per trial (10 a second; default 900)"
    )
    add_set_argument(
        parser,
        "run the servers with this navigation setting changed (repeatable, as bench navigate's "
        "--set): --set topometric.lock_fix_s=3.0",
    )
    parser.add_argument("--json", type=Path, default=None, help="write the results here")
    parser.add_argument(
        "--trace",
        type=Path,
        default=None,
        help="write every step of every trial (true pose, command, top beliefs, the path "
        "tracker's estimate) to DIR/seed_N.jsonl, as bench navigate's --trace",
    )


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """``arrived``: trials that arrived at the goal (``success``); ``wrong``: that said
    "arrived" at another place; the median robot time of those at the goal (NaN: none)."""
    arrived = [r for r in rows if r["success"]]
    return {
        "trials": len(rows),
        "arrived": len(arrived),
        "wrong": sum(1 for r in rows if r["wrong_arrival"]),
        "median_time_s": float(np.median([r["time_s"] for r in arrived])) if arrived else math.nan,
    }


def _trial(
    args: argparse.Namespace, scenario: Scenario, seed: int, env: dict[str, str]
) -> dict[str, Any]:
    from robot_client.client import TeachRepeatClient
    from robot_client.guide import teach_route
    from robot_client.sim import SimulatedRobot, SimWorld, load_plan
    from robot_client.sim.world import Pose
    from robot_client.trial import run_trial
    from server.bench.nav_sweep import ANSWER_WAIT_S, tracer, write_trace
    from server.process import start_server

    plan = load_plan(scenario.plan)
    first = next(p for p in plan.places if p.name == scenario.route[0])
    trace: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        server = start_server(Path(tmp) / "carried.sqlite", extra_env=env)
        try:
            token = server.register_robot("carried", timeout_s=ANSWER_WAIT_S)
            with (
                TeachRepeatClient(server.url, token, timeout_s=ANSWER_WAIT_S) as client,
                SimWorld(plan, condition=args.condition, seed=seed) as world,
            ):
                robot = SimulatedRobot(world, Pose(first.x, first.y, first.yaw), seed=seed)
                teach_route(client, "carried", robot, plan, tour="short", route=scenario.route)
                robot.teleport(Pose(*scenario.start))
                result = run_trial(
                    client,
                    "carried",
                    robot,
                    plan,
                    scenario.goal,
                    max_steps=args.max_steps,
                    on_step=None if args.trace is None else tracer(robot, trace),
                )
        finally:
            server.stop()
    if args.trace is not None:
        write_trace(args.trace / f"seed_{seed}.jsonl", trace)
    return {
        "seed": seed,
        "state": result.state,
        "success": result.success,
        "wrong_arrival": result.wrong_arrival,
        "time_s": round(result.time_s, 2),
        "distance_m": round(result.distance_m, 3),
        "cause": result.cause,
    }


def check(args: argparse.Namespace) -> tuple[Scenario | None, str | None]:
    """The scenario, or what is wrong with the arguments (a message saying what to fix)."""
    from robot_client.sim import load_plan
    from robot_client.sim.floorplan import PlanError

    if args.seeds < 1:
        return None, f"--seeds must be at least 1 (got {args.seeds})"
    if args.max_steps < 1:
        return None, f"--max-steps must be at least 1 (got {args.max_steps})"
    try:
        navigation_env(args.settings)
    except ValueError as exc:
        return None, f"--set: {exc}"
    try:
        scenario = Scenario.load(args.scenario)
        names = {p.name for p in load_plan(scenario.plan).places}
    except (ValueError, OSError, PlanError) as exc:
        return None, f"--scenario: {exc}"
    unknown = [n for n in [*scenario.route, scenario.goal] if n not in names]
    if unknown:
        places = ", ".join(sorted(names))
        return None, f"--scenario: no place {unknown[0]!r} in the plan; its places: {places}"
    if len(scenario.route) < 2:
        return None, "--scenario: the route needs at least two places (the tour is taught along it)"
    return scenario, None


def run(args: argparse.Namespace) -> int:
    scenario, problem = check(args)
    if scenario is None:
        print(f"teachrepeat bench carried: {problem}")
        return 2
    env = navigation_env(args.settings)
    rows = []
    for seed in range(1, args.seeds + 1):
        row = _trial(args, scenario, seed, env)
        rows.append(row)
        print(
            f"seed {seed}: {row['state']:9s} {row['time_s']:6.1f} s (robot), "
            f"{row['distance_m']:.2f} m from {scenario.goal}"
            + (" WRONG" if row["wrong_arrival"] else "")
        )
    total = summarise(rows)
    print(
        f"arrived at the goal {total['arrived']}/{total['trials']}, at a wrong place "
        f"{total['wrong']}, median time of those at the goal {total['median_time_s']:.1f} s (robot)"
    )
    write_json(
        args.json,
        {
            "scenario": str(args.scenario),
            "plan": str(scenario.plan),
            "route": list(scenario.route),
            "start": list(scenario.start),
            "goal": scenario.goal,
            "condition": args.condition,
            "settings": dict(args.settings),
            "bench_server_settings": json.loads(env["TEACHREPEAT_NAVIGATION"]),
            "rows": rows,
            **total,
        },
    )
    return 0
