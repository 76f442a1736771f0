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

With ``--offsets M [M ...]`` the camera is put beside the taught path instead: from taught path
frames picked by ``--seed``, moved ``M`` metres sideways (left for half the views, right for the
other half) and turned up to ``--turn-deg`` degrees off the taught heading. Per offset and
condition it reports how many views retrieve the nearest taught image (within ``--radius`` and
``--angle`` of the source frame's pose) *and* share at least ``--min-inliers`` RANSAC
homography inliers with it (mutual nearest-neighbour corners,
:meth:`~server.vision.index.TourIndex.geometric_inliers`). The engine is the server's default,
with the weights the server would use for the tour.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from server.bench.common import write_json

if TYPE_CHECKING:
    from robot_client.sim.floorplan import FloorPlan
    from robot_client.sim.world import Pose, SimWorld
    from server.vision.features import DescriptorKind, FeatureParams
    from server.vision.index import TourIndex

CONDITIONS = ("same", "lighting", "moved")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from robot_client.sim.check_plan import add_plan_argument

    add_plan_argument(parser)
    parser.add_argument(
        "--queries",
        type=int,
        default=300,
        help="random poses, or with --offsets taught path frames to move (default 300)",
    )
    parser.add_argument("--seed", type=int, default=7, help="random seed of the poses")
    parser.add_argument(
        "--offsets",
        type=float,
        nargs="+",
        default=None,
        metavar="M",
        help="put the camera M metres beside the taught path instead of at random poses",
    )
    parser.add_argument(
        "--condition",
        nargs="+",
        choices=CONDITIONS,
        default=None,
        help="conditions to query in (default: all three; with --offsets: same)",
    )
    parser.add_argument(
        "--turn-deg",
        type=float,
        default=30.0,
        help="with --offsets: largest turn off the taught heading, degrees (default 30)",
    )
    parser.add_argument(
        "--min-inliers",
        type=int,
        default=10,
        help="with --offsets: RANSAC inliers a match needs (default 10)",
    )
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


def camera_shot(world: SimWorld, pose: Pose, noise: np.random.Generator) -> Shot:
    """The frame at ``pose`` as a query reaches the engine: Gaussian camera noise (2 grey
    levels) from ``noise``, then JPEG at quality 85."""
    img = world.render(pose).astype(np.float32) + noise.normal(0, 2.0, (240, 320, 3))
    clean = np.clip(img, 0, 255).astype(np.uint8)
    return Shot(_jpeg(clean, 85), pose.x, pose.y, pose.theta)


def queries(
    plan: FloorPlan, n: int, seed: int, conditions: Sequence[str] = CONDITIONS
) -> dict[str, list[Shot]]:
    """The same ``n`` random free poses rendered in every condition (camera noise, JPEG)."""
    from robot_client.sim import SimWorld

    rng = np.random.default_rng(seed)
    with SimWorld(plan, condition="same", seed=seed) as world:
        poses = [world.free_random_pose(rng) for _ in range(n)]
    out: dict[str, list[Shot]] = {}
    for condition in conditions:
        noise = np.random.default_rng(seed + 1)
        with SimWorld(plan, condition=condition, seed=seed) as world:
            out[condition] = [camera_shot(world, p, noise) for p in poses]
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


# ---------------------------------------------------------------- viewpoint change (--offsets)


def offset_label(offset_m: float) -> str:
    """The JSON key of an offset: metres as written, ``.`` as ``_``, then ``m``.

    ``0.25 -> "0_25m"``, ``0.5 -> "0_5m"``, ``1.0 -> "1m"``, ``1.5 -> "1_5m"``, ``0 -> "0m"``
    (rounded to micrometres)."""
    if not (math.isfinite(offset_m) and offset_m >= 0):
        raise ValueError(f"an offset is a finite distance >= 0 in metres, got {offset_m}")
    text = f"{offset_m:.6f}".rstrip("0").rstrip(".")
    return text.replace(".", "_") + "m"


def side_poses(
    sources: Sequence[Pose],
    offset_m: float,
    *,
    seed: int,
    is_free: Callable[[float, float], bool],
    turn_deg: float = 30.0,
    step_m: float = 0.05,
) -> list[Pose | None]:
    """Camera poses ``offset_m`` metres beside each of ``sources``, turned off its heading.

    From ``seed`` alone (so every offset moves a source to the same side and turns it by the
    same angle): a side per source, left (``+90`` degrees from its heading) for half of them and
    right for the other half in random order, and a turn drawn uniformly in
    ``[-turn_deg, +turn_deg]``. A side is taken when ``is_free`` holds at every point of the
    sideways move (sampled at most ``step_m`` apart, both ends included): the camera stays in
    free space on the way and does not pass through a wall into the next room. Otherwise the
    other side is tried; when neither is free the view is ``None``.

    Args:
        sources: ``(n,)`` taught poses (metres, radians).
        offset_m: sideways distance, metres, >= 0 (0: the source position, turned).
        seed: random seed of the sides and turns.
        is_free: whether a camera (robot) may stand at ``(x, y)`` metres.
        turn_deg: largest turn off the source heading, degrees.
        step_m: largest spacing of the free-space samples along the move, metres.

    Returns:
        ``n`` poses (heading wrapped to ``[-pi, pi)``), ``None`` where both sides are blocked.
    """
    from robot_client.sim.world import Pose

    if not (math.isfinite(offset_m) and offset_m >= 0):
        raise ValueError(f"offset_m must be a finite distance >= 0, got {offset_m}")
    if step_m <= 0:
        raise ValueError(f"step_m must be > 0, got {step_m}")
    if not 0 <= turn_deg <= 180:
        raise ValueError(f"turn_deg must lie in [0, 180] degrees, got {turn_deg}")
    n = len(sources)
    rng = np.random.default_rng(seed)
    sides = 1 - 2 * rng.permutation(np.arange(n) % 2)  # +1 left, -1 right
    turns = rng.uniform(-math.radians(turn_deg), math.radians(turn_deg), n)
    fractions = np.linspace(0.0, 1.0, max(2, math.ceil(offset_m / step_m) + 1))
    out: list[Pose | None] = []
    for src, side, turn in zip(sources, sides, turns, strict=True):
        pose = None
        for s in (int(side), -int(side)):
            ux, uy = -math.sin(src.theta) * s, math.cos(src.theta) * s
            if all(
                is_free(src.x + f * offset_m * ux, src.y + f * offset_m * uy) for f in fractions
            ):
                theta = (src.theta + float(turn) + math.pi) % (2 * math.pi) - math.pi
                pose = Pose(src.x + offset_m * ux, src.y + offset_m * uy, theta)
                break
        out.append(pose)
    return out


def canonical_order(keys: Sequence[str]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """The tour's shots in the order the server's index holds them
    (:class:`server.domain.TourGraph`): every place's spin images, places in the order they
    were first visited, then the frames of every traversal of a path (an edge), in the order
    walked.

    Args:
        keys: ``(n,)`` state key of every shot as :func:`teach` gives them (``place`` for a
            spin image, ``from->to`` for a path frame), in the order taken.

    Returns:
        ``order`` ``(n,) int64``: ``order[k]`` is the shot stored as image ``k``; ``states``
        ``(n,) int64``: the upper state of image ``k`` (places ``0..L-1``, then one per
        traversal).
    """
    places: dict[str, int] = {}
    spins: list[list[int]] = []
    traversals: list[list[int]] = []
    previous: str | None = None
    for i, key in enumerate(keys):
        if "->" in key:
            if key != previous:
                traversals.append([])
            traversals[-1].append(i)
        else:
            if key not in places:
                places[key] = len(spins)
                spins.append([])
            spins[places[key]].append(i)
        previous = key
    order: list[int] = []
    states: list[int] = []
    for state, group in enumerate(spins + traversals):
        order.extend(group)
        states.extend([state] * len(group))
    return np.asarray(order, np.int64), np.asarray(states, np.int64)


def server_index(
    tour: Sequence[Shot], keys: Sequence[str]
) -> tuple[TourIndex, npt.NDArray[np.int64], FeatureParams]:
    """The tour's index as the server builds it for navigation: its default
    :class:`~server.navigation.NavigationParams` (features, engine), the canonical image order
    and the signature weights it would use (``signature_weights``, or when ``None`` those
    :func:`~server.vision.learning.learn_weights` learns for the tour, as
    ``NavigationService._weights`` does).

    Returns:
        the index, ``order`` (``order[k]`` = shot of image ``k``) and the feature parameters
        to extract queries with.
    """
    from server.navigation import NavigationParams
    from server.vision.features import extract
    from server.vision.index import TourIndex
    from server.vision.learning import learn_weights

    nav = NavigationParams()
    order, states = canonical_order(keys)
    index = TourIndex(nav.engine)
    index.add([extract(tour[i].image, nav.features) for i in order], states)
    chosen = nav.signature_weights
    weights = learn_weights(index, params=nav.engine) if chosen is None else chosen
    index.set_weights(np.asarray(weights, np.float64))
    return index, order, nav.features


@dataclass(frozen=True)
class OffsetView:
    """One query beside the taught path and what the engine made of it.

    Attributes:
        source: the taught path frame (index into the tour's shots) the camera was moved from.
        offset_m: sideways distance, metres. condition: ``same``, ``lighting`` or ``moved``.
        pose: where the camera stood (metres, radians).
        best: the shot the engine ranked first (argmax of ``Similarity.image``).
        retrieved: ``best`` is the source or within the tolerance of the source's pose.
        inliers: RANSAC homography inliers between the query and ``best``.
    """

    source: int
    offset_m: float
    condition: str
    pose: Pose
    best: int
    retrieved: bool
    inliers: int


def offset_summary(
    views: Sequence[OffsetView], skipped: int, *, min_inliers: int
) -> dict[str, Any]:
    """One cell of the report: ``matched_fraction`` (retrieved and at least ``min_inliers``
    inliers), ``retrieved_fraction``, ``geometric_fraction``, each over the ``views`` rendered,
    with ``matched_ci95`` (Wilson); ``views``, ``skipped`` (no free side) and
    ``median_inliers``. Fractions are NaN without views."""
    from server.bench.common import wilson_interval

    n = len(views)
    retrieved = np.array([v.retrieved for v in views], bool)
    inliers = np.array([v.inliers for v in views], np.int64)
    geometric = inliers >= min_inliers
    matched = int((retrieved & geometric).sum())
    lo, hi = wilson_interval(matched, n)
    return {
        "matched_fraction": matched / n if n else math.nan,
        "retrieved_fraction": float(retrieved.mean()) if n else math.nan,
        "geometric_fraction": float(geometric.mean()) if n else math.nan,
        "matched_ci95": [lo, hi],
        "views": n,
        "skipped": skipped,
        "median_inliers": float(np.median(inliers)) if n else math.nan,
    }


def pick_sources(keys: Sequence[str], n: int, seed: int) -> list[int]:
    """``min(n, path frames)`` path frames (shots whose key is ``from->to``; spin images are
    left out) chosen at random from ``seed``, in tour order."""
    frames = np.array([i for i, k in enumerate(keys) if "->" in k], np.int64)
    rng = np.random.default_rng(seed)
    pick = rng.choice(frames, size=min(n, len(frames)), replace=False)
    return sorted(int(i) for i in pick)


def free_space(plan: FloorPlan, radius_m: float) -> Callable[[float, float], bool]:
    """Where the robot may stand in every condition: inside a room and at least ``radius_m``
    from walls and furniture, as :meth:`PlanGeometry.free_random_pose` tests it, with the
    furniture both where it was taught and where ``moved`` puts it (so every condition
    renders the same views)."""
    from robot_client.sim.world import PlanGeometry

    geometries = [PlanGeometry(plan, condition=c) for c in ("same", "moved")]

    def is_free(x: float, y: float) -> bool:
        return plan.room_at(x, y) is not None and not any(
            g.collides(x, y, radius_m) for g in geometries
        )

    return is_free


def evaluate_offsets(
    plan: FloorPlan,
    tour: Sequence[Shot],
    keys: Sequence[str],
    *,
    offsets: Sequence[float],
    conditions: Sequence[str],
    n_sources: int,
    seed: int,
    turn_deg: float,
    radius: float,
    angle_deg: float,
) -> tuple[list[OffsetView], dict[float, int], list[float]]:
    """Query the server's engine from beside the taught path.

    Returns:
        every rendered view (all offsets and conditions), the number of views skipped per
        offset (no free side; the same in every condition) and the weights used.
    """
    from robot_client.sim import RobotParams, SimWorld
    from robot_client.sim.world import Pose
    from server.vision.features import extract

    index, order, fp = server_index(tour, keys)
    tx = np.array([s.x for s in tour])
    ty = np.array([s.y for s in tour])
    tt = np.array([s.theta for s in tour])
    sources = pick_sources(keys, n_sources, seed)
    is_free = free_space(plan, RobotParams().radius_m)
    source_poses = [Pose(tour[i].x, tour[i].y, tour[i].theta) for i in sources]
    poses = {
        off: side_poses(source_poses, off, seed=seed + 2, is_free=is_free, turn_deg=turn_deg)
        for off in offsets
    }
    skipped = {off: sum(p is None for p in ps) for off, ps in poses.items()}
    views: list[OffsetView] = []
    for condition in conditions:
        with SimWorld(plan, condition=condition, seed=seed) as world:
            for off in offsets:
                noise = np.random.default_rng(seed + 1)
                for src, pose in zip(sources, poses[off], strict=True):
                    if pose is None:
                        continue
                    q = extract(camera_shot(world, pose, noise).image, fp)
                    k = int(np.argmax(index.query(q).image))
                    best = int(order[k])
                    turn = np.abs((tt - tt[src] + np.pi) % (2 * np.pi) - np.pi)
                    near = np.hypot(tx - tx[src], ty - ty[src]) <= radius
                    near &= turn <= math.radians(angle_deg)
                    views.append(
                        OffsetView(
                            source=src,
                            offset_m=off,
                            condition=condition,
                            pose=pose,
                            best=best,
                            retrieved=best == src or bool(near[best]),
                            inliers=int(index.geometric_inliers(q, [k])[0]),
                        )
                    )
    return views, skipped, [round(float(x), 4) for x in index.weights]


def run_offsets(args: argparse.Namespace, plan: FloorPlan, route: tuple[str, ...]) -> int:
    """``--offsets``: the report per offset (and per condition), printed and as JSON."""
    offsets = list(dict.fromkeys(args.offsets))
    try:
        labels = {off: offset_label(off) for off in offsets}
    except ValueError as exc:
        print(f"teachrepeat bench sim-retrieval: --offsets: {exc}")
        return 2
    if len(set(labels.values())) < len(labels):
        print("teachrepeat bench sim-retrieval: --offsets: two offsets have the same label")
        return 2
    if not 0 <= args.turn_deg <= 180:
        print(
            f"teachrepeat bench sim-retrieval: --turn-deg must lie in [0, 180], not {args.turn_deg}"
        )
        return 2
    if args.queries < 1:
        print(f"teachrepeat bench sim-retrieval: --queries must be at least 1, not {args.queries}")
        return 2
    conditions = list(dict.fromkeys(args.condition or ["same"]))
    t0 = time.perf_counter()
    tour, keys = teach(plan, route)
    views, skipped, weights = evaluate_offsets(
        plan,
        tour,
        keys,
        offsets=offsets,
        conditions=conditions,
        n_sources=args.queries,
        seed=args.seed,
        turn_deg=args.turn_deg,
        radius=args.radius,
        angle_deg=args.angle,
    )
    n_sources = len(pick_sources(keys, args.queries, args.seed))
    print(
        f"tour: {len(tour)} images; {n_sources} path frames moved sideways, turned up to "
        f"{args.turn_deg:g} deg; weights {weights}"
    )
    print("offset  condition  views  skipped  matched  retrieved  geometric  median inliers")
    per_condition: dict[str, dict[str, Any]] = {}
    for condition in conditions:
        cells: dict[str, Any] = {}
        for off in offsets:
            mine = [v for v in views if v.condition == condition and v.offset_m == off]
            cell = offset_summary(mine, skipped[off], min_inliers=args.min_inliers)
            cells[labels[off]] = {"offset_m": off, **cell}
            print(
                f"{off:5.2f} m {condition:10s} {cell['views']:5d}  {cell['skipped']:7d}  "
                f"{cell['matched_fraction']:7.3f}  {cell['retrieved_fraction']:9.3f}  "
                f"{cell['geometric_fraction']:9.3f}  {cell['median_inliers']:14.1f}"
            )
        per_condition[condition] = {"offsets": cells}
    result: dict[str, Any] = {
        "plan": Path(plan.source).name,
        "plan_name": plan.name,
        "plan_sha256": plan.sha256,
        "route": list(route),
        "tour_images": len(tour),
        "poses": n_sources,
        "seed": args.seed,
        "radius_m": args.radius,
        "angle_deg": args.angle,
        "turn_deg": args.turn_deg,
        "min_inliers": args.min_inliers,
        "condition": conditions[0],
        "weights": weights,
        "offsets": per_condition[conditions[0]]["offsets"],
        "seconds": time.perf_counter() - t0,
    }
    if len(conditions) > 1:
        result["conditions"] = per_condition
    write_json(args.json, result)
    return 0


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
    if args.offsets is not None:
        return run_offsets(args, plan, route)
    conditions = list(dict.fromkeys(args.condition or CONDITIONS))
    t0 = time.perf_counter()
    tour, keys = teach(plan, route)
    qs = queries(plan, args.queries, args.seed, conditions)
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
                for c in conditions
            )
            n = res[conditions[0]]["queries"]
            print(f"{name:20s} image/state recall@1: {cells}  (n={n})")
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
