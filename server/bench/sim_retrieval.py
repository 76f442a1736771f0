"""``teachrepeat bench sim-retrieval``: which taught image does a frame match, in the simulated
home, when the light or the furniture has changed since the tour?

The guide walks the teaching route in-process (no server), keeping every frame and spin image
with its ground-truth pose. Then, for each condition (``same``, ``lighting``, ``moved``), the
camera is put at the same random free poses and the engine is asked for the best-matching
image. A query counts when some taught image was taken within ``--radius`` metres and
``--angle`` degrees of its pose; it is right when the best image is one of those
(``image_recall@1``), or when the best *state* (location or edge) holds one of them
(``state_recall@1``). Compared side by side: grey-world colour normalisation on and off, with
the weights learned for the tour and with the fixed lighting-robust weights.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from server.bench.common import write_json

if TYPE_CHECKING:
    from robot_client.sim.floorplan import FloorPlan
    from server.vision.features import DescriptorKind

CONDITIONS = ("same", "lighting", "moved")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from robot_client.sim.check_plan import add_plan_argument

    add_plan_argument(parser)
    parser.add_argument("--queries", type=int, default=300, help="random poses (default 300)")
    parser.add_argument("--seed", type=int, default=7, help="random seed of the poses")
    parser.add_argument(
        "--route",
        default=None,
        help="comma-separated places the guide walks (default: the plan's teaching route)",
    )
    parser.add_argument("--radius", type=float, default=0.5, help="metres (default 0.5)")
    parser.add_argument("--angle", type=float, default=30.0, help="degrees (default 30)")
    parser.add_argument("--json", type=Path, default=None, help="write the results here")


@dataclass(frozen=True)
class Shot:
    """One rendered image and where it was taken."""

    image: npt.NDArray[np.uint8]
    x: float
    y: float
    theta: float


def _jpeg(image: npt.NDArray[np.uint8], quality: int) -> npt.NDArray[np.uint8]:
    """Through JPEG and back, as every image reaches the server."""
    import cv2

    from server.imaging import encode_jpeg

    data = np.frombuffer(encode_jpeg(image, quality), np.uint8)
    return np.asarray(cv2.imdecode(data, cv2.IMREAD_COLOR), np.uint8)


def teach(plan: FloorPlan, route: tuple[str, ...]) -> tuple[list[Shot], list[str]]:
    """The tour's images with their poses and state keys (``place`` or ``from->to``)."""
    from robot_client.guide import GuideParams, guided_tour_steps
    from robot_client.sim import SimulatedRobot, SimWorld
    from robot_client.sim.world import Pose

    params = GuideParams()
    shots: list[Shot] = []
    keys: list[str] = []
    with SimWorld(plan, condition="same", seed=0) as world:
        first = next(p for p in plan.places if p.name == route[0])
        robot = SimulatedRobot(world, Pose(first.x, first.y, first.yaw), seed=0)
        previous = route[0]
        for item in guided_tour_steps(robot, plan, route, params):
            if item.kind == "mark":
                previous = item.place
                continue
            image = robot.read()
            if image is None:
                raise RuntimeError("the simulated camera returned no frame")
            p = robot.pose
            shots.append(Shot(_jpeg(image, params.jpeg_quality), p.x, p.y, p.theta))
            keys.append(item.place if item.kind == "spin" else f"{previous}->{item.place}")
    return shots, keys


def queries(plan: FloorPlan, n: int, seed: int) -> dict[str, list[Shot]]:
    """The same ``n`` random free poses rendered in every condition (camera noise, JPEG)."""
    from robot_client.sim import SimWorld

    rng = np.random.default_rng(seed)
    with SimWorld(plan, condition="same", seed=seed) as world:
        poses = [world.free_random_pose(rng) for _ in range(n)]
    out: dict[str, list[Shot]] = {}
    for condition in CONDITIONS:
        noise = np.random.default_rng(seed + 1)
        shots = []
        with SimWorld(plan, condition=condition, seed=seed) as world:
            for p in poses:
                img = world.render(p).astype(np.float32) + noise.normal(0, 2.0, (240, 320, 3))
                clean = np.clip(img, 0, 255).astype(np.uint8)
                shots.append(Shot(_jpeg(clean, 85), p.x, p.y, p.theta))
        out[condition] = shots
    return out


def evaluate(
    tour: list[Shot],
    keys: list[str],
    qs: dict[str, list[Shot]],
    *,
    colour_constancy: bool,
    weights: str,
    radius: float,
    angle_deg: float,
    descriptor: DescriptorKind = "grad36",
) -> dict[str, Any]:
    """Recall of one engine configuration in every condition (``descriptor``:
    ``FeatureParams.descriptor``)."""
    from server.navigation import ROBUST_WEIGHTS
    from server.vision.features import FeatureParams, extract
    from server.vision.index import EngineParams, TourIndex
    from server.vision.learning import learn_weights

    fp = FeatureParams(colour_constancy=colour_constancy, descriptor=descriptor)
    ep = EngineParams(features=fp)
    names = sorted(set(keys))
    state_of = {k: i for i, k in enumerate(names)}
    states = np.array([state_of[k] for k in keys])
    tx = np.array([s.x for s in tour])
    ty = np.array([s.y for s in tour])
    tt = np.array([s.theta for s in tour])
    index = TourIndex(ep)
    index.add([extract(s.image, fp) for s in tour], states)
    w = learn_weights(index, params=ep) if weights == "learned" else np.array(ROBUST_WEIGHTS)
    index.set_weights(w)
    result: dict[str, Any] = {"weights": [round(float(x), 3) for x in w]}
    for condition, shots in qs.items():
        hits_image = hits_state = counted = 0
        for q in shots:
            turn = np.abs((tt - q.theta + np.pi) % (2 * np.pi) - np.pi)
            near = (np.hypot(tx - q.x, ty - q.y) <= radius) & (turn <= math.radians(angle_deg))
            if not near.any():
                continue
            counted += 1
            sim = index.query(extract(q.image, fp), n_states=len(names))
            hits_image += bool(near[int(np.argmax(sim.image))])
            hits_state += int(np.argmax(sim.state)) in set(states[near].tolist())
        result[condition] = {
            "image_recall@1": hits_image / counted if counted else math.nan,
            "state_recall@1": hits_state / counted if counted else math.nan,
            "queries": counted,
        }
    return result


def run(args: argparse.Namespace) -> int:
    from robot_client.guide import check_route
    from robot_client.sim.check_plan import load_plans_or_exit
    from robot_client.sim.route import teaching_route

    plan = load_plans_or_exit([args.plan], "teachrepeat bench sim-retrieval")[0]
    route = (
        tuple(s.strip() for s in args.route.split(",") if s.strip())
        if args.route
        else teaching_route(plan)
    )
    try:
        check_route(plan, route)
    except ValueError as exc:
        print(f"teachrepeat bench sim-retrieval: --route {exc}")
        return 2
    t0 = time.perf_counter()
    tour, keys = teach(plan, route)
    qs = queries(plan, args.queries, args.seed)
    print(f"tour: {len(tour)} images, {len(set(keys))} states; {args.queries} poses per condition")
    configs: dict[str, Any] = {}
    for constancy in (True, False):
        for weights in ("learned", "robust"):
            name = f"{'grey_world' if constancy else 'raw'}/{weights}"
            res = evaluate(
                tour,
                keys,
                qs,
                colour_constancy=constancy,
                weights=weights,
                radius=args.radius,
                angle_deg=args.angle,
            )
            configs[name] = res
            cells = "  ".join(
                f"{c} {res[c]['image_recall@1']:.2f}/{res[c]['state_recall@1']:.2f}"
                for c in CONDITIONS
            )
            print(f"{name:20s} image/state recall@1: {cells}  (n={res['same']['queries']})")
    write_json(
        args.json,
        {
            "plan": Path(plan.source).name,
            "plan_name": plan.name,
            "plan_sha256": plan.sha256,
            "route": list(route),
            "tour_images": len(tour),
            "poses": args.queries,
            "seed": args.seed,
            "radius_m": args.radius,
            "angle_deg": args.angle,
            "configs": configs,
            "seconds": time.perf_counter() - t0,
        },
    )
    return 0
