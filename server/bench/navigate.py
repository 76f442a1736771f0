"""``teachrepeat bench navigate``: closed-loop navigation in the simulated home.

One teaching tour (the default guide route, taught in the ``same`` home), then N trials in the
chosen condition, each from a random free pose (every fourth one inside the look-alike rooms)
to a random place. The robot is carried between trials without being told: every trial starts
with a kidnapping. Success = the robot says "arrived" within 0.5 m of the place. Each trial's
start, goal and noise depend only on the seed and the trial number (a closed loop is chaotic:
otherwise one trial that went differently would change every later one).
"""

from __future__ import annotations

import argparse
import json
import random
import sys
from pathlib import Path
from typing import Any

import numpy as np

from server.bench.common import stats, write_json


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--trials", type=int, default=50, help="navigation trials (default 50)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument(
        "--condition",
        choices=("same", "lighting", "moved"),
        default="same",
        help="how the home differs from when it was taught",
    )
    parser.add_argument("--max-steps", type=int, default=1500, help="frames per trial at most")
    parser.add_argument(
        "--only",
        type=_trial_list,
        default=None,
        help="run only these trials (comma-separated numbers, e.g. 2,5,14); the others are "
        "drawn but not driven, so each one starts as in the full run; most then go as they "
        "went there, not every one (docs/navigation.md)",
    )
    parser.add_argument("--json", type=Path, default=None, help="write the results here")
    parser.add_argument(
        "--set",
        dest="settings",
        metavar="NAME=VALUE",
        action="append",
        type=_setting,
        default=[],
        help="run the server with this navigation setting changed (repeatable; dotted names "
        "for nested ones, values as JSON): --set dock_second_axis=false --set "
        "motion.unstick_s=6. For ablations: the same trials with and without a change",
    )
    parser.add_argument(
        "--trace",
        type=Path,
        default=None,
        help="write every step of every trial (true pose, command, top beliefs) to "
        "DIR/trial_NNN.jsonl, to see why a trial failed",
    )


def _setting(text: str) -> tuple[str, Any]:
    name, eq, raw = text.partition("=")
    if not eq or not name.strip():
        raise argparse.ArgumentTypeError(f"--set takes NAME=VALUE, not {text!r}")
    try:
        value = json.loads(raw)
    except json.JSONDecodeError:
        value = raw  # a bare word is a string
    return name.strip(), value


def _trial_list(text: str) -> frozenset[int]:
    try:
        trials = frozenset(int(t) for t in text.split(",") if t.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--only takes trial numbers like 2,5,14, not {text!r}"
        ) from None
    if not trials or min(trials) < 0:
        raise argparse.ArgumentTypeError(f"--only takes trial numbers >= 0, not {text!r}")
    return trials


def _start_pose(world: Any, plan: Any, rng: np.random.Generator, trial: int) -> Any:
    from robot_client.sim.world import Pose

    aliases = [name for group in plan.aliases for name in group] if plan.aliases else []
    if aliases and trial % 4 == 3:
        place = next(p for p in plan.places if p.name == aliases[trial // 4 % len(aliases)])
        for _ in range(100):
            x = place.x + rng.uniform(-0.8, 0.8)
            y = place.y + rng.uniform(-0.8, 0.8)
            if not world.collides(x, y, 0.3):
                return Pose(x, y, rng.uniform(-np.pi, np.pi))
    return world.free_random_pose(rng)


def _tracer(robot: Any, out: list[dict[str, Any]]) -> Any:
    """A step hook that records the true pose, the command and the top beliefs."""

    def hook(step: int, result: Any) -> None:
        pose, c = robot.pose, result.command
        out.append(
            {
                "step": step,
                "t": round(robot.now(), 2),
                "pose": [round(pose.x, 3), round(pose.y, 3), round(pose.theta, 3)],
                "action": c.action,
                "behaviour": c.behaviour,
                "edge": c.edge,
                "target_image": c.target_image_id,
                "v": round(c.v, 3),
                "w": round(c.w, 3),
                "top": [[b.name, round(b.probability, 3)] for b in result.belief.top[:3]],
            }
        )

    return hook


def _write_trace(path: Path, rows: list[dict[str, Any]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))


def _navigation_env(settings: list[tuple[str, Any]]) -> dict[str, str]:
    """The server's environment for ``--set`` (checked here first, so a typo fails fast)."""
    from server.session import NavigationParams
    from server.tuning import tuned

    overrides = dict(settings)
    tuned(NavigationParams(), overrides)  # ValueError names what is wrong
    return {"TEACHREPEAT_NAVIGATION": json.dumps(overrides)} if overrides else {}


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from robot_client.client import TeachRepeatClient
    from robot_client.guide import teach_route
    from robot_client.sim import SimulatedRobot, SimWorld, load_plan
    from robot_client.trial import run_trial
    from server.process import scratch_server

    try:
        env = _navigation_env(args.settings)
    except ValueError as exc:
        print(f"teachrepeat bench navigate: {exc}", file=sys.stderr)
        return 2
    plan = load_plan()
    rng = random.Random(args.seed)
    np_rng = np.random.default_rng(args.seed)
    rows: list[dict[str, Any]] = []
    with (
        scratch_server("bench.sqlite", extra_env=env) as server,
        TeachRepeatClient(server.url, server.register_robot("bench")) as client,
    ):
        with SimWorld(plan, condition="same", seed=args.seed) as world:
            robot = SimulatedRobot(world, world.free_random_pose(np_rng), seed=args.seed)
            graph = teach_route(client, "bench", robot, plan, tour="home")
        print(f"taught {len(graph.locations)} places, {len(graph.edges)} edges")
        names = [p.name for p in plan.places]
        with SimWorld(plan, condition=args.condition, seed=args.seed) as world:
            robot = SimulatedRobot(world, world.free_random_pose(np_rng), seed=args.seed)
            for trial in tqdm(range(args.trials), desc=args.condition, unit="trial"):
                start = _start_pose(world, plan, np_rng, trial)
                goal = rng.choice(names)
                if args.only is not None and trial not in args.only:
                    continue  # drawn as in the full run, not driven
                robot.teleport(start)
                # every trial seeds its own noise: what happens in one trial does not change
                # the noise of the next, so two versions of the code compare trial by trial
                robot.reseed(args.seed * 1000 + trial)
                trace: list[dict[str, Any]] = []
                result = run_trial(
                    client,
                    "bench",
                    robot,
                    plan,
                    goal,
                    tour=graph,
                    max_steps=args.max_steps,
                    on_step=None if args.trace is None else _tracer(robot, trace),
                )
                if args.trace is not None:
                    _write_trace(args.trace / f"trial_{trial:03d}.jsonl", trace)
                rows.append({"trial": trial, **result.row()})
                tqdm.write(
                    f"{trial:3d} -> {goal:<12} {'ok' if result.success else result.state:9}"
                    f" {result.distance_m:5.2f} m  {result.time_s:5.0f} s"
                    f"  ratio {result.path_ratio:4.2f}  {result.reason or ''}"
                )
    successes = [r for r in rows if r["success"]]
    summary = {
        "condition": args.condition,
        "seed": args.seed,
        "settings": dict(args.settings),
        "trials": len(rows),
        "success_rate": len(successes) / len(rows) if rows else 0.0,
        "wrong_arrivals": sum(r["wrong_arrival"] for r in rows),
        "median_time_s": stats([r["time_s"] for r in successes])["p50"],
        "median_path_ratio": stats([r["path_ratio"] for r in successes])["p50"],
        "median_free_space_ratio": stats([r["free_space_ratio"] for r in successes])["p50"],
        "explore_fraction": float(np.mean([r["explore_fraction"] for r in rows])) if rows else 0.0,
        "path_ratio_definition": "driven metres / shortest taught route (free space to a place, "
        "then taught edges by their taught lengths); free_space_ratio: / A* path on the plan",
        "rows": rows,
    }
    print(
        f"{args.condition}: {len(successes)}/{len(rows)} = {summary['success_rate']:.0%} success, "
        f"{summary['wrong_arrivals']} wrong arrivals, median {summary['median_time_s']:.0f} s, "
        f"median path ratio {summary['median_path_ratio']:.2f}"
    )
    write_json(args.json, summary)
    return 0
