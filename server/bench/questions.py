"""``teachrepeat bench questions``: how well "are we at the kitchen?" is asked while teaching.

For each simulated home, the guide walks the plan's whole teaching route (every place visited
more than once) on a real server with ``questions.teaching`` on, twice:

* **marked**: every arrival is named, as today. Every question raised is scored by the
  simulator's truth: *near* when the robot stood within ``--near`` metres of the place asked
  about (it was arriving there; the mark then withdraws it), *false* otherwise.
* **unmarked revisits**: a place's second and later arrivals are not named; the robot stands
  there for up to ``--wait`` frames (the camera's view, sent again). A question about a place
  the robot is within ``--near`` metres of is answered yes (the loop closes there, teaching
  goes on; on the way in, before the robot stopped, counts too), any other no; a revisit with
  no yes in time is a *miss* (the guide then names the place).

Nothing here is tuned: the run reports the defaults of ``QuestionParams``.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any

from server.bench.common import write_json
from server.tuning import add_set_argument


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--plan", type=Path, nargs="+", default=None, help="floor plans (default: apartment)"
    )
    parser.add_argument("--seed", type=int, default=0, help="simulator seed (default 0)")
    parser.add_argument(
        "--near", type=float, default=1.0, help="metres from the place that count as at it"
    )
    parser.add_argument(
        "--wait", type=int, default=15, help="frames a robot stands at an unnamed place"
    )
    parser.add_argument(
        "--modes",
        nargs="+",
        choices=("marked", "unmarked"),
        default=["marked", "unmarked"],
        help="every arrival named, revisits unnamed, or both (default)",
    )
    add_set_argument(parser, "a navigation setting for the server (questions.same_place_mass=0.8)")
    parser.add_argument("--json", type=Path, default=None, help="write the results here")


def _view_fit(client: Any, frame_id: int | None, place_image: int | None) -> tuple[int, float]:
    """Inliers and scale of :func:`homing_scale` between the frame a question was asked at and
    the place's image it matched (0, 0.0 when either is gone or no fit)."""
    from server.imaging import ImageLimits, decode_jpeg
    from server.vision.features import extract
    from server.vision.homing import homing_scale

    if frame_id is None or place_image is None:
        return 0, 0.0
    limits = ImageLimits()
    a, b = (extract(decode_jpeg(client.image(i), limits)[0]) for i in (frame_id, place_image))
    fit = homing_scale(a, b)
    return (0, 0.0) if fit is None else (fit.inliers, round(fit.scale, 3))


def _home(
    plan_path: Path | None,
    seed: int,
    near: float,
    wait: int,
    marked: bool,
    settings: dict[str, Any],
) -> dict[str, Any]:
    """Teach one home's route once (``marked``: every arrival named) and score the questions."""
    from robot_client.client import TeachRepeatClient
    from robot_client.guide import guided_tour_steps, recorded_steps
    from robot_client.sim import SimulatedRobot, SimWorld, load_plan
    from robot_client.sim.route import teaching_route
    from robot_client.sim.world import Pose
    from server.imaging import encode_jpeg
    from server.process import scratch_server

    plan = load_plan(plan_path)
    route = teaching_route(plan)
    env = {"TEACHREPEAT_NAVIGATION": json.dumps({"questions.teaching": True, **settings})}
    asked: list[dict[str, Any]] = []
    revisits = hits = misses = wrong = 0
    started = time.perf_counter()
    with (
        scratch_server("questions.sqlite", extra_env=env) as server,
        TeachRepeatClient(server.url, server.register_robot("guide")) as client,
        SimWorld(plan, condition="same", seed=seed) as world,
    ):
        first = plan.place(route[0])
        robot = SimulatedRobot(world, Pose(first.x, first.y, first.yaw), seed=seed)
        client.start_teaching("guide", client.tour_named("bench", create=True).id)
        seen_ids: set[int] = set()
        visited: set[str] = set()
        pose = (first.x, first.y)
        t = 0.0
        frames = 0

        closed: list[str] = []  # places closed on a yes since the last revisit

        def answer_all() -> None:
            """Yes to a question about the place the robot is at (within ``near``), else no."""
            nonlocal wrong
            for q in new_questions():
                place = plan.place(q.location)
                yes = math.hypot(pose[0] - place.x, pose[1] - place.y) <= near
                client.answer("guide", q.id, "yes" if yes else "no")
                if yes:
                    closed.append(q.location)
                else:
                    wrong += 1

        def new_questions() -> list[Any]:
            found = [q for q in client.questions("guide") if q.id not in seen_ids]
            for q in found:
                seen_ids.add(q.id)
                place = plan.place(q.location)
                distance = math.hypot(pose[0] - place.x, pose[1] - place.y)
                inliers, scale = _view_fit(client, q.image_id, q.match_image_id)
                asked.append(
                    {
                        "inliers": inliers,
                        "scale": scale,
                        "place": q.location,
                        "confidence": q.confidence,
                        "distance_m": round(distance, 3),
                        "near": distance <= near,
                        "frame": frames,
                    }
                )
            return found

        for item in recorded_steps(robot, guided_tour_steps(robot, plan, route)):
            if item.kind == "mark":
                if marked or item.place not in visited:
                    client.mark_location("guide", item.place)
                    visited.add(item.place)
                    continue
                revisits += 1
                for _ in range(wait):
                    if item.place in closed:
                        break
                    image = robot.read()
                    assert image is not None
                    t += 0.1
                    client.upload_frame("guide", encode_jpeg(image), timestamp=t)
                    frames += 1
                    answer_all()
                if item.place in closed:
                    hits += 1
                else:
                    misses += 1
                    client.mark_location("guide", item.place)
                closed.clear()
                continue
            assert item.jpeg is not None
            t = max(t + 1e-3, item.t)
            if item.pose is not None:
                pose = (item.pose[0], item.pose[1])
            if item.kind == "spin":
                client.upload_spin_image("guide", item.jpeg, timestamp=t, v=item.v, w=item.w)
            else:
                client.upload_frame("guide", item.jpeg, timestamp=t, v=item.v, w=item.w)
                frames += 1
                if marked:
                    new_questions()
                else:
                    answer_all()
        if client.state("guide").teaching.open_path_images:  # type: ignore[union-attr]
            # the loop closed on the way in, before the route's last arrival: its last frames
            # end nowhere
            graph = client.abort_teaching("guide").tour
        else:
            graph = client.finish_teaching("guide").tour
    return {
        "plan": plan.name,
        "marked": marked,
        "frames": frames,
        "questions": len(asked),
        "near": sum(a["near"] for a in asked),
        "false": sum(not a["near"] for a in asked),
        "revisits": revisits,
        "closed_on_yes": hits,
        "missed": misses,
        "answered_no": wrong,
        "places": len(graph.locations),
        "edges": len(graph.edges),
        "seconds": round(time.perf_counter() - started, 1),
        "asked": asked,
    }


def run(args: argparse.Namespace) -> int:
    plans: list[Path | None] = list(args.plan) if args.plan else [None]
    results = []
    for plan in plans:
        for marked in [m == "marked" for m in args.modes]:
            r = _home(plan, args.seed, args.near, args.wait, marked, dict(args.settings or []))
            results.append(r)
            if marked:
                print(
                    f"{r['plan']}, every arrival named: {r['questions']} questions over "
                    f"{r['frames']} frames, {r['near']} within {args.near} m of the place asked "
                    f"about, {r['false']} elsewhere ({r['seconds']} s)"
                )
            else:
                print(
                    f"{r['plan']}, revisits unnamed: {r['closed_on_yes']} of {r['revisits']} "
                    f"revisits asked about and closed on yes, {r['missed']} missed, "
                    f"{r['answered_no']} questions about another place; {r['places']} places, "
                    f"{r['edges']} paths ({r['seconds']} s)"
                )
    summary = {
        "seed": args.seed,
        "near_m": args.near,
        "wait": args.wait,
        "settings": dict(args.settings or []),
        "runs": results,
    }
    write_json(args.json, summary)
    return 0
