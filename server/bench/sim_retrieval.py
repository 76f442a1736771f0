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
condition it reports how many views retrieve **the taught image nearest to where the camera
now stands** *and* share at least ``--min-inliers`` RANSAC homography inliers with the image
retrieved (mutual nearest-neighbour corners,
:meth:`~server.vision.index.TourIndex.geometric_inliers`): ``matched_fraction``. "Nearest" is
by :func:`pose_distance`, metres plus the heading difference at ``--radius`` metres per
``--angle`` degrees, over every taught image (path frames of every traversal and spin images);
the best image counts as that one when it lies within ``--radius`` and ``--angle`` of it, as
neighbouring frames are near copies. Before 2026-11-26 the report judged the best image against
the *source* frame the camera was moved from instead (within ``--radius`` and ``--angle`` of
it); that figure is kept as ``source_matched_fraction``. Two figures say what limits it:
``reachable_fraction``, the views for which some image within the tolerance of the nearest one
has the inliers (what a perfect retrieval would match with these features), and
``faces_wall_fraction``, the views facing a wall or furniture nearer than
:data:`FACES_WALL_M`. The engine is the server's default (``--descriptor`` and ``--set``
change it), with the weights the server would use for the tour.
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

from server.bench.common import DESCRIPTOR_CHOICES, write_json
from server.tuning import add_set_argument

if TYPE_CHECKING:
    from robot_client.sim.floorplan import FloorPlan
    from robot_client.sim.world import Pose, SimWorld
    from server.navigation import NavigationParams
    from server.vision.features import DescriptorKind, FeatureParams, ImageFeatures
    from server.vision.index import TourIndex

CONDITIONS = ("same", "lighting", "moved")
#: A view "faces a wall" when the nearest wall or piece of furniture across the middle of the
#: view (rays within :data:`AHEAD_DEG` of its heading, median) is nearer than this, metres.
FACES_WALL_M = 0.7
#: Half-width of the middle of the view the distance ahead is measured over, degrees.
AHEAD_DEG = 10.0


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
        "--descriptor",
        choices=DESCRIPTOR_CHOICES,
        default=None,
        help="with --offsets: the local features (FeatureParams.descriptor of the navigation "
        "features and of the engine; default: the server's)",
    )
    add_set_argument(
        parser,
        "with --offsets: a navigation setting for the engine (dotted names, values as "
        "JSON), e.g. --set engine.geometric=true --set engine.n_candidates=40; "
        "features.* and engine.features.* must agree",
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


def navigation_params(
    descriptor: str | None = None, settings: Sequence[tuple[str, Any]] = ()
) -> NavigationParams:
    """The server's default :class:`~server.navigation.NavigationParams` with ``settings``
    (dotted names, :func:`server.tuning.tuned`) and, when given, ``descriptor`` as the local
    features of both the navigation features and the engine. ``ValueError`` names an unknown
    or ill-typed setting, or features that differ from the engine's (the index refuses them)."""
    from server.navigation import NavigationParams
    from server.tuning import tuned

    overrides = dict(settings)
    if descriptor is not None:
        overrides["features.descriptor"] = descriptor
        overrides["engine.features.descriptor"] = descriptor
    nav = tuned(NavigationParams(), overrides)
    if nav.features != nav.engine.features:
        raise ValueError(
            "features.* and engine.features.* differ; set both (e.g. --set "
            "features.n_features=200 --set engine.features.n_features=200)"
        )
    return nav


def server_index(
    tour: Sequence[Shot], keys: Sequence[str], nav: NavigationParams | None = None
) -> tuple[TourIndex, npt.NDArray[np.int64], FeatureParams]:
    """The tour's index as the server builds it for navigation: ``nav`` (default: its default
    :class:`~server.navigation.NavigationParams`; features, engine), the canonical image order
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

    nav = nav or NavigationParams()
    order, states = canonical_order(keys)
    index = TourIndex(nav.engine)
    index.add([extract(tour[i].image, nav.features) for i in order], states)
    chosen = nav.signature_weights
    weights = learn_weights(index, params=nav.engine) if chosen is None else chosen
    index.set_weights(np.asarray(weights, np.float64))
    return index, order, nav.features


def pose_distance(
    pose: Pose,
    xs: npt.ArrayLike,
    ys: npt.ArrayLike,
    thetas: npt.ArrayLike,
    *,
    metres_per_radian: float,
) -> npt.NDArray[np.float64]:
    """How far taught poses are from ``pose``: ``(n,) float64`` metres, the distance between
    the positions plus ``metres_per_radian`` times the heading difference (wrapped to
    ``[0, pi]``), so that a taught image facing elsewhere is far even when taken on the spot.

    Args:
        pose: the camera (metres, radians).
        xs, ys, thetas: ``(n,)`` taught positions (metres) and headings (radians).
        metres_per_radian: what a radian of heading difference weighs, metres (>= 0).
    """
    if not metres_per_radian >= 0:
        raise ValueError(f"metres_per_radian must be >= 0, got {metres_per_radian}")
    x, y, t = (np.asarray(v, np.float64) for v in (xs, ys, thetas))
    turn = np.abs((t - pose.theta + np.pi) % (2 * np.pi) - np.pi)
    return np.hypot(x - pose.x, y - pose.y) + metres_per_radian * turn


@dataclass(frozen=True)
class TaughtPoses:
    """Where every taught image was taken, and the tolerance within which two of them count
    as the same view.

    Attributes:
        x, y, theta: ``(n,) float64`` positions (metres) and headings (radians), shot order.
        radius: metres; angle: radians. Two images within both of each other are "the same".
    """

    x: npt.NDArray[np.float64]
    y: npt.NDArray[np.float64]
    theta: npt.NDArray[np.float64]
    radius: float
    angle: float

    @classmethod
    def of(cls, tour: Sequence[Shot], radius: float, angle_deg: float) -> TaughtPoses:
        return cls(
            np.array([s.x for s in tour], np.float64),
            np.array([s.y for s in tour], np.float64),
            np.array([s.theta for s in tour], np.float64),
            float(radius),
            math.radians(angle_deg),
        )

    def near(self, i: int) -> npt.NDArray[np.bool_]:
        """``(n,)``: the images within ``radius`` and ``angle`` of image ``i`` (``i`` too)."""
        turn = np.abs((self.theta - self.theta[i] + np.pi) % (2 * np.pi) - np.pi)
        return (np.hypot(self.x - self.x[i], self.y - self.y[i]) <= self.radius) & (
            turn <= self.angle + 1e-12
        )

    def nearest(self, pose: Pose) -> int:
        """The taught image nearest to ``pose`` by :func:`pose_distance`, a radian weighing
        ``radius / angle`` metres (so the tolerance's two limits weigh alike)."""
        d = pose_distance(
            pose, self.x, self.y, self.theta, metres_per_radian=self.radius / self.angle
        )
        return int(np.argmin(d))


@dataclass(frozen=True)
class OffsetView:
    """One query beside the taught path and what the engine made of it.

    Attributes:
        source: the taught path frame (index into the tour's shots) the camera was moved from.
        offset_m: sideways distance, metres. condition: ``same``, ``lighting`` or ``moved``.
        pose: where the camera stood (metres, radians).
        best: the shot the engine ranked first (argmax of ``Similarity.image``).
        retrieved: ``best`` is ``nearest`` or within the tolerance of its pose.
        inliers: RANSAC homography inliers between the query and ``best``.
        nearest: the taught shot nearest to ``pose`` (:meth:`TaughtPoses.nearest`).
        retrieved_source: ``best`` is the source or within the tolerance of the source's pose
            (the definition before 2026-11-26).
        reachable: some taught image within the tolerance of ``nearest`` has at least the
            required inliers with the query: a perfect retrieval would match this view.
        ahead_m: distance to the wall or furniture across the middle of the view, metres.
    """

    source: int
    offset_m: float
    condition: str
    pose: Pose
    best: int
    retrieved: bool
    inliers: int
    nearest: int = -1
    retrieved_source: bool = False
    reachable: bool = False
    ahead_m: float = math.inf


def offset_summary(
    views: Sequence[OffsetView],
    skipped: int,
    *,
    min_inliers: int,
    taught: TaughtPoses | None = None,
) -> dict[str, Any]:
    """One cell of the report, each fraction over the ``views`` rendered (NaN without views):

    * ``matched_fraction`` (with ``matched_ci95``, Wilson): the nearest taught image retrieved
      and at least ``min_inliers`` inliers with it; ``retrieved_fraction``: retrieved alone;
    * ``source_matched_fraction`` (with ``source_matched_ci95``), ``source_retrieved_fraction``:
      the same judged against the source frame (the definition before 2026-11-26);
    * ``geometric_fraction``: at least ``min_inliers`` inliers with the best image;
    * ``reachable_fraction``: some image within the tolerance of the nearest one has at least
      ``min_inliers`` inliers with the query (:attr:`OffsetView.reachable`): the most any
      retrieval could match with these features; ``faces_wall_fraction``: the view faces a wall
      or furniture nearer than :data:`FACES_WALL_M`;
    * ``views``, ``skipped`` (no free side), ``median_inliers``; with ``taught``, also
      ``nearest_is_source_fraction`` (the nearest image within the tolerance of the source:
      the two definitions judge alike) and the median distance (m) and heading difference
      (degrees) from the camera to its nearest taught image.
    """
    from server.bench.common import wilson_interval

    n = len(views)
    retrieved = np.array([v.retrieved for v in views], bool)
    from_source = np.array([v.retrieved_source for v in views], bool)
    inliers = np.array([v.inliers for v in views], np.int64)
    geometric = inliers >= min_inliers
    matched = int((retrieved & geometric).sum())
    matched_source = int((from_source & geometric).sum())

    def frac(x: npt.NDArray[np.bool_]) -> float:
        return float(x.mean()) if n else math.nan

    out: dict[str, Any] = {
        "matched_fraction": matched / n if n else math.nan,
        "retrieved_fraction": frac(retrieved),
        "source_matched_fraction": matched_source / n if n else math.nan,
        "source_retrieved_fraction": frac(from_source),
        "geometric_fraction": frac(geometric),
        "reachable_fraction": frac(np.array([v.reachable for v in views], bool)),
        "faces_wall_fraction": frac(np.array([v.ahead_m < FACES_WALL_M for v in views], bool)),
        "matched_ci95": list(wilson_interval(matched, n)),
        "source_matched_ci95": list(wilson_interval(matched_source, n)),
        "views": n,
        "skipped": skipped,
        "median_inliers": float(np.median(inliers)) if n else math.nan,
    }
    if taught is not None:
        same = np.array([bool(taught.near(v.source)[v.nearest]) for v in views], bool)
        dist = [
            math.hypot(taught.x[v.nearest] - v.pose.x, taught.y[v.nearest] - v.pose.y)
            for v in views
        ]
        turn = [
            math.degrees(
                abs((taught.theta[v.nearest] - v.pose.theta + math.pi) % (2 * math.pi) - math.pi)
            )
            for v in views
        ]
        out["nearest_is_source_fraction"] = frac(same)
        out["nearest_m_median"] = float(np.median(dist)) if n else math.nan
        out["nearest_deg_median"] = float(np.median(turn)) if n else math.nan
    return out


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


@dataclass(frozen=True)
class SideView:
    """A camera frame rendered beside the taught path (before the engine sees it).

    Attributes:
        source: the taught path frame it was moved from; offset_m: metres; condition: as
        rendered; shot: the frame (camera noise, JPEG) and its pose; ahead_m: distance to the
        wall or furniture across the middle of the view (median over rays within
        :data:`AHEAD_DEG` of the heading), metres.
    """

    source: int
    offset_m: float
    condition: str
    shot: Shot
    ahead_m: float = math.inf


def render_side_views(
    plan: FloorPlan,
    tour: Sequence[Shot],
    keys: Sequence[str],
    *,
    offsets: Sequence[float],
    conditions: Sequence[str],
    n_sources: int,
    seed: int,
    turn_deg: float,
) -> tuple[list[SideView], dict[float, int]]:
    """Render the views beside the taught path (see the module docstring): sources from
    ``seed``, sides and turns from ``seed + 2``, camera noise from ``seed + 1`` per offset.

    Returns:
        every rendered view (offsets within conditions) and the number skipped per offset
        (no free side; the same in every condition).
    """
    from robot_client.sim import RobotParams, SimWorld
    from robot_client.sim.world import Pose

    sources = pick_sources(keys, n_sources, seed)
    is_free = free_space(plan, RobotParams().radius_m)
    source_poses = [Pose(tour[i].x, tour[i].y, tour[i].theta) for i in sources]
    poses = {
        off: side_poses(source_poses, off, seed=seed + 2, is_free=is_free, turn_deg=turn_deg)
        for off in offsets
    }
    skipped = {off: sum(p is None for p in ps) for off, ps in poses.items()}
    views: list[SideView] = []
    rays = np.radians(np.linspace(-AHEAD_DEG, AHEAD_DEG, 5))
    for condition in conditions:
        with SimWorld(plan, condition=condition, seed=seed) as world:
            for off in offsets:
                noise = np.random.default_rng(seed + 1)
                for src, pose in zip(sources, poses[off], strict=True):
                    if pose is not None:
                        shot = camera_shot(world, pose, noise)
                        ahead = float(np.median(world.cast_rays(pose.x, pose.y, pose.theta + rays)))
                        views.append(SideView(src, off, condition, shot, ahead))
    return views, skipped


def score_side_views(
    views: Sequence[SideView],
    index: TourIndex,
    order: npt.NDArray[np.int64],
    features: FeatureParams,
    taught: TaughtPoses,
    *,
    min_inliers: int = 10,
) -> list[OffsetView]:
    """What the engine (``index``, its images in ``order``, queries extracted with
    ``features``) makes of every view: the best image, whether it is the nearest taught image
    (and the source), its RANSAC inliers with the query, and whether any image within the
    tolerance of the nearest has ``min_inliers`` of them (:func:`reachable`)."""
    from robot_client.sim.world import Pose
    from server.vision.features import extract

    position = np.empty(len(order), np.int64)  # shot -> image index
    position[order] = np.arange(len(order))
    out = []
    for v in views:
        q = extract(v.shot.image, features)
        k = int(np.argmax(index.query(q).image))
        best = int(order[k])
        pose = Pose(v.shot.x, v.shot.y, v.shot.theta)
        nearest = taught.nearest(pose)
        retrieved = bool(taught.near(nearest)[best])
        inliers = int(index.geometric_inliers(q, [k])[0])
        out.append(
            OffsetView(
                source=v.source,
                offset_m=v.offset_m,
                condition=v.condition,
                pose=pose,
                best=best,
                retrieved=retrieved,
                inliers=inliers,
                nearest=nearest,
                retrieved_source=bool(taught.near(v.source)[best]),
                # a matched view is reachable: its best image is one such image
                reachable=(retrieved and inliers >= min_inliers)
                or reachable(index, q, position, taught, pose, nearest, min_inliers),
                ahead_m=v.ahead_m,
            )
        )
    return out


def reachable(
    index: TourIndex,
    query: ImageFeatures,
    position: npt.NDArray[np.int64],
    taught: TaughtPoses,
    pose: Pose,
    nearest: int,
    min_inliers: int,
    *,
    batch: int = 8,
) -> bool:
    """Whether some taught image within the tolerance of ``nearest`` shares at least
    ``min_inliers`` RANSAC inliers with ``query`` (the view's features): whether a perfect
    retrieval could match the view. Images are tried nearest to ``pose`` first, ``batch`` at
    a time, until one has enough. ``position[shot]`` is the shot's image index in ``index``."""
    ok = np.flatnonzero(taught.near(nearest))
    d = pose_distance(
        pose,
        taught.x[ok],
        taught.y[ok],
        taught.theta[ok],
        metres_per_radian=taught.radius / taught.angle,
    )
    ranked = position[ok[np.argsort(d, kind="stable")]]
    for lo in range(0, len(ranked), batch):
        if int(index.geometric_inliers(query, ranked[lo : lo + batch]).max()) >= min_inliers:
            return True
    return False


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
    min_inliers: int = 10,
    nav: NavigationParams | None = None,
) -> tuple[list[OffsetView], dict[float, int], list[float]]:
    """Query the server's engine (``nav``, default: the server's defaults) from beside the
    taught path.

    Returns:
        every rendered view (all offsets and conditions), the number of views skipped per
        offset (no free side; the same in every condition) and the weights used.
    """
    index, order, fp = server_index(tour, keys, nav)
    rendered, skipped = render_side_views(
        plan,
        tour,
        keys,
        offsets=offsets,
        conditions=conditions,
        n_sources=n_sources,
        seed=seed,
        turn_deg=turn_deg,
    )
    taught = TaughtPoses.of(tour, radius, angle_deg)
    views = score_side_views(rendered, index, order, fp, taught, min_inliers=min_inliers)
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
    if not (args.radius > 0 and 0 < args.angle <= 180):
        print(
            "teachrepeat bench sim-retrieval: --radius must be > 0 and --angle in (0, 180], "
            f"not {args.radius} and {args.angle}"
        )
        return 2
    try:
        nav = navigation_params(args.descriptor, args.settings)
    except ValueError as exc:
        print(f"teachrepeat bench sim-retrieval: --set: {exc}")
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
        min_inliers=args.min_inliers,
        nav=nav,
    )
    taught = TaughtPoses.of(tour, args.radius, args.angle)
    n_sources = len(pick_sources(keys, args.queries, args.seed))
    print(
        f"tour: {len(tour)} images; {n_sources} path frames moved sideways, turned up to "
        f"{args.turn_deg:g} deg; descriptor {nav.features.descriptor}; weights {weights}"
    )
    print(
        "offset  condition  views  skipped  matched  retrieved  geometric  median inliers  "
        "reachable  faces wall | from source: matched  retrieved"
    )
    per_condition: dict[str, dict[str, Any]] = {}
    for condition in conditions:
        cells: dict[str, Any] = {}
        for off in offsets:
            mine = [v for v in views if v.condition == condition and v.offset_m == off]
            cell = offset_summary(mine, skipped[off], min_inliers=args.min_inliers, taught=taught)
            cells[labels[off]] = {"offset_m": off, **cell}
            print(
                f"{off:5.2f} m {condition:10s} {cell['views']:5d}  {cell['skipped']:7d}  "
                f"{cell['matched_fraction']:7.3f}  {cell['retrieved_fraction']:9.3f}  "
                f"{cell['geometric_fraction']:9.3f}  {cell['median_inliers']:14.1f}  "
                f"{cell['reachable_fraction']:9.3f}  {cell['faces_wall_fraction']:10.3f} "
                f"| {cell['source_matched_fraction']:20.3f}  "
                f"{cell['source_retrieved_fraction']:9.3f}"
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
        "nearest": "the taught image with the smallest position distance + heading difference "
        "x radius / angle (m per rad); retrieved = best within radius and angle of it",
        "descriptor": nav.features.descriptor,
        "settings": dict(args.settings),
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
    if args.descriptor is not None or args.settings:
        print("teachrepeat bench sim-retrieval: --descriptor and --set go with --offsets")
        return 2
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
