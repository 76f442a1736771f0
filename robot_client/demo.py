"""``teachrepeat demo``: the whole product in a simulated home.

1. Starts the server on the embedded SQLite default (``data/teachrepeat.sqlite``) with the
   dashboard, and prints the dashboard's address first: open it to watch what the robot
   believes while it is taught and while it drives.
2. Registers a simulated robot and has a scripted guide teach it the home (``--plan``, default
   the packaged apartment; reused on later runs unless ``--reteach`` or the plan changed).
3. Carries the robot to a random spot, then sends it to three places in turn, with a progress
   bar per trip and a summary at the end.
4. Keeps serving until Ctrl-C so the dashboard can still be looked at (``--exit`` ends at once;
   ``--no-dashboard`` runs without the dashboard, for scripts and CI).
"""

from __future__ import annotations

import argparse
import os
import random
import threading
from pathlib import Path

import numpy as np

from robot_client.client import ApiError, TeachRepeatClient
from robot_client.sim.check_plan import add_plan_argument
from robot_client.sim.floorplan import CONDITIONS

DEMO_ROBOT = "sim-robot"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--db", type=Path, help="SQLite file (default: data/teachrepeat.sqlite)")
    add_plan_argument(parser)
    parser.add_argument("--seed", type=int, default=None, help="random seed (default: random)")
    parser.add_argument(
        "--condition",
        choices=CONDITIONS,
        default="same",
        help="how the home differs from when it was taught",
    )
    parser.add_argument("--goals", type=int, default=3, help="places to visit in turn")
    parser.add_argument("--reteach", action="store_true", help="teach the tour again")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.add_argument(
        "--no-dashboard", action="store_true", help="run without the dashboard (scripts, CI)"
    )
    parser.add_argument(
        "--exit",
        action="store_true",
        help="end when the robot is done instead of serving until Ctrl-C",
    )


def _robot_token(admin: TeachRepeatClient, token_file: Path) -> str:
    """Register the demo robot once; its token is kept beside the database (mode 0600)."""
    if token_file.exists():
        return token_file.read_text().strip()
    try:
        token = admin.register_robot(DEMO_ROBOT).token
    except ApiError as exc:
        raise SystemExit(
            f"robot {DEMO_ROBOT!r} is registered but its token file {token_file} is gone; "
            "delete the database or pass --db to start afresh"
        ) from exc
    fd = os.open(token_file, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.write(token + "\n")
    return token


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from robot_client.guide import rehearse, teach_route
    from robot_client.sim import SimulatedRobot, SimWorld
    from robot_client.sim.check_plan import load_plans_or_exit
    from robot_client.trial import run_trial
    from server.config import Settings
    from server.process import start_server
    from server.serve import admin_token_for

    if args.goals < 1:
        print("teachrepeat demo: --goals must be at least 1")
        return 2
    plan = load_plans_or_exit([args.plan], "teachrepeat demo")[0]  # before anything starts
    settings = Settings(**({"db": args.db} if args.db else {}))
    admin_token = admin_token_for(settings).get_secret_value()
    seed = args.seed if args.seed is not None else random.SystemRandom().randrange(10_000)
    rng = random.Random(seed)
    server = start_server(settings.db, admin_token=admin_token, dashboard=not args.no_dashboard)
    if server.dashboard_url:
        print(f"dashboard        {server.dashboard_url}   <- open it to watch the robot")
    print(f"teachrepeat API  {server.url}   (docs: {server.url}/docs)")
    print(f"database         {settings.db}")
    print(f"home             {plan.name} ({plan.source})")
    print(f"seed {seed}, condition {args.condition!r}")
    tour_name = f"demo {plan.name} {plan.sha256[:8]}"  # a changed plan file is taught afresh
    results = []
    ok = 0
    try:
        with TeachRepeatClient(server.url, admin_token) as admin:
            token = _robot_token(admin, settings.db.parent / f"{DEMO_ROBOT}.token")
        with (
            TeachRepeatClient(server.url, token, retries=3) as client,
            SimWorld(plan, condition="same", seed=seed) as teach_world,
        ):
            tours = {t.name: t for t in client.tours()}
            if tour_name not in tours or tours[tour_name].edges == 0 or args.reteach:
                name = tour_name
                if tour_name in tours:
                    name = f"{tour_name} ({len(tours) + 1})"
                start = teach_world.free_random_pose(np.random.default_rng(seed))
                robot = SimulatedRobot(teach_world, start, seed=seed)
                walk = rehearse(plan)
                with tqdm(
                    desc="teaching", total=walk.uploads, unit="image", disable=args.quiet
                ) as bar:

                    def tick(what: str) -> None:
                        bar.update(1)
                        bar.set_postfix_str(what, refresh=False)

                    graph = teach_route(client, DEMO_ROBOT, robot, plan, tour=name, on_frame=tick)
                print(
                    f"taught {graph.name!r}: {len(graph.locations)} places, "
                    f"{len(graph.edges)} edges, "
                    f"{sum(e.image_count for e in graph.edges)} path images"
                )
                tour_id = graph.id
            else:
                tour_id = tours[tour_name].id
                print(f"reusing the taught tour {tour_name!r} (--reteach to teach it again)")

        with (
            TeachRepeatClient(server.url, token, retries=3) as client,
            SimWorld(plan, condition=args.condition, seed=seed) as world,
        ):
            np_rng = np.random.default_rng(seed)
            robot = SimulatedRobot(world, world.free_random_pose(np_rng), seed=seed)
            p = robot.pose
            print(f"carried the robot to ({p.x:.1f}, {p.y:.1f}); it does not know where it is")
            names = [pl.name for pl in plan.places]
            goals: list[str] = []
            for _ in range(args.goals):
                goals.append(rng.choice([n for n in names if not goals or n != goals[-1]]))
            taught = client.tour(tour_id)
            client.goto(DEMO_ROBOT, goals[0], tour=tour_id)
            for goal in goals:
                with tqdm(desc=f"to {goal}", unit="step", disable=args.quiet) as bar:

                    def show(step: int, result: object, bar: tqdm = bar) -> None:
                        bar.update(1)
                        top = result.belief.top[0]  # type: ignore[attr-defined]
                        action = result.command.action  # type: ignore[attr-defined]
                        bar.set_postfix_str(f"{action}, thinks: {top.name} {top.probability:.2f}")

                    result = run_trial(
                        client, DEMO_ROBOT, robot, plan, goal, tour=taught, on_step=show
                    )
                results.append(result)
                verdict = "arrived" if result.success else f"{result.state} ({result.reason})"
                print(
                    f"  {goal}: {verdict}, {result.distance_m:.2f} m from the place, "
                    f"{result.time_s:.0f} s of robot time, {result.driven_m:.1f} m driven"
                )
        print("\nsummary (time: seconds of robot time, as the simulated robot lived them)")
        width = max(len("goal"), *(len(r.goal) for r in results))
        print(
            f"{'goal':<{width}} {'result':<10} {'off by':>7} {'time':>7} {'driven':>7} "
            f"{'shortest':>9}"
        )
        for r in results:
            print(
                f"{r.goal:<{width}} {('ok' if r.success else r.state):<10} {r.distance_m:>6.2f}m "
                f"{r.time_s:>6.0f}s {r.driven_m:>6.1f}m {r.shortest_m:>8.1f}m"
            )
        ok = sum(r.success for r in results)
        print(f"{ok} of {len(results)} places reached")
        if not args.exit:
            where = f" on the dashboard at {server.dashboard_url}" if server.dashboard_url else ""
            print(f"\nthe server keeps running{where}; Ctrl-C ends the demo")
            _wait_for_interrupt()
    finally:
        server.stop()
    return 0 if ok == len(results) else 1


def _wait_for_interrupt() -> None:
    """Block until Ctrl-C (or SIGTERM, which the command line turns into SystemExit)."""
    try:
        threading.Event().wait()
    except KeyboardInterrupt:
        print()
