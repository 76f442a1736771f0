"""``teachrepeat bench features``: the local feature options side by side, for the default.

Every option of ``FeatureParams.descriptor`` (``server.vision.features.DESCRIPTOR_KINDS``:
grad36 at Harris corners, upright ORB at Harris corners, OpenCV's ORB with its FAST keypoints,
OpenCV's SIFT, AKAZE as it comes and with its upright descriptor, BRISK, TEBLID at the Harris
corners) with the engine's settings otherwise unchanged (``EngineParams()``: its geometric
setting, 100 keypoints), measured by the other benchmarks' own functions:

1. **extraction** of one 320x240 frame, p50 / p95 in ms: real frames of every data set resized
   to the working size beforehand, the full :func:`~server.vision.features.extract` and its
   local part alone (:func:`~server.vision.features.extract_corners`); one OpenCV / BLAS
   thread; the options take turns frame by frame, so that the load of a shared machine falls
   on all of them alike;
2. **retrieval** (``bench retrieval``'s tasks, default weights): corridor recall@1 / @5,
   triplets top-1, ukbench score;
3. **corridor localisation** (``bench localize``'s tour, replay and scoring with its defaults:
   a location every 10 frames, weights learned on the tour): ``ir_only`` and ``tracker``
   recall@1 at tolerance 0 and 2, and the engine's query time per frame;
4. 2 and 3 again with ``EngineParams(geometric=True)`` (unless ``--no-geometric``);
5. **Nordland** summer <-> winter on a window of frames (``--nordland-frames`` from
   ``--nordland-skip``): retrieval recall@1 at +-1 / +-10 frames (both directions, default
   weights) and the tracker summer -> winter with patch-only weights (as in docs/localize.md);
6. **simulated home** (``bench sim-retrieval``'s teach, queries and evaluate; learned weights,
   colour normalisation): image and state recall@1 in every condition;
7. **query time** on synthesised tours (``bench retrieval``'s speed test), total p50 / p95.

Output: tables on stdout and, with ``--json OUT``, ``{"descriptors": {kind: {...}}, "meta":
{...}}``.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from server.bench.common import DESCRIPTOR_CHOICES, default_data_dir, stats, write_json
from server.threads import pin_threads

if TYPE_CHECKING:
    from server.bench._retrieval_impl import Datasets
    from server.bench.localize import GroundTruth
    from server.bench.sim_retrieval import Shot
    from server.vision.features import DescriptorKind, FeatureParams
    from server.vision.index import EngineParams

Image = npt.NDArray[np.uint8]

#: localisation tolerances reported (frames)
CORRIDOR_TOLERANCES = (0, 2)
NORDLAND_TOLERANCES = (1, 10)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``teachrepeat bench features``."""
    from robot_client.sim.check_plan import add_plan_argument

    parser.add_argument(
        "--data",
        type=Path,
        default=default_data_dir(),
        help="data folder with corridor/, nordland/, triplets/, ukbench/ "
        "(default: $TEACHREPEAT_DATA or ../shared/data)",
    )
    parser.add_argument(
        "--descriptors",
        default=",".join(DESCRIPTOR_CHOICES),
        help=f"comma-separated options to compare (default all: {','.join(DESCRIPTOR_CHOICES)})",
    )
    parser.add_argument("--json", type=Path, default=None, help="write the results here")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="smoke run: a few frames of every set, a short simulated route, small tours",
    )
    parser.add_argument(
        "--timing-frames",
        type=int,
        default=400,
        help="real frames timed per option: all corridor, triplets and ukbench frames and 50 "
        "of Nordland (312) at most (default 400; --quick: 30)",
    )
    parser.add_argument(
        "--nordland-frames",
        type=int,
        default=600,
        help="Nordland frames per season (default 600; --quick: 60; 0 skips Nordland)",
    )
    parser.add_argument(
        "--nordland-skip",
        type=int,
        default=17,
        help="first Nordland frame used (default 17: the ones before are near-blank)",
    )
    add_plan_argument(parser)
    parser.add_argument(
        "--sim-queries",
        type=int,
        default=300,
        help="random poses per condition in the simulated home (default 300; --quick: 30; "
        "0 skips the simulator)",
    )
    parser.add_argument(
        "--sizes",
        default=None,
        help="comma-separated synthesised tour sizes for the query time (default 1000,10000; "
        "--quick: 300)",
    )
    parser.add_argument(
        "--queries", type=int, default=100, help="timed queries per tour size (default 100)"
    )
    parser.add_argument(
        "--no-geometric",
        action="store_true",
        help="skip the runs with EngineParams(geometric=True)",
    )


# ------------------------------------------------------------------------------ measurements


def working_size_frames(images: Sequence[Image], params: FeatureParams) -> list[Image]:
    """``images`` resized to the working size (INTER_AREA when shrinking, INTER_LINEAR when
    enlarging, as :func:`~server.vision.features.extract` does), so that timing extraction
    measures a 320x240 frame whatever the data set's size."""
    import cv2

    size = (params.width, params.height)
    out = []
    for im in images:
        shrink = im.shape[1] >= params.width and im.shape[0] >= params.height
        interp = cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
        out.append(np.asarray(cv2.resize(im, size, interpolation=interp), np.uint8))
    return out


def extraction_times(
    frames: Sequence[Image], sets: Sequence[str], kinds: Sequence[DescriptorKind]
) -> dict[str, dict[str, Any]]:
    """Per option: ``extract_ms`` and ``local_ms`` (keypoints and descriptors only) statistics
    (:func:`~server.bench.common.stats`) over ``frames`` (working size; ``sets[i]`` names the
    data set of frame i), the p50 of ``extract_ms`` per data set and the mean number of
    keypoints. The options take turns on each frame."""
    from server.vision.features import FeatureParams, extract, extract_corners

    params = {k: FeatureParams(descriptor=k) for k in kinds}
    full: dict[str, list[float]] = {k: [] for k in kinds}
    local: dict[str, list[float]] = {k: [] for k in kinds}
    keypoints: dict[str, list[int]] = {k: [] for k in kinds}
    for k in kinds:  # warm-up: first calls allocate
        extract(frames[0], params[k])
    for frame in frames:
        for k in kinds:
            t0 = time.perf_counter()
            f = extract(frame, params[k])
            t1 = time.perf_counter()
            extract_corners(frame, params[k])
            t2 = time.perf_counter()
            full[k].append((t1 - t0) * 1e3)
            local[k].append((t2 - t1) * 1e3)
            keypoints[k].append(f.n_keypoints)
    labels = np.asarray(sets)
    return {
        k: {
            "extract_ms": stats(full[k]),
            "local_ms": stats(local[k]),
            "extract_ms_p50_per_set": {
                name: float(np.median(np.asarray(full[k])[labels == name]))
                for name in dict.fromkeys(sets)
            },
            "keypoints_mean": float(np.mean(keypoints[k])),
            "frames": len(frames),
        }
        for k in kinds
    }


def retrieval(params: EngineParams, ds: Datasets) -> dict[str, Any]:
    """``bench retrieval``'s corridor, triplets and ukbench tasks with the default weights."""
    from server.bench import _retrieval_impl as impl

    acc = impl.accuracy(impl.Engine(params, learn=False), ds, with_nordland=False)
    return {
        "corridor_recall@1": acc["corridor"]["recall@1"],
        "corridor_recall@5": acc["corridor"]["recall@5"],
        "triplets_top1": acc["triplets"]["top1"],
        "ukbench_score": acc["ukbench"]["score"],
        "seconds": acc["accuracy_seconds"],
    }


def localise(
    refs: Sequence[Image],
    queries: Sequence[Image],
    gt: GroundTruth,
    params: EngineParams,
    *,
    first_frame: int = 0,
    tolerances: Sequence[int],
    every: int = 10,
    learn: bool = True,
) -> dict[str, Any]:
    """``bench localize`` with its defaults (a location every ``every`` frames, the bench
    transitions, the policy's action, ``TrackerParams()``): ``refs`` / ``queries`` are frames
    ``first_frame, first_frame + 1, ...`` of the two traversals. Returns recall@1 of
    ``ir_only``, ``tracker`` and ``smoother`` per tolerance, and the engine's query time per
    frame (ms, extraction excluded)."""
    from server.belief.tracker import TrackerParams
    from server.bench import localize as loc
    from server.vision.features import extract

    ref_frames = list(range(first_frame, first_frame + len(refs)))
    qry_frames = list(range(first_frame, first_frame + len(queries)))
    feats = [extract(im, params.features) for im in refs]
    tour = loc.build_tour(ref_frames, every)
    index = loc.make_index(feats, tour.graph, params, learn=learn)
    res = loc.replay(
        tour,
        index,
        qry_frames,
        queries,
        transitions=loc.bench_transitions(),
        tracker_params=TrackerParams(),
        action_mode="policy",
        progress=False,
    )
    out: dict[str, Any] = {}
    for name in ("ir_only", "tracker", "smoother"):
        err = loc.errors(res.query, getattr(res, name), gt)
        out[name] = {f"tol{t}": loc.score(err, t)["recall@1"] for t in tolerances}
    query_ms = np.asarray(res.engine_ms) - np.asarray(res.extract_ms)
    out["query_ms"] = stats(query_ms.tolist())
    out["frames"] = len(qry_frames)
    return out


def nordland(params: EngineParams, ds: Datasets) -> dict[str, Any]:
    """Retrieval both ways (``bench retrieval``'s Nordland task, default weights) and the
    tracker summer -> winter with patch-only weights, on the frames in ``ds``."""
    from server.bench import _retrieval_impl as impl
    from server.bench.localize import PATCH_WEIGHTS, GroundTruth

    ret = impl.nordland(impl.Engine(params, learn=False), ds)
    patch = replace(params, weights=PATCH_WEIGHTS)
    loc = localise(
        ds.winter, ds.summer, GroundTruth(), patch, tolerances=NORDLAND_TOLERANCES, learn=False
    )
    return {
        "retrieval_recall@1_tol1": ret["recall@1_tol1"],
        "retrieval_recall@1_tol10": ret["recall@1_tol10"],
        "tracker_s2w_patch": loc["tracker"],
        "ir_only_s2w_patch": loc["ir_only"],
        "frames": len(ds.summer),
    }


def simulator(
    tour: list[Shot],
    keys: list[str],
    qs: dict[str, list[Shot]],
    kind: DescriptorKind,
    *,
    radius: float = 0.5,
    angle_deg: float = 30.0,
) -> dict[str, Any]:
    """``bench sim-retrieval``'s evaluate with the server's settings (learned weights, colour
    normalisation) and the given descriptor; a query counts when a taught image lies within
    ``radius`` metres and ``angle_deg`` degrees of its pose (defaults as there)."""
    from server.bench.sim_retrieval import evaluate

    return evaluate(
        tour,
        keys,
        qs,
        colour_constancy=True,
        weights="learned",
        radius=radius,
        angle_deg=angle_deg,
        descriptor=kind,
    )


def query_speed(
    ds: Datasets, params: EngineParams, sizes: Sequence[int], queries: int, pool: int
) -> dict[str, Any]:
    """``bench retrieval``'s speed test (engine only): per tour size the query time."""
    from server.bench import _retrieval_impl as impl

    engine, _, _ = impl.speed(
        ds,
        sizes,
        params=params,
        n_queries=queries,
        baseline_queries=[0],
        images_per_state=100,
        pool=pool,
        with_baseline=False,
        compare_index=False,
    )
    return {
        n: {k: s[k] for k in ("total_ms_p50", "total_ms_p95", "bytes_per_image")}
        for n, s in engine.items()
    }


# ------------------------------------------------------------------------------ run


def _kinds(spec: str) -> list[DescriptorKind]:
    from server.vision.features import DESCRIPTOR_KINDS

    kinds = [s.strip() for s in spec.split(",") if s.strip()]
    unknown = [k for k in kinds if k not in DESCRIPTOR_KINDS]
    if unknown or not kinds:
        raise ValueError(
            f"--descriptors: unknown {unknown or spec!r}; choose from {','.join(DESCRIPTOR_KINDS)}"
        )
    return [k for k in DESCRIPTOR_KINDS if k in kinds]


def run(args: argparse.Namespace) -> int:
    """Run the comparison described in the module doc; 0 on success, 2 on bad input."""

    from server.bench import _retrieval_impl as impl
    from server.bench.localize import GroundTruth, list_frames, read_image
    from server.vision.features import FeatureParams
    from server.vision.index import EngineParams

    try:
        kinds = _kinds(args.descriptors)
    except ValueError as exc:
        print(f"teachrepeat bench features: {exc}")
        return 2
    data = Path(args.data)
    if not (data / "corridor").is_dir():
        print(
            f"teachrepeat bench features: no corridor/ in data folder {data.resolve()}; "
            "pass --data DIR or set TEACHREPEAT_DATA"
        )
        return 2
    blas = pin_threads()
    quick = bool(args.quick)
    t_start = time.perf_counter()
    ds = impl.load(data, quick)
    n_nord = min(args.nordland_frames, 60) if quick else args.nordland_frames
    lo = args.nordland_skip
    nord_ds = replace(ds, summer=ds.summer[lo : lo + n_nord], winter=ds.winter[lo : lo + n_nord])
    n_timing = min(args.timing_frames, 30) if quick else args.timing_frames
    sizes = [int(s) for s in (args.sizes or ("300" if quick else "1000,10000")).split(",")]
    corridor_gt = GroundTruth.parse(str(data / "corridor" / "ground_truth.json"))
    # localisation reads whole traversals (--quick: their first 40 frames)
    c_ref, c_qry = (
        [read_image(f) for f in list_frames(data / "corridor" / part)][: 40 if quick else None]
        for part in ("ref", "query")
    )

    pool = {
        "corridor": ds.corridor_ref + ds.corridor_query,
        "triplets": ds.triplets,
        "ukbench": ds.ukbench,
        "nordland": nord_ds.summer[:50],
    }
    named = [(name, im) for name, images in pool.items() for im in images]
    named = named[:: max(1, len(named) // max(n_timing, 1))][:n_timing]
    frames = working_size_frames([im for _, im in named], FeatureParams())
    print(f"extraction: {len(frames)} real frames at 320x240, options in turn", flush=True)
    extraction = extraction_times(frames, [name for name, _ in named], kinds)

    sim_data = _simulator_data(args, quick)
    results: dict[str, dict[str, Any]] = {}
    for kind in kinds:
        t0 = time.perf_counter()
        params = EngineParams(features=FeatureParams(descriptor=kind))
        res: dict[str, Any] = {"extraction": extraction[kind]}
        res["retrieval"] = retrieval(params, ds)
        res["corridor_localize"] = localise(
            c_ref, c_qry, corridor_gt, params, tolerances=CORRIDOR_TOLERANCES
        )
        if not args.no_geometric:
            geo = replace(params, geometric=True)
            res["retrieval_geometric"] = retrieval(geo, ds)
            res["corridor_localize_geometric"] = localise(
                c_ref, c_qry, corridor_gt, geo, tolerances=CORRIDOR_TOLERANCES
            )
        if n_nord > 0:
            res["nordland"] = nordland(params, nord_ds)
        if sim_data is not None:
            tour, keys, qs, info = sim_data
            res["sim"] = simulator(
                tour, keys, qs, kind, radius=info["radius_m"], angle_deg=info["angle_deg"]
            )
        res["query_speed"] = query_speed(
            ds, params, sizes, 20 if quick else args.queries, 100 if quick else 1000
        )
        res["seconds"] = time.perf_counter() - t0
        results[kind] = res
        print(f"{kind}: done in {res['seconds']:.0f} s", flush=True)

    output = {
        "descriptors": results,
        "meta": {
            "quick": quick,
            "data": str(data.resolve()),
            "engine_params": _params_dict(EngineParams()),
            "threads": blas,
            "timing_frames": len(frames),
            "corridor_frames": len(c_qry),
            "nordland": {"first_frame": lo, "frames": len(nord_ds.summer)},
            "sim": None if sim_data is None else sim_data[3],
            "sizes": sizes,
            "protocol": {
                "retrieval": "bench retrieval's tasks, default weights (learn=False)",
                "corridor_localize": "bench localize defaults: location every 10 frames, "
                "bench transitions, policy action, weights learned on the tour",
                "nordland": "retrieval both ways with default weights; tracker summer -> "
                "winter with patch-only weights (docs/localize.md), no learning",
                "sim": "sim-retrieval evaluate: learned weights, colour normalisation, "
                "0.5 m / 30 degrees",
                "query_speed": "bench retrieval's synthesised tours, 100 images per state, "
                "pool of 1000 distinct images (--quick: 100), tiled",
            },
            "seconds": time.perf_counter() - t_start,
        },
    }
    print(format_tables(output))
    write_json(args.json, output)
    return 0


def _simulator_data(
    args: argparse.Namespace, quick: bool
) -> tuple[list[Shot], list[str], dict[str, list[Shot]], dict[str, Any]] | None:
    """The simulated tour and query shots shared by every option (``None``: skipped)."""
    n = min(args.sim_queries, 30) if quick else args.sim_queries
    if n <= 0:
        return None
    from robot_client.sim.check_plan import load_plans_or_exit
    from robot_client.sim.route import teaching_route
    from server.bench.sim_retrieval import queries, teach

    plan = load_plans_or_exit([args.plan], "teachrepeat bench features")[0]
    route = teaching_route(plan)
    if quick:  # a short route: count queries within 1 m and 45 degrees (as the sim test does)
        route = route[:3]
    t0 = time.perf_counter()
    tour, keys = teach(plan, route)
    qs = queries(plan, n, seed=7)
    print(
        f"simulator: {len(tour)} taught images, {n} poses per condition "
        f"({time.perf_counter() - t0:.0f} s)",
        flush=True,
    )
    info = {
        "plan": Path(plan.source).name,
        "route": list(route),
        "tour_images": len(tour),
        "poses": n,
        "radius_m": 1.0 if quick else 0.5,
        "angle_deg": 45.0 if quick else 30.0,
    }
    return tour, keys, qs, info


def _params_dict(params: EngineParams) -> dict[str, Any]:
    from dataclasses import asdict

    return asdict(params)


def _cell(d: Any, *path: str, fmt: str = "{:.3f}") -> str:
    for key in path:
        if not isinstance(d, dict) or key not in d:
            return "-"
        d = d[key]
    return fmt.format(d) if isinstance(d, (int, float)) else "-"


def format_tables(output: dict[str, Any]) -> str:
    """The results as plain-text tables, one row per option."""
    res = output["descriptors"]
    lines: list[str] = []

    def table(title: str, columns: Sequence[tuple[str, tuple[str, ...], str]]) -> None:
        lines.append("")
        lines.append(title)
        head = f"{'option':14s}" + "".join(f"{name:>13s}" for name, _, _ in columns)
        lines.append(head)
        for kind, r in res.items():
            cells = "".join(f"{_cell(r, *path, fmt=fmt):>13s}" for _, path, fmt in columns)
            lines.append(f"{kind:14s}{cells}")

    ms = "{:.2f}"
    table(
        "time (ms): extraction of one 320x240 frame, engine query",
        [
            ("extract p50", ("extraction", "extract_ms", "p50"), ms),
            ("extract p95", ("extraction", "extract_ms", "p95"), ms),
            ("local p50", ("extraction", "local_ms", "p50"), ms),
            ("keypoints", ("extraction", "keypoints_mean"), "{:.0f}"),
        ]
        + [
            (f"q{n} p50", ("query_speed", n, "total_ms_p50"), ms)
            for n in next(iter(res.values()))["query_speed"]
        ],
    )
    for suffix, title in (("", "default engine"), ("_geometric", "geometric=True")):
        if not any(f"retrieval{suffix}" in r for r in res.values()):
            continue
        table(
            f"real data, {title}: retrieval; corridor localisation recall@1 (tol 0 / 2)",
            [
                ("corr. r@1", (f"retrieval{suffix}", "corridor_recall@1"), "{:.3f}"),
                ("corr. r@5", (f"retrieval{suffix}", "corridor_recall@5"), "{:.3f}"),
                ("triplets", (f"retrieval{suffix}", "triplets_top1"), "{:.3f}"),
                ("ukbench", (f"retrieval{suffix}", "ukbench_score"), "{:.2f}"),
                ("tracker t0", (f"corridor_localize{suffix}", "tracker", "tol0"), "{:.3f}"),
                ("tracker t2", (f"corridor_localize{suffix}", "tracker", "tol2"), "{:.3f}"),
                ("ir_only t0", (f"corridor_localize{suffix}", "ir_only", "tol0"), "{:.3f}"),
                ("ir_only t2", (f"corridor_localize{suffix}", "ir_only", "tol2"), "{:.3f}"),
                ("query ms", (f"corridor_localize{suffix}", "query_ms", "p50"), ms),
            ],
        )
    if any("nordland" in r for r in res.values()):
        table(
            "Nordland recall@1: retrieval both ways; tracker summer -> winter, patch weights",
            [
                ("retr. +-1", ("nordland", "retrieval_recall@1_tol1"), "{:.3f}"),
                ("retr. +-10", ("nordland", "retrieval_recall@1_tol10"), "{:.3f}"),
                ("tracker +-1", ("nordland", "tracker_s2w_patch", "tol1"), "{:.3f}"),
                ("tracker +-10", ("nordland", "tracker_s2w_patch", "tol10"), "{:.3f}"),
                ("ir_only +-10", ("nordland", "ir_only_s2w_patch", "tol10"), "{:.3f}"),
            ],
        )
    if any("sim" in r for r in res.values()):
        table(
            "simulated home recall@1 (learned weights)",
            [
                (f"{c[:5]} {w}", ("sim", c, f"{w}_recall@1"), "{:.3f}")
                for w in ("state", "image")
                for c in ("same", "lighting", "moved")
            ]
            + [("queries", ("sim", "same", "queries"), "{:d}")],
        )
    return "\n".join(lines)


__all__ = [
    "add_arguments",
    "extraction_times",
    "format_tables",
    "localise",
    "nordland",
    "query_speed",
    "retrieval",
    "run",
    "simulator",
    "working_size_frames",
]
