"""``teachrepeat sim check-plan FILE [--png OUT]``: for people writing homes.

Checks the plan as ``demo`` and the benchmarks do (:func:`robot_client.sim.floorplan.load_plan`)
and lists every problem at once, each with its JSON path; exits 2 when there is one. On a good
plan it prints the teaching route (the plan's own, or derived) with the length of every leg and
what teaching it takes, and with ``--png`` draws a top-down map (rooms, doorways, furniture,
places, the route's legs) and, beside it, a contact sheet of the camera's view at every place.
"""

from __future__ import annotations

import argparse
import itertools
import sys
from collections.abc import Sequence
from pathlib import Path

from robot_client.sim.floorplan import FloorPlan, PlanError, load_plan


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("plan", type=Path, metavar="FILE", help="floor plan JSON file")
    parser.add_argument(
        "--png",
        type=Path,
        default=None,
        metavar="OUT",
        help="draw the map with the route to OUT and the view at every place to OUT_places.png",
    )


def add_plan_argument(parser: argparse.ArgumentParser, *, several: bool = False) -> None:
    """``--plan FILE`` (``several``: ``--plan FILE [FILE ...]``), default ``None``: the
    packaged apartment; read with :func:`load_plans_or_exit`."""
    parser.add_argument(
        "--plan",
        nargs="+" if several else None,
        type=Path,
        default=None,
        metavar="FILE",
        help="floor plan JSON file"
        + ("s" if several else " of the home")
        + " (default: the packaged apartment)",
    )


def load_plans_or_exit(paths: Sequence[Path | None], prog: str) -> list[FloorPlan]:
    """Load and check every plan (``None``: the packaged apartment); on a problem print them
    all, as ``check-plan`` does, and exit with status 2."""
    plans, failed = [], False
    for path in paths:
        try:
            plans.append(load_plan(path))
        except PlanError as exc:
            print(f"{prog}: {exc}", file=sys.stderr)
            failed = True
    if failed:
        raise SystemExit(2)
    return plans


def run(args: argparse.Namespace) -> int:
    from robot_client.guide import rehearse
    from robot_client.sim.route import leg_lengths_m, teaching_route

    plan = load_plans_or_exit([args.plan], "teachrepeat sim check-plan")[0]
    route = teaching_route(plan)
    legs = leg_lengths_m(plan, route)
    walk = rehearse(plan, route)
    moving = sum(f.moved is not None for f in plan.furniture)
    print(
        f"{args.plan}: plan {plan.name!r} is good (sha256 {plan.sha256[:12]}): "
        f"{len(plan.rooms)} rooms, {len(plan.doors)} doors, {len(plan.furniture)} pieces of "
        f"furniture ({moving} move under 'moved'), {len(plan.places)} places"
    )
    how = "from the plan" if plan.route else "derived: every pair of neighbouring places both ways"
    print(
        f"teaching route ({how}): {len(legs)} legs, {sum(legs):.1f} m; teaching uploads about "
        f"{walk.uploads} images over {walk.seconds / 60:.1f} min of robot time"
    )
    for k, ((a, b), m) in enumerate(zip(itertools.pairwise(route), legs, strict=True), start=1):
        print(f"  {k:3d}. {a} -> {b}  {m:.1f} m")
    if args.png is not None:
        for path in draw(plan, route, args.png):
            print(f"wrote {path}")
    return 0


def draw(plan: FloorPlan, route: Sequence[str], out: Path) -> list[Path]:
    """The map with the route's legs (``out``) and the view at every place (``out`` with
    ``_places`` before its suffix)."""
    import cv2

    from robot_client.sim.figures import contact_sheet, label_image
    from robot_client.sim.paths import GUIDE_CLEARANCE_M, shortest_path
    from robot_client.sim.world import Pose, SimWorld, draw_map

    places = {p.name: p for p in plan.places}
    seen: set[frozenset[str]] = set()
    legs = []
    for a, b in itertools.pairwise(route):
        if frozenset((a, b)) in seen:
            continue  # the way back is drawn on the same line
        seen.add(frozenset((a, b)))
        pa, pb = places[a], places[b]
        legs.append(shortest_path(plan, (pa.x, pa.y), (pb.x, pb.y), clearance=GUIDE_CLEARANCE_M))
    out.parent.mkdir(parents=True, exist_ok=True)
    sheet = out.with_name(f"{out.stem}_places{out.suffix or '.png'}")
    with SimWorld(plan) as world:
        cv2.imwrite(str(out), draw_map(world, legs=legs))
        views = [label_image(world.render(Pose(p.x, p.y, p.yaw)), p.name) for p in plan.places]
    cv2.imwrite(str(sheet), contact_sheet(views, min(4, len(views))))
    return [out, sheet]
