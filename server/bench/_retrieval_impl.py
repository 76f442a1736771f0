"""The work behind ``teachrepeat bench retrieval`` (imported by :mod:`server.bench.retrieval`
inside ``run`` so that building the CLI parser stays cheap)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from server.bench.common import stats
from server.bench.common import write_json as _write_json
from server.threads import pin_threads
from server.vision.features import FeatureParams, ImageFeatures, extract
from server.vision.index import EngineParams, TourIndex
from server.vision.learning import learn_weights

Image = npt.NDArray[np.uint8]
NORDLAND_TOLERANCES = tuple(range(0, 11))
RATIO = 0.75


# ------------------------------------------------------------------------------ data


def _read(path: Path) -> Image:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise FileNotFoundError(f"cannot read image {path}")
    return np.asarray(img, np.uint8)


@dataclass
class Datasets:
    corridor_ref: list[Image]
    corridor_query: list[Image]
    corridor_query_ids: list[int]
    corridor_gt: dict[int, list[int]]
    summer: list[Image]
    winter: list[Image]
    triplets: list[Image]
    triplet_place: list[int]
    ukbench: list[Image]


def load(data: Path, quick: bool) -> Datasets:
    cref = sorted((data / "corridor" / "ref").glob("*.jpg"))
    cqry = sorted((data / "corridor" / "query").glob("*.jpg"))
    gt_raw = json.loads((data / "corridor" / "ground_truth.json").read_text())
    gt = {int(k): [int(x) for x in v] for k, v in gt_raw.items()}
    summer = sorted((data / "nordland" / "summer").glob("*.png"))
    winter = sorted((data / "nordland" / "winter").glob("*.png"))
    if quick:
        summer, winter = summer[:100], winter[:100]
        cqry = cqry[::4]
    trip = sorted((data / "triplets").glob("p*/i*/*.jpg"))
    places = [int(p.parent.parent.name[1:]) for p in trip]
    ukb = sorted((data / "ukbench").glob("*.jpg"))
    return Datasets(
        corridor_ref=[_read(p) for p in cref],
        corridor_query=[_read(p) for p in cqry],
        corridor_query_ids=[int(p.stem) for p in cqry],
        corridor_gt=gt,
        summer=[_read(p) for p in summer],
        winter=[_read(p) for p in winter],
        triplets=[_read(p) for p in trip],
        triplet_place=places,
        ukbench=[_read(p) for p in ukb],
    )


# ------------------------------------------------------------------------------ methods


class Method:
    """A retrieval method: ``build(refs, states)`` then ``rank(query) -> image indices``."""

    name = "method"

    def prepare(self, images: Sequence[Image]) -> list[Any]:
        raise NotImplementedError

    def build(self, refs: list[Any], states: npt.ArrayLike, learn_groups: npt.ArrayLike) -> None:
        raise NotImplementedError

    def rank(self, query: Any) -> npt.NDArray[np.int64]:
        raise NotImplementedError


class Engine(Method):
    def __init__(self, params: EngineParams, *, learn: bool = True, name: str = "engine") -> None:
        self.params = params
        self.learn = learn
        self.name = name
        self.index = TourIndex(params)
        self.learned: list[list[float]] = []

    def prepare(self, images: Sequence[Image]) -> list[ImageFeatures]:
        return [extract(im, self.params.features) for im in images]

    def build(
        self, refs: list[ImageFeatures], states: npt.ArrayLike, learn_groups: npt.ArrayLike
    ) -> None:
        self.index = TourIndex(self.params)
        self.index.add(refs, states)
        if self.learn:
            w = learn_weights(self.index.signatures, learn_groups, params=self.params)
            self.index.set_weights(w)
            self.learned.append([round(float(x), 4) for x in w])

    def rank(self, query: ImageFeatures) -> npt.NDArray[np.int64]:
        sim = self.index.query(query)
        return np.argsort(-sim.image, kind="stable").astype(np.int64)


@dataclass
class OrbImage:
    keypoints: npt.NDArray[np.float32]
    descriptors: npt.NDArray[np.uint8] | None


class Baseline(Method):
    """ORB-500, BFMatcher(NORM_HAMMING).knnMatch(k=2) + ratio 0.75 against every image."""

    name = "baseline"

    def __init__(self) -> None:
        self.orb = cv2.ORB.create(nfeatures=500)
        self.matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
        self.refs: list[OrbImage] = []

    def prepare_one(self, image: Image) -> OrbImage:
        grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
        kps, desc = self.orb.detectAndCompute(grey, None)
        pts = np.array([k.pt for k in kps], np.float32).reshape(-1, 2)
        return OrbImage(pts, None if desc is None else np.asarray(desc, np.uint8))

    def prepare(self, images: Sequence[Image]) -> list[OrbImage]:
        return [self.prepare_one(im) for im in images]

    def build(
        self, refs: list[OrbImage], states: npt.ArrayLike, learn_groups: npt.ArrayLike
    ) -> None:
        self.refs = refs

    def good_matches(self, q: OrbImage, r: OrbImage) -> int:
        if q.descriptors is None or r.descriptors is None or len(r.descriptors) < 2:
            return 0
        good = 0
        for pair in self.matcher.knnMatch(q.descriptors, r.descriptors, k=2):
            if len(pair) == 2 and pair[0].distance < RATIO * pair[1].distance:
                good += 1
        return good

    def scores(self, q: OrbImage) -> npt.NDArray[np.float64]:
        return np.array([self.good_matches(q, r) for r in self.refs], np.float64)

    def rank(self, query: OrbImage) -> npt.NDArray[np.int64]:
        return np.argsort(-self.scores(query), kind="stable").astype(np.int64)


# ------------------------------------------------------------------------------ tasks


def corridor(method: Method, ds: Datasets) -> dict[str, Any]:
    refs = method.prepare(ds.corridor_ref)
    qs = method.prepare(ds.corridor_query)
    n = len(refs)
    method.build(refs, np.arange(n), np.arange(n) // 5)
    hit1 = hit5 = 0
    for i, q in zip(ds.corridor_query_ids, qs, strict=True):
        ranked = method.rank(q)
        truth = set(ds.corridor_gt.get(i, []))
        hit1 += int(ranked[0]) in truth
        hit5 += bool(truth.intersection(int(x) for x in ranked[:5]))
    return {"recall@1": hit1 / len(qs), "recall@5": hit5 / len(qs), "n_queries": len(qs)}


def nordland(method: Method, ds: Datasets) -> dict[str, Any]:
    feats = {"summer": method.prepare(ds.summer), "winter": method.prepare(ds.winter)}
    per_dir: dict[str, list[float]] = {}
    for src, dst in (("summer", "winter"), ("winter", "summer")):
        refs = feats[dst]
        n = len(refs)
        method.build(refs, np.arange(n), np.arange(n) // 10)
        err = np.array(
            [abs(int(method.rank(q)[0]) - i) for i, q in enumerate(feats[src])], np.int64
        )
        per_dir[f"{src}->{dst}"] = [float(np.mean(err <= t)) for t in NORDLAND_TOLERANCES]
    curves = np.array(list(per_dir.values()))
    mean = curves.mean(axis=0)
    return {
        "recall@1_tol1": float(mean[1]),
        "recall@1_tol10": float(mean[10]),
        "curve": {"tolerance": list(NORDLAND_TOLERANCES), **per_dir, "mean": mean.tolist()},
        "n_queries": int(sum(len(v) for v in feats.values())),
    }


def triplets(method: Method, ds: Datasets) -> dict[str, Any]:
    feats = method.prepare(ds.triplets)
    places = np.asarray(ds.triplet_place)
    hits = 0
    for i in range(len(feats)):
        others = [j for j in range(len(feats)) if j != i]
        method.build([feats[j] for j in others], places[others], places[others])
        best = others[int(method.rank(feats[i])[0])]
        hits += int(places[best] == places[i])
    return {"top1": hits / len(feats), "n_queries": len(feats)}


def ukbench(method: Method, ds: Datasets) -> dict[str, Any]:
    feats = method.prepare(ds.ukbench)
    n = len(feats)
    group = np.arange(n) // 4
    method.build(feats, np.arange(n), group)
    total = 0
    for i, q in enumerate(feats):
        top = method.rank(q)[:4]
        total += int(np.sum(group[top] == group[i]))
    best = float(sum(min(4, int(np.sum(group == g))) for g in group)) / n
    return {"score": total / n, "max_possible": best, "n_queries": n}


# ------------------------------------------------------------------------------ speed


def synthesise(
    images: Sequence[Image], count: int, seed: int, *, sources: list[int] | None = None
) -> list[Image]:
    """``count`` 320x240 variants of ``images``: random crops (70-100 % of each side),
    brightness x0.6-1.4 and horizontal flips. ``sources``, when given, receives the index in
    ``images`` each variant was made from (the ground truth of the tours' recall)."""
    rng = np.random.default_rng(seed)
    out: list[Image] = []
    for k in range(count):
        s = int(rng.integers(len(images))) if k >= len(images) else k
        if sources is not None:
            sources.append(s)
        src = images[s]
        h, w = src.shape[:2]
        fw, fh = rng.uniform(0.7, 1.0, size=2)
        cw, ch = max(8, int(w * fw)), max(8, int(h * fh))
        x0 = int(rng.integers(0, w - cw + 1))
        y0 = int(rng.integers(0, h - ch + 1))
        crop = cv2.resize(src[y0 : y0 + ch, x0 : x0 + cw], (320, 240), interpolation=cv2.INTER_AREA)
        crop = cv2.convertScaleAbs(crop, alpha=float(rng.uniform(0.6, 1.4)))
        if rng.random() < 0.5:
            crop = np.ascontiguousarray(crop[:, ::-1])
        out.append(np.asarray(crop, np.uint8))
    return out


def _timeit(fn: Callable[[], Any], repeat: int) -> list[float]:
    out = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        out.append((time.perf_counter() - t) * 1e3)
    return out


def _tour(
    pool_feats: Sequence[ImageFeatures],
    n: int,
    params: EngineParams,
    images_per_state: int,
    rng: np.random.Generator,
) -> TourIndex:
    """A synthesised tour of ``n`` images: pool image ``(k * 7919) % pool`` at place ``k``,
    ``images_per_state`` consecutive images per state; copies' signatures jittered."""
    idx = TourIndex(params)
    states = np.arange(n) // images_per_state
    chunk = 10_000
    for lo in range(0, n, chunk):
        hi = min(n, lo + chunk)
        feats = [pool_feats[(k * 7919) % len(pool_feats)] for k in range(lo, hi)]
        idx.add(feats, states[lo:hi])
    if n > len(pool_feats):  # tiled copies: jitter signatures so that rankings are not ties
        sig = idx.signatures
        sig += rng.normal(0, 0.01, size=sig.shape).astype(np.float32)
        idx.set_block_signatures(sig)
    return idx


@dataclass
class _Timing:
    """Per-query figures of one engine on one tour."""

    total: list[float]
    first: list[float]
    second: list[float]
    candidates: list[int]
    scored: list[int]
    top: list[npt.NDArray[np.int64]]

    @classmethod
    def empty(cls) -> _Timing:
        return cls([], [], [], [], [], [])

    def record(self, idx: TourIndex, f: ImageFeatures) -> None:
        t = time.perf_counter()
        sim = idx.query(f)
        self.total.append((time.perf_counter() - t) * 1e3)
        self.first.append(sim.first_pass_ms)
        self.second.append(sim.second_pass_ms)
        self.candidates.append(len(sim.candidates))
        self.scored.append(sim.n_scored)
        self.top.append(sim.candidates[:5].copy())

    def summary(self, n: int, truth: npt.NDArray[np.int64], query_truth: Sequence[int]) -> dict:
        fp = stats(self.first)
        hit1 = [int(truth[t[0]] == q) for t, q in zip(self.top, query_truth, strict=True)]
        hit5 = [int(q in truth[t]) for t, q in zip(self.top, query_truth, strict=True)]
        return {
            "total_ms_p50": stats(self.total)["p50"],
            "total_ms_p95": stats(self.total)["p95"],
            "first_pass_ms_p50": fp["p50"],
            "second_pass_ms_p50": stats(self.second)["p50"],
            "comparisons_per_s": n / (fp["p50"] / 1e3) if fp["p50"] > 0 else float("inf"),
            "candidates_p50": float(np.median(self.candidates)),
            "scored_p50": float(np.median(self.scored)),
            "recall@1": float(np.mean(hit1)),
            "recall@5": float(np.mean(hit5)),
        }


def speed(
    ds: Datasets,
    sizes: Sequence[int],
    *,
    params: EngineParams,
    n_queries: int,
    baseline_queries: Sequence[int],
    images_per_state: int,
    pool: int,
    with_baseline: bool = True,
    compare_index: bool = True,
) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    """Per-query time on synthesised tours; returns (engine, baseline, extraction).

    With ``compare_index`` every tour is answered twice, query by query in turns: by the
    exhaustive first pass and through the inverted files (``EngineParams.index_min_images``
    forced below and above the tour size), side by side in ``engine[n]["exhaustive"]`` and
    ``engine[n]["inverted_files"]``; ``engine[n]`` itself holds the figures of the one the
    engine picks at that size (``engine[n]["automatic"]``). Without it, only the engine as
    ``params`` configure it is timed. Recall: the best image is a variant of the image the
    query was made from (``recall@1``; ``recall@5`` among the five best)."""
    base = ds.triplets + ds.ukbench + ds.corridor_ref + ds.corridor_query
    pool_src: list[int] = []
    query_src: list[int] = []
    pool_imgs = synthesise(base, pool, seed=1, sources=pool_src)
    query_imgs = synthesise(base, max(n_queries, 10), seed=2, sources=query_src)
    pool_feats = [extract(im, params.features) for im in pool_imgs]
    query_feats = [extract(im, params.features) for im in query_imgs]

    frame = query_imgs[0]
    ext: dict[str, Any] = {
        "engine_ms_p50": stats(_timeit(lambda: extract(frame, params.features), 200))["p50"],
    }
    bl = Baseline()
    if with_baseline:
        ext["baseline_orb500_ms_p50"] = stats(_timeit(lambda: bl.prepare_one(frame), 50))["p50"]
        pool_orb = bl.prepare(pool_imgs[: min(pool, 1000)])
        query_orb = bl.prepare(query_imgs[:10])

    engine: dict[str, Any] = {}
    baseline: dict[str, Any] = {}
    rng = np.random.default_rng(3)
    never = replace(params, index_min_images=sys.maxsize)
    always = replace(params, index_min_images=1)
    for si, n in enumerate(sizes):
        states = np.arange(n) // images_per_state
        truth = np.asarray(pool_src, np.int64)[(np.arange(n) * 7919) % len(pool_feats)]
        qtruth = [query_src[k % len(query_feats)] for k in range(n_queries)]
        auto = "inverted_files" if n >= params.index_min_images else "exhaustive"
        if compare_index:
            exhaustive = _tour(pool_feats, n, never, images_per_state, rng)
            t = time.perf_counter()
            indexed = exhaustive.with_params(always)
            build_s = time.perf_counter() - t
            engines = {"exhaustive": exhaustive, "inverted_files": indexed}
        else:
            idx = _tour(pool_feats, n, params, images_per_state, rng)
            auto = "inverted_files" if idx.uses_inverted_files else "exhaustive"
            engines = {auto: idx}
        timing = {name: _Timing.empty() for name in engines}
        for e in engines.values():
            for f in query_feats[:3]:
                e.query(f)  # warm-up
        names = list(engines)
        for k in range(n_queries):
            f = query_feats[k % len(query_feats)]
            for name in names if k % 2 == 0 else names[::-1]:  # in turns: same machine load
                timing[name].record(engines[name], f)
        side = {name: tm.summary(n, truth, qtruth) for name, tm in timing.items()}
        chosen = engines[auto]
        engine[str(n)] = {
            **side[auto],
            "bytes_per_image": chosen.bytes_per_image + chosen.index_bytes_per_image,
            "n_states": int(states.max()) + 1,
            "n_queries": n_queries,
            "automatic": auto,
        }
        if compare_index:
            ex, ix = side["exhaustive"], side["inverted_files"]
            same = [
                int(a[0] == b[0])
                for a, b in zip(timing["exhaustive"].top, timing["inverted_files"].top, strict=True)
            ]
            engine[str(n)]["exhaustive"] = {**ex, "bytes_per_image": exhaustive.bytes_per_image}
            engine[str(n)]["inverted_files"] = {
                **ix,
                "bytes_per_image": indexed.bytes_per_image + indexed.index_bytes_per_image,
                "index_bytes_per_image": indexed.index_bytes_per_image,
                "build_s": build_s,
                "recall@1_points_vs_exhaustive": 100.0 * (ix["recall@1"] - ex["recall@1"]),
                "same_best_image_as_exhaustive": float(np.mean(same)),
                "speedup_vs_exhaustive": ex["total_ms_p50"] / max(ix["total_ms_p50"], 1e-9),
            }
            print(
                f"  speed n={n}: exhaustive {ex['total_ms_p50']:.2f} ms p50 "
                f"(recall@1 {ex['recall@1']:.3f}), inverted files {ix['total_ms_p50']:.2f} ms "
                f"(recall@1 {ix['recall@1']:.3f}, built in {build_s:.1f} s); automatic: {auto}",
                flush=True,
            )
        del engines, chosen
        nq = baseline_queries[min(si, len(baseline_queries) - 1)] if baseline_queries else 0
        if not with_baseline or nq <= 0:  # 0 baseline queries: the baseline skips this size
            continue
        refs = [pool_orb[(k * 7919) % len(pool_orb)] for k in range(n)]
        bl.build(refs, states, states)
        times = []
        for k in range(nq):
            q = query_orb[k % len(query_orb)]
            t = time.perf_counter()
            bl.rank(q)
            times.append((time.perf_counter() - t) * 1e3)
        n_desc = np.mean([0 if r.descriptors is None else len(r.descriptors) for r in pool_orb])
        st = stats(times)
        baseline[str(n)] = {
            "total_ms_p50": st["p50"],
            "total_ms_p95": st["p95"],
            "first_pass_ms_p50": None,
            "second_pass_ms_p50": st["p50"],
            "bytes_per_image": float(n_desc * (32 + 8)),
            "n_queries": nq,
        }
        engine[str(n)]["speedup_vs_baseline"] = st["p50"] / max(
            engine[str(n)]["total_ms_p50"], 1e-9
        )
        print(
            f"  speed n={n}: engine {engine[str(n)]['total_ms_p50']:.2f} ms "
            f"(first {engine[str(n)]['first_pass_ms_p50']:.2f}, "
            f"{engine[str(n)]['candidates_p50']:.0f} candidates), "
            f"baseline {st['p50']:.1f} ms over {nq} queries",
            flush=True,
        )
    notes = {
        "pool": pool,
        "images_per_state": images_per_state,
        "tiling": "tours larger than the pool repeat pool features (signatures jittered by "
        "N(0, 0.01)); the baseline stores the ORB features of the first 1000 pool images "
        "cyclically. Times are measured, never extrapolated; baseline query counts are in "
        "speed.<n>.n_queries.",
        "recall": "recall@1: the best image is a variant of the real image the query was made "
        "from (recall@5: one of the five best); exhaustive and inverted_files answer the same "
        "tour and queries in turns; the engine's own figures are those of speed.<n>.automatic",
    }
    ext["notes"] = notes
    return engine, baseline, ext


# ------------------------------------------------------------------------------ driver


def accuracy(method: Method, ds: Datasets, *, with_nordland: bool = True) -> dict[str, Any]:
    t = time.perf_counter()
    out: dict[str, Any] = {
        "corridor": corridor(method, ds),
        "triplets": triplets(method, ds),
        "ukbench": ukbench(method, ds),
    }
    if with_nordland:
        out["nordland"] = nordland(method, ds)
    out["accuracy_seconds"] = time.perf_counter() - t
    return out


def _summary(acc: dict[str, Any]) -> str:
    nord = acc.get("nordland")
    nordland_text = (
        f"nordland tol1 {nord['recall@1_tol1']:.3f} tol10 {nord['recall@1_tol10']:.3f}"
        if nord
        else "nordland skipped"
    )
    return (
        f"corridor r@1 {acc['corridor']['recall@1']:.3f} r@5 {acc['corridor']['recall@5']:.3f} | "
        f"{nordland_text} | "
        f"triplets {acc['triplets']['top1']:.3f} | ukbench {acc['ukbench']['score']:.2f}"
    )


def run_all(args: argparse.Namespace) -> dict[str, Any]:
    blas = pin_threads()
    quick = bool(args.quick)
    ds = load(Path(args.data), quick)
    sizes_arg = args.sizes or ("300" if quick else "1000,10000,100000")
    sizes = [int(s) for s in sizes_arg.split(",") if s.strip()]
    bq = [int(s) for s in str(args.baseline_queries).split(",") if s.strip()]
    params = EngineParams(features=FeatureParams(descriptor=args.descriptor))
    t0 = time.perf_counter()

    engine = accuracy(Engine(params, learn=False), ds)
    engine["weights"] = [float(x) for x in TourIndex(params).weights]
    print("engine  :", _summary(engine), flush=True)
    baseline = accuracy(Baseline(), ds)
    print("baseline:", _summary(baseline), flush=True)

    variants: dict[str, Any] = {}
    if not quick:
        # the real data through the inverted files (forced on: these sets are far below the
        # threshold), default weights as the engine row: what the approximation costs
        forced = Engine(replace(params, index_min_images=1), learn=False)
        variants["inverted_files"] = accuracy(forced, ds)
        print(f"{'inverted_files':16s}:", _summary(variants["inverted_files"]), flush=True)
    if not (quick or args.no_variants):
        other_geo = replace(params, geometric=not params.geometric)
        # every variant learns its weights per tour (groups of consecutive references), so
        # compare the others with "learned_weights", which differs from "engine" only there
        p50 = replace(params, features=replace(params.features, n_features=50))
        orb = replace(params, features=FeatureParams(descriptor="orb"))
        for name, method in (
            (f"geometric_{'on' if other_geo.geometric else 'off'}", Engine(other_geo, learn=True)),
            ("learned_weights", Engine(params, learn=True)),
            ("features_50", Engine(p50, learn=True)),
            ("orb", Engine(orb, learn=True)),
        ):
            # ORB (256-bit unpacked) against all 1800 Nordland references costs ~10 min: skipped
            variants[name] = accuracy(method, ds, with_nordland=name != "orb")
            if isinstance(method, Engine) and method.learned:
                variants[name]["learned_weights"] = method.learned
            print(f"{name:16s}:", _summary(variants[name]), flush=True)

    eng_speed, base_speed, extraction = speed(
        ds,
        sizes,
        params=params,
        n_queries=20 if quick else args.queries,
        baseline_queries=[min(b, 3) for b in bq] if quick else bq,
        images_per_state=args.images_per_state,
        pool=min(args.pool, 100) if quick else args.pool,
    )
    if "features_50" in variants:
        p50 = replace(params, features=replace(params.features, n_features=50))
        variants["features_50"]["speed"], _, ext50 = speed(
            ds,
            sizes,
            params=p50,
            n_queries=args.queries,
            baseline_queries=bq,
            images_per_state=args.images_per_state,
            pool=args.pool,
            with_baseline=False,
            compare_index=False,
        )
        variants["features_50"]["extraction"] = {"ms_p50": ext50["engine_ms_p50"]}
    engine["speed"] = eng_speed
    baseline["speed"] = base_speed
    engine["extraction"] = {"ms_p50": extraction["engine_ms_p50"], "size": "320x240"}
    baseline["extraction"] = {"ms_p50": extraction["baseline_orb500_ms_p50"], "size": "320x240"}
    return {
        "engine": engine,
        "baseline": baseline,
        "variants": variants,
        "meta": {
            "quick": quick,
            "data": str(Path(args.data).resolve()),
            "engine_params": _params_dict(params),
            "baseline": "ORB nfeatures=500 on the original image, BFMatcher NORM_HAMMING "
            "knnMatch k=2, ratio 0.75, best = most good matches, every stored image",
            "threads": f"OMP/OPENBLAS/MKL_NUM_THREADS=1, {blas}",
            "speed_setup": extraction["notes"],
            "protocol": {
                "corridor": "ref = index (state = each image), query -> ref, ground_truth.json",
                "nordland": "single images, state = each reference image, both directions "
                "averaged; tolerance in frames; learned weights use groups of 10 references",
                "triplets": "leave-one-out over 30 images, state = place",
                "ukbench": "query included in the database, mean same-group count in top 4",
            },
            "variants": "all variants but inverted_files learn their weights per tour (groups "
            "of 5 corridor / 10 Nordland references, places for triplets; defaults where too "
            "small); compare them with variants.learned_weights. ORB skips Nordland (too "
            "slow). inverted_files: the engine row with EngineParams.index_min_images=1 (the "
            "inverted files forced on; run with --no-variants too).",
            "seconds": time.perf_counter() - t0,
        },
    }


def _params_dict(params: EngineParams) -> dict[str, Any]:
    from dataclasses import asdict

    return asdict(params)


def format_table(results: dict[str, Any]) -> str:
    e, b = results["engine"], results["baseline"]
    rows = [
        ("corridor recall@1", e["corridor"]["recall@1"], b["corridor"]["recall@1"]),
        ("corridor recall@5", e["corridor"]["recall@5"], b["corridor"]["recall@5"]),
        ("nordland recall@1 +-1", e["nordland"]["recall@1_tol1"], b["nordland"]["recall@1_tol1"]),
        (
            "nordland recall@1 +-10",
            e["nordland"]["recall@1_tol10"],
            b["nordland"]["recall@1_tol10"],
        ),
        ("triplets top-1", e["triplets"]["top1"], b["triplets"]["top1"]),
        ("ukbench score (of 4)", e["ukbench"]["score"], b["ukbench"]["score"]),
    ]
    for n, s in e["speed"].items():
        nan = float("nan")
        bs = b["speed"].get(n, {"total_ms_p50": nan, "total_ms_p95": nan, "bytes_per_image": nan})
        rows.append((f"{n} images: total ms p50", s["total_ms_p50"], bs["total_ms_p50"]))
        rows.append((f"{n} images: total ms p95", s["total_ms_p95"], bs["total_ms_p95"]))
        rows.append((f"{n} images: first pass ms p50", s["first_pass_ms_p50"], float("nan")))
        rows.append((f"{n} images: second pass ms p50", s["second_pass_ms_p50"], float("nan")))
        rows.append((f"{n} images: bytes/image", s["bytes_per_image"], bs["bytes_per_image"]))
    lines = [f"{'metric':34s} {'engine':>12s} {'baseline':>12s}"]
    for name, ev, bv in rows:
        lines.append(f"{name:34s} {ev:12.3f} {bv:12.3f}")
    lines.append(
        f"extraction ms p50 (320x240): engine {e['extraction']['ms_p50']:.2f}, "
        f"ORB-500 {b['extraction']['ms_p50']:.2f}"
    )
    sides = [(n, sp) for n, sp in e["speed"].items() if "inverted_files" in sp]
    if sides:
        lines.append(
            f"{'tour: first pass':42s} {'ms p50':>8s} {'ms p95':>8s} {'recall@1':>9s} "
            f"{'recall@5':>9s} {'build s':>8s}"
        )
    for n, sp in sides:
        for name in ("exhaustive", "inverted_files"):
            r = sp[name]
            mark = " (automatic)" if sp["automatic"] == name else ""
            lines.append(
                f"{f'{n} images: {name}{mark}':42s} {r['total_ms_p50']:8.2f} "
                f"{r['total_ms_p95']:8.2f} {r['recall@1']:9.3f} {r['recall@5']:9.3f} "
                f"{r.get('build_s', 0.0):8.1f}"
            )
    return "\n".join(lines)


def write_json(results: dict[str, Any], path: Path) -> None:
    _write_json(path, results)


def plot_nordland(results: dict[str, Any], path: Path) -> None:
    """Recall@1 against tolerance (frames) on Nordland, drawn with OpenCV."""
    w, h, m = 640, 420, 60
    img = np.full((h, w, 3), 255, np.uint8)
    tol = results["engine"]["nordland"]["curve"]["tolerance"]
    tmax = max(tol)

    def xy(t: float, r: float) -> tuple[int, int]:
        return int(m + (w - 2 * m) * t / tmax), int(h - m - (h - 2 * m) * r)

    for r in np.linspace(0, 1, 6):
        cv2.line(img, xy(0, r), xy(tmax, r), (225, 225, 225), 1)
        cv2.putText(
            img,
            f"{r:.1f}",
            (10, xy(0, r)[1] + 5),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.45,
            (0, 0, 0),
            1,
            cv2.LINE_AA,
        )
    for t in tol:
        cv2.putText(
            img,
            str(t),
            (xy(t, 0)[0] - 5, h - m + 20),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.45,
            (0, 0, 0),
            1,
            cv2.LINE_AA,
        )
    cv2.rectangle(img, xy(0, 1), xy(tmax, 0), (0, 0, 0), 1)
    series = [
        ("engine summer->winter", "engine", "summer->winter", (200, 80, 0), 2),
        ("engine winter->summer", "engine", "winter->summer", (255, 160, 60), 2),
        ("baseline summer->winter", "baseline", "summer->winter", (0, 0, 200), 1),
        ("baseline winter->summer", "baseline", "winter->summer", (80, 80, 255), 1),
    ]
    for k, (label, who, key, colour, thick) in enumerate(series):
        ys = results[who]["nordland"]["curve"][key]
        pts = np.array([xy(t, r) for t, r in zip(tol, ys, strict=True)], np.int32)
        cv2.polylines(img, [pts], False, colour, thick, cv2.LINE_AA)
        cv2.putText(
            img,
            label,
            (m + 10, m + 20 + 20 * k),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.5,
            colour,
            1,
            cv2.LINE_AA,
        )
    cv2.putText(
        img,
        "Nordland recall@1 vs tolerance (frames)",
        (m, 30),
        cv2.FONT_HERSHEY_SIMPLEX,
        0.6,
        (0, 0, 0),
        1,
        cv2.LINE_AA,
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img)
