"""``teachrepeat bench localize``: sequence localisation on a route recorded twice.

A tour is taught from the reference traversal (a location every ``--location-every`` frames, the
frames in between on the edge joining two consecutive locations, taught at 1 m/s and 10 frames/s),
then the query traversal is replayed through the engine and the belief tracker as a robot
driving forward along the tour at the taught pace. For every query frame the bench records the
reference frame picked by

* ``ir_only``: the single most similar stored image (argmax of the engine's per-image
  similarity; image retrieval alone),
* ``tracker``: the image of the most likely fine state of the filter (a location -> its image,
  an edge image -> that image),
* ``smoother``: the fixed-lag smoother's re-estimate of the frame at the *oldest* end of its
  window (``lag - 1`` frames after it was seen; the final frames use the last window),

and scores them against the ground truth within a tolerance (in frames): ``--tolerance`` and
always 0, 2 and 10 (``recall_at``; the replay does not depend on the tolerance), over the whole
run and over each half of its query frames (``halves``). ``--both-directions`` runs it again with
the traversals swapped (the ground truth inverted); ``--half first|second`` replays only one half
of the query traversal against the part of the reference its ground truth covers, so that
parameters can be chosen on one half and reported on the other. It also runs the
Table 1 protocol of 001 section 9.2 (every other reference frame held out as a query against a
tour of the others; error rate of ``argmax_s sim(s)``), times the engine and the belief + policy
step separately, and times the belief + policy step on a synthetic tour of 10 000 images.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from server.bench.common import DESCRIPTOR_CHOICES, stats, write_json
from server.bench.localize_ambiguity import figures as ambiguity_figures
from server.threads import pin_threads

if TYPE_CHECKING:
    from server.belief.model import Action, TransitionParams
    from server.belief.tracker import TrackerParams
    from server.domain import TourGraph
    from server.vision.features import ImageFeatures
    from server.vision.index import EngineParams, TourIndex
    from server.vision.learning import LearnParams

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
Image = npt.NDArray[np.uint8]

#: tolerances of the recall curve stored in the JSON and plotted
CURVE_TOLERANCES = tuple(range(21))
#: tolerances (frames) every run is scored at, besides its ``--tolerance``
REPORT_TOLERANCES = (0, 2, 10)
#: values of ``--half``: which half of the query traversal a run replays
HALVES = ("first", "second", "all")
#: the three estimates scored per query frame
METHODS = ("ir_only", "tracker", "smoother")
#: frame period and speed of the synthetic teaching run
FRAME_DT = 0.1
SPEED = 1.0


# ------------------------------------------------------------------------------ arguments


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``teachrepeat bench localize``."""
    parser.add_argument("--reference", type=Path, required=True, help="taught traversal folder")
    parser.add_argument("--query", type=Path, required=True, help="repeated traversal folder")
    parser.add_argument(
        "--gt",
        default="same-index",
        help="'same-index' (query k = reference k) or a JSON file: query index -> list of "
        "matching reference indices (default same-index)",
    )
    parser.add_argument(
        "--tolerance", type=int, default=0, help="frames of slack around the truth (default 0)"
    )
    parser.add_argument("--json", type=Path, default=None, help="write the results here")
    parser.add_argument(
        "--both-directions",
        action="store_true",
        help="after reference -> query, run again with the traversals swapped (the query "
        "folder taught, the reference folder replayed; a ground-truth file is inverted)",
    )
    parser.add_argument(
        "--half",
        choices=HALVES,
        default="all",
        help="replay only the first or second half of the query traversal against the part of "
        "the reference its ground truth covers (choose parameters on 'first', report 'second' "
        "and 'all'; default all)",
    )
    parser.add_argument(
        "--location-every", type=int, default=10, help="a location every M frames (default 10)"
    )
    parser.add_argument(
        "--limit", type=int, default=None, help="use only the first K frames of both traversals"
    )
    parser.add_argument(
        "--skip-first", type=int, default=0, help="drop the first S frames of both traversals"
    )
    parser.add_argument(
        "--transitions",
        choices=("bench", "default"),
        default="bench",
        help="'default' TransitionParams, or 'bench': a robot driving on at the taught pace "
        "leaves locations and edge ends quickly (see docs/localize.md; default bench)",
    )
    parser.add_argument(
        "--action",
        choices=("policy", "navigate"),
        default="policy",
        help="action given to the tracker: Navigate along the policy's edge (policy) or "
        "Navigate(None) (default policy)",
    )
    parser.add_argument(
        "--weights",
        default="learned",
        help="signature block weights (hist, thumb, desc_mean, desc_var, patch): 'learned' on "
        "the reference tour as the server does, 'default' (engine defaults), 'patch' (the "
        "patch-normalised thumbnail only) or five comma-separated numbers (default learned)",
    )
    parser.add_argument(
        "--appearance",
        choices=("models", "single"),
        default="models",
        help="'models': two appearance models (the weights above and the change-robust ones) "
        "weighed by the tracker; 'single': the weights above alone, as the server navigates "
        "today (default models; docs/localize.md)",
    )
    parser.add_argument(
        "--no-change-gate",
        action="store_true",
        help="with two appearance models: let them compete on every frame, also on frames "
        "the tour's model recognises in its own light (AppearanceParams.change_gate off; "
        "docs/localize.md)",
    )
    parser.add_argument(
        "--learn-changed",
        type=int,
        default=0,
        metavar="N",
        help="learn the weights also on N tour images under random changes of light "
        "(LearnParams.changed_images; default 0, see docs/localize.md)",
    )
    parser.add_argument(
        "--descriptor",
        choices=DESCRIPTOR_CHOICES,
        default="grad36",
        help="local features, FeatureParams.descriptor (default grad36; docs/retrieval.md)",
    )
    parser.add_argument("--lag", type=int, default=10, help="smoother window (default 10)")
    parser.add_argument(
        "--likelihood-power",
        type=float,
        default=BENCH_LIKELIHOOD_POWER,
        help="TrackerParams.likelihood_power: the engine's similarities are raised to this "
        f"power (default {BENCH_LIKELIHOOD_POWER}, chosen on the first halves; the server "
        "navigates with 1.0; docs/localize.md)",
    )
    parser.add_argument(
        "--changed-likelihood-power",
        default="navigation",
        help="TrackerParams.changed_likelihood_power: the power the similarities are raised to "
        "once the change gate is open, interpolated from --likelihood-power as it opens: a "
        "number, 'navigation' (the default: navigation's own, 0.75) or 'none' "
        "(--likelihood-power at every frame; docs/localize.md)",
    )
    parser.add_argument("--no-table1", action="store_true", help="skip the Table 1 protocol")
    parser.add_argument(
        "--size-10k", type=int, default=10_000, help="images of the synthetic step-time tour"
    )
    parser.add_argument("--plot", type=Path, default=None, help="draw the belief-over-time PNG")
    parser.add_argument(
        "--recall-plot", type=Path, default=None, help="draw the recall-vs-tolerance PNG"
    )


# ------------------------------------------------------------------------------ data


def list_frames(folder: Path) -> list[Path]:
    """The PNG / JPEG frames of ``folder`` in name order."""
    files = [p for p in folder.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg")]
    return sorted(files)


def read_image(path: Path) -> Image:
    """A BGR uint8 image (``FileNotFoundError`` if unreadable)."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise FileNotFoundError(f"cannot read image {path}")
    return np.asarray(img, np.uint8)


@dataclass(frozen=True)
class GroundTruth:
    """Which reference frames match a query frame.

    ``matches`` is ``None`` for "same index" (query k matches reference k), else a map from
    query index to the listed reference indices.
    """

    matches: dict[int, tuple[int, ...]] | None = None

    @classmethod
    def parse(cls, spec: str) -> GroundTruth:
        """``"same-index"`` or the path of a JSON file ``{query: [reference, ...]}``."""
        if spec == "same-index":
            return cls(None)
        raw = json.loads(Path(spec).read_text())
        return cls({int(k): tuple(int(x) for x in v) for k, v in raw.items()})

    def error(self, query: int, reference: int) -> float:
        """Frames between ``reference`` and the nearest matching reference of ``query``
        (``inf`` when the query has no listed match)."""
        if self.matches is None:
            return float(abs(reference - query))
        listed = self.matches.get(query)
        if not listed:
            return math.inf
        return float(min(abs(reference - t) for t in listed))

    def has_truth(self, query: int) -> bool:
        return self.matches is None or bool(self.matches.get(query))

    def inverted(self) -> GroundTruth:
        """The truth with the traversals swapped: same-index stays same-index, a listed map
        ``query -> references`` becomes ``reference -> queries`` (:func:`invert_matches`)."""
        if self.matches is None:
            return self
        return GroundTruth(invert_matches(self.matches))

    def covered(self, query_frames: Sequence[int]) -> list[int]:
        """The reference frames listed for ``query_frames`` (same-index: the frames themselves),
        sorted, without repeats."""
        if self.matches is None:
            return sorted(set(query_frames))
        return sorted({r for q in query_frames for r in self.matches.get(q, ())})


def invert_matches(matches: Mapping[int, Sequence[int]]) -> dict[int, tuple[int, ...]]:
    """Swap the roles of the traversals in a ground-truth map.

    ``matches``: query frame -> its matching reference frames. Returns reference frame -> the
    query frames that list it (sorted). A reference frame no query lists has no entry (it is not
    scored when it is replayed as a query), nor has a query with an empty list; so
    ``invert_matches(invert_matches(m))`` is ``m`` without its empty entries (lists sorted).
    """
    out: dict[int, set[int]] = {}
    for q, refs in matches.items():
        for r in refs:
            out.setdefault(int(r), set()).add(int(q))
    return {r: tuple(sorted(qs)) for r, qs in sorted(out.items())}


def half_frames(frames: Sequence[int], half: str) -> list[int]:
    """``first``: ``frames[: n // 2]``; ``second``: ``frames[n // 2 :]``; ``all``: all of them."""
    n = len(frames)
    if half == "first":
        return list(frames[: n // 2])
    if half == "second":
        return list(frames[n // 2 :])
    if half == "all":
        return list(frames)
    raise ValueError(f"half must be one of {', '.join(HALVES)}, got {half!r}")


def select_half(
    query_frames: Sequence[int], reference_frames: Sequence[int], gt: GroundTruth, half: str
) -> tuple[list[int], list[int]]:
    """The frames a ``--half`` run replays: ``(query frames, reference frames)``.

    The query frames are that half of ``query_frames`` (:func:`half_frames`); the reference
    frames are those of ``reference_frames`` from the smallest to the largest reference frame
    the ground truth lists for them (same-index: the same frames, so the same half of both when
    the traversals are equally long). Frame numbers stay the original ones, so ``gt`` applies
    unchanged. ``half == "all"`` returns both lists whole. ``ValueError`` when the ground truth
    lists nothing for that half or none of it is among ``reference_frames``.
    """
    qry = half_frames(query_frames, half)
    if half == "all":
        return qry, list(reference_frames)
    covered = gt.covered(qry)
    ref = [r for r in reference_frames if covered and covered[0] <= r <= covered[-1]]
    if not ref:
        raise ValueError(
            f"the ground truth lists no reference frame for the {half} half of the query "
            f"traversal (frames {qry[0] if qry else '-'}..{qry[-1] if qry else '-'}); "
            "check --gt, --limit and --skip-first"
        )
    return qry, ref


# ------------------------------------------------------------------------------ tour


@dataclass(frozen=True)
class Tour:
    """A taught tour and the reference frame behind every image / fine state / upper state.

    * ``image_frame``: ``(n_images,)`` reference frame of each image, canonical order.
    * ``fine_frame``: ``(n_fine,)`` reference frame of each fine state.
    * ``state_frames``: per upper state, its reference frames.
    """

    graph: TourGraph
    image_frame: IntArray
    fine_frame: IntArray
    state_frames: tuple[tuple[int, ...], ...]


def build_tour(frames: Sequence[int], every: int, *, first_id: int = 0) -> Tour:
    """A linear tour over the reference ``frames`` (original frame numbers, in order).

    A location at positions ``0, every, 2 every, ...`` of ``frames`` and at the last one; the
    frames in between form the edge joining two consecutive locations, taught at ``SPEED`` m/s
    with timestamps ``frame * FRAME_DT`` (w = 0). Image ids are ``first_id + position``.
    """
    from server.domain import Edge, Location, TourGraph

    n = len(frames)
    if n == 0:
        raise ValueError("no reference frames")
    every = max(1, int(every))
    marks = list(range(0, n, every))
    if marks[-1] != n - 1:
        marks.append(n - 1)
    locations = tuple(Location(name=f"f{frames[p]}", image_ids=(first_id + p,)) for p in marks)
    edges: list[Edge] = []
    for k in range(len(marks) - 1):
        inner = list(range(marks[k] + 1, marks[k + 1]))
        if not inner:
            continue
        t = np.asarray([frames[p] * FRAME_DT for p in inner], np.float64)
        edges.append(
            Edge(
                source=k,
                target=k + 1,
                image_ids=tuple(first_id + p for p in inner),
                timestamps=t,
                v=np.full(len(inner), SPEED),
                w=np.zeros(len(inner)),
            )
        )
    graph = TourGraph(locations=locations, edges=tuple(edges))
    image_frame = np.asarray([frames[int(i) - first_id] for i in graph.image_ids], np.int64)
    fine_frame = np.empty(graph.n_fine, np.int64)
    fine_frame[graph.image_fine] = image_frame
    state_frames: list[list[int]] = [[] for _ in range(graph.n_states)]
    for s, f in zip(graph.image_state, image_frame, strict=True):
        state_frames[int(s)].append(int(f))
    return Tour(graph, image_frame, fine_frame, tuple(tuple(x) for x in state_frames))


#: ``TrackerParams.likelihood_power`` of the replay: with two appearance models the mixed
#: similarities are tempered (``L ** 0.75``) so that one look-alike frame cannot take the
#: belief away from where the route has been. Chosen among 0.5, 0.75 and 1.0 on the first halves
#: of the shared data sets, tracker recall@1 at 0.5 / 0.75 / 1.0: corridor query -> ref at +-0
#: 0.964 / 0.982 / 0.964; Nordland at +-10 summer -> winter 0.904 / 0.907 / 0.809, winter ->
#: summer 0.833 / 0.823 / 0.709. Navigation keeps 1.0 (with two models, since 2026-11-28): at
#: 0.75 and 0.5 simulated trials arrived at the wrong place or got lost more often
#: (docs/localize.md).
BENCH_LIKELIHOOD_POWER = 0.75


def bench_transitions() -> TransitionParams:
    """Transition probabilities for a robot that drives on at the taught pace: it is at a
    location for about one frame, so mass leaves locations (0.7 per frame along the edge being
    driven; with ``--action navigate`` there is no active edge and the "other edges" 0.3 applies)
    and edge ends (0.8) in a frame or two; the defaults (0.2, 0.3) hold it there for ~5 frames,
    tuned for a robot that stops and spins at every location. The replay's odometry always says
    the robot moved, so a stall (no advance in a frame) is rare: 0.01 (0.1, the default, made
    the belief trail the robot by a frame or more after every location; chosen on the first
    halves of the shared data sets, where 0 to 0.02 differ by under 1 point). Past the last
    location, which no edge leaves, the robot drives on as it drives off an edge's end: 0.8
    per frame of that location's mass spreads like the prior (``navigate_dead_end``; the
    default 0.2 kept it there, and a look-alike image at the end of Nordland's first half held
    the belief for up to 150 frames: winter -> summer on that half 0.41 -> 0.71 at +-10)."""
    from server.belief.model import TransitionParams

    return TransitionParams(
        navigate_exit=0.8,
        navigate_loc_to_active_edge=0.7,
        navigate_loc_to_other_edges=0.3,
        navigate_edge_to_sibling=0.0,
        navigate_stall=0.01,
        navigate_dead_end=0.8,
    )


# ------------------------------------------------------------------------------ engine


def parse_weights(spec: str) -> tuple[float, ...] | None:
    """``--weights``: None for 'learned' / 'default', else the five block weights."""
    if spec in ("learned", "default"):
        return None
    if spec == "patch":
        return PATCH_WEIGHTS
    values = tuple(float(x) for x in spec.split(","))
    if len(values) != len(PATCH_WEIGHTS):
        raise ValueError(f"--weights needs {len(PATCH_WEIGHTS)} numbers, got {spec!r}")
    return values


#: only the patch-normalised thumbnail (illumination / season invariant, SeqSLAM's signature)
PATCH_WEIGHTS = (0.0, 0.0, 0.0, 0.0, 1.0)


def make_index(
    feats: Sequence[ImageFeatures],
    graph: TourGraph,
    params: EngineParams,
    *,
    learn: bool = True,
    image_of: Callable[[int], Image] | None = None,
    learn_params: LearnParams | None = None,
) -> TourIndex:
    """The tour's engine index with weights learned on it, as the navigation service does.

    ``feats[p]`` are the features of image id ``p`` (the tour's ``p``-th reference frame, as
    :func:`build_tour` numbers them) and ``image_of(p)`` its image (for the changed-light views
    the learning makes with ``learn_params.changed_images`` > 0; ``None``: learn from the
    features alone); the index holds them in canonical image order.
    """
    from server.vision.index import TourIndex
    from server.vision.learning import LearnParams, learn_tour_weights

    index = TourIndex(params)
    ids = [int(i) for i in graph.image_ids]
    index.add([feats[p] for p in ids], graph.image_state)
    if learn:
        source = None if image_of is None else (lambda i: image_of(ids[i]))
        index.set_weights(learn_tour_weights(index, source, learn=learn_params or LearnParams()))
    return index


def table1(
    feats: Sequence[ImageFeatures], every: int, params: EngineParams, *, learn: bool = True
) -> dict[str, Any]:
    """001 Table 1: every other reference frame is a query against a tour of the others; the
    error rate of the most likely state by single-image similarity ``argmax_s sim(s)``.

    The tour keeps frames 0, 2, 4, ... (a location every ``every // 2`` kept frames, so at the
    same frames as the full tour when ``every`` is even). ``error_rate`` counts a guess right when
    it is the state of either kept neighbour of frame k (k - 1 or k + 1: a frame next to a
    one-frame location is as close to the location as to the edge); ``strict_error_rate`` only
    accepts the edge whose locations bracket k.
    """
    n = len(feats)
    kept = list(range(0, n, 2))
    held = list(range(1, n, 2))
    if len(kept) < 2 or not held:
        return {"error_rate": float("nan"), "queries": 0}
    tour = build_tour(kept, max(1, every // 2))
    index = make_index([feats[k] for k in kept], tour.graph, params, learn=learn)
    graph = tour.graph
    state_of = {int(f): int(s) for f, s in zip(tour.image_frame, graph.image_state, strict=True)}
    L = tour.graph.n_locations
    loc_frame = [tour.state_frames[k][0] for k in range(L)]
    edge_span = [(loc_frame[e.source], loc_frame[e.target]) for e in tour.graph.edges]
    wrong = strict_wrong = 0
    for k in held:
        # lenient: the state of either kept neighbour (k - 1 or k + 1); a frame next to a
        # one-frame location lies on the boundary between the location and the edge
        near = {state_of[f] for f in (k - 1, k + 1) if f in state_of}
        # strict: the edge whose locations bracket k (001: where the image was captured)
        strict = next((L + j for j, (a, b) in enumerate(edge_span) if a < k < b), None)
        guess = int(np.argmax(index.query(feats[k], n_states=tour.graph.n_states).state))
        wrong += int(guess not in near)
        strict_wrong += int(guess != (strict if strict is not None else min(near)))
    return {
        "error_rate": wrong / len(held),
        "strict_error_rate": strict_wrong / len(held),
        "queries": len(held),
        "tour_images": len(kept),
        "states": tour.graph.n_states,
    }


# ------------------------------------------------------------------------------ replay


@dataclass
class Replay:
    """Per query frame results of one replay (reference frame numbers)."""

    query: list[int] = field(default_factory=list)
    ir_only: list[int] = field(default_factory=list)
    tracker: list[int] = field(default_factory=list)
    smoother: list[int] = field(default_factory=list)
    localised_frames: list[tuple[int, ...] | None] = field(default_factory=list)
    step_ms: list[float] = field(default_factory=list)
    smooth_ms: list[float] = field(default_factory=list)
    engine_ms: list[float] = field(default_factory=list)
    extract_ms: list[float] = field(default_factory=list)
    changed: list[float] = field(default_factory=list)
    """Per frame, the tracker's belief that the change-robust appearance model holds (0 with
    one model)."""
    light_change: list[float] = field(default_factory=list)
    """Per frame, the change evidence the tracker weighed the models with (1 with one model;
    :mod:`server.belief.appearance`)."""


def next_action(decision_action: Action, mode: str) -> Action:
    """The motion the robot executes next: it always drives forward (Navigate); with
    ``mode == "policy"`` along the edge the policy chose (active edge or edge to find)."""
    from server.belief.model import Action, ActionKind

    if mode == "policy" and decision_action.kind in (
        ActionKind.NAVIGATE,
        ActionKind.ROTATE_AND_FIND_EDGE,
    ):
        return Action.navigate(decision_action.edge)
    return Action.navigate(None)


def replay(
    tour: Tour,
    index: TourIndex,
    query_frames: Sequence[int],
    query_images: Sequence[Image],
    *,
    transitions: TransitionParams,
    tracker_params: TrackerParams,
    action_mode: str,
    progress: bool = True,
) -> Replay:
    """Drive the query traversal through engine, tracker and policy (see the module doc)."""
    from server.belief.appearance import familiarity
    from server.belief.model import Action, build_model
    from server.belief.tracker import Tracker, fine_likelihood
    from server.navigation.runtime import related_states
    from server.policy.costs import CostParams, cost_to_goal
    from server.policy.voting import decide
    from server.vision.features import extract

    graph = tour.graph
    model = build_model(graph, transitions)
    model.warm_up()
    tracker = Tracker(model, tracker_params)
    goal = graph.n_locations - 1
    costs = cost_to_goal(graph, goal, CostParams())
    fp = index.params.features
    levels = (
        index.error_levels(related_states(graph))
        if index.params.changed_weights is not None and tracker_params.appearance.change_gate
        else np.zeros(0)
    )
    out = Replay()
    n = len(query_frames)
    smoothed: list[int | None] = [None] * n
    action = Action.navigate(None)
    for i, (qf, img) in enumerate(zip(query_frames, query_images, strict=True)):
        t0 = time.perf_counter()
        feats = extract(img, fp)
        t1 = time.perf_counter()
        sims = index.query_models(feats, n_states=graph.n_states)
        lik = np.stack([fine_likelihood(s.image, graph) for s in sims])
        best = int(np.argmax(sims[0].image))  # ir_only: retrieval with the tour's weights
        known = familiarity(sims[0].best_error, levels) if len(sims) > 1 else math.nan
        t2 = time.perf_counter()
        summary = tracker.step(action, lik, v=SPEED, dt=FRAME_DT, familiarity=known)
        decision = decide(graph, summary.belief, goal, costs)
        t3 = time.perf_counter()
        action = next_action(decision.action, action_mode)
        traj = tracker.smoothed()
        t4 = time.perf_counter()
        if traj is not None:
            # window entry j is step (i + 1) - (len - 1) + j; step s saw query frame s - 1
            first = i + 1 - (len(traj.fine) - 1)
            for j, f in enumerate(traj.fine):
                k = first + j - 1
                if 0 <= k < n and (j == 0 or smoothed[k] is None or i == n - 1):
                    smoothed[k] = int(tour.fine_frame[int(f)])
        out.query.append(int(qf))
        out.ir_only.append(int(tour.image_frame[best]))
        out.changed.append(float(summary.appearance[-1]) if len(lik) > 1 else 0.0)
        out.light_change.append(float(summary.light_change))
        out.tracker.append(int(tour.fine_frame[int(np.argmax(summary.belief))]))
        out.localised_frames.append(
            tour.state_frames[summary.localised_state]
            if summary.localised and summary.localised_state is not None
            else None
        )
        out.extract_ms.append((t1 - t0) * 1e3)
        out.engine_ms.append((t2 - t0) * 1e3)
        out.step_ms.append((t3 - t2) * 1e3)
        out.smooth_ms.append((t4 - t3) * 1e3)
        if progress and (i + 1) % 200 == 0:
            print(f"  {i + 1}/{n} frames")
    out.smoother = [s if s is not None else t for s, t in zip(smoothed, out.tracker, strict=True)]
    return out


# ------------------------------------------------------------------------------ scoring


def errors(query: Sequence[int], estimate: Sequence[int], gt: GroundTruth) -> FloatArray:
    """``(n,)`` frames between each estimate and the nearest true reference frame."""
    return np.asarray([gt.error(q, r) for q, r in zip(query, estimate, strict=True)], np.float64)


def score(err: FloatArray, tolerance: int) -> dict[str, float]:
    """``recall@1`` (error <= tolerance) and ``mean_error_frames`` over frames with a truth."""
    ok = np.isfinite(err)
    if not ok.any():
        return {"recall@1": float("nan"), "mean_error_frames": float("nan")}
    return {
        "recall@1": float(np.mean(err[ok] <= tolerance)),
        "mean_error_frames": float(np.mean(err[ok])),
    }


def score_at(err: FloatArray, tolerances: Sequence[int]) -> dict[str, dict[str, float]]:
    """:func:`score` at every tolerance at once: ``{str(t): {"recall@1", "mean_error_frames"}}``.

    ``err``: ``(n,)`` errors in frames, ``inf`` for frames without a truth (not scored).
    """
    ok = np.isfinite(err)
    tol = np.asarray(tolerances, np.float64)
    if not ok.any():
        nan = {"recall@1": float("nan"), "mean_error_frames": float("nan")}
        return {str(int(t)): dict(nan) for t in tolerances}
    recall = np.mean(err[ok][:, None] <= tol[None, :], axis=0)
    mean = float(np.mean(err[ok]))
    return {
        str(int(t)): {"recall@1": float(r), "mean_error_frames": mean}
        for t, r in zip(tolerances, recall, strict=True)
    }


def recall_at(
    errs: Mapping[str, FloatArray], tolerances: Sequence[int]
) -> dict[str, dict[str, dict[str, float]]]:
    """Per tolerance, per method: ``{str(t): {method: {"recall@1", "mean_error_frames"}}}``.

    ``errs``: method -> ``(n,)`` errors in frames of the same query frames. The mean error does
    not depend on the tolerance; it is repeated so that every entry has :func:`score`'s shape.
    """
    per_method = {name: score_at(e, tolerances) for name, e in errs.items()}
    return {
        str(int(t)): {name: s[str(int(t))] for name, s in per_method.items()} for t in tolerances
    }


def report_tolerances(tolerance: int) -> list[int]:
    """:data:`REPORT_TOLERANCES` and the run's own ``tolerance``, sorted."""
    return sorted({*REPORT_TOLERANCES, int(tolerance)})


def halves_scores(errs: Mapping[str, FloatArray], tolerances: Sequence[int]) -> dict[str, Any]:
    """:func:`recall_at` on the first and on the second half of a run's query frames (split as
    :func:`half_frames` splits them): ``{"first": {"frames", "recall_at"}, "second": ...}``."""
    n = len(next(iter(errs.values()))) if errs else 0
    out: dict[str, Any] = {}
    for half in ("first", "second"):
        pos = half_frames(range(n), half)
        part = {name: e[pos] for name, e in errs.items()}
        out[half] = {"frames": len(pos), "recall_at": recall_at(part, tolerances)}
    return out


def converged_after(right: npt.NDArray[np.bool_], window: int = 20) -> dict[str, int | None]:
    """``stays_right``: first frame after which the tracker is never wrong again (None if the
    last frame is wrong); ``first_run``: first frame starting ``window`` right frames in a row
    (or the rest of the sequence, if shorter)."""
    n = len(right)
    stays: int | None = None
    if n and right[-1]:
        wrong = np.flatnonzero(~right)
        stays = int(wrong[-1]) + 1 if len(wrong) else 0
    first: int | None = None
    for k in range(n):
        w = min(window, n - k)
        if right[k : k + w].all():
            first = k
            break
    return {"stays_right": stays, "first_run": first}


def max_wrong_localised_run(
    query: Sequence[int],
    localised: Sequence[tuple[int, ...] | None],
    gt: GroundTruth,
    tolerance: int,
) -> int:
    """Longest run of frames flagged "localised" on an upper state none of whose reference
    frames is within ``tolerance`` of the truth."""
    best = run = 0
    for q, frames in zip(query, localised, strict=True):
        wrong = (
            frames is not None
            and gt.has_truth(q)
            and min(gt.error(q, f) for f in frames) > (tolerance)
        )
        run = run + 1 if wrong else 0
        best = max(best, run)
    return best


# ------------------------------------------------------------------------------ 10k step


def step_time_synthetic(
    n_images: int,
    transitions: TransitionParams,
    tracker_params: TrackerParams,
    *,
    action_mode: str = "policy",
    steps: int = 300,
) -> dict[str, Any]:
    """Belief + policy step time on a linear tour of ``n_images`` images (a location every 10).

    The cost depends only on the sizes, so the likelihoods are synthetic: uniform noise in
    [0.001, 0.3] plus a bump of 1 on the fine state of a robot advancing one image per step
    (so the policy's active edge changes every ~10 steps, as in a real run). A new active edge
    builds that action's structure once (``BeliefModel`` caches 16): this shows in p95 / p99.
    """
    from server.belief.model import Action, build_model
    from server.belief.tracker import Tracker
    from server.policy.costs import CostParams, cost_to_goal
    from server.policy.voting import decide

    tour = build_tour(list(range(n_images)), 10)
    graph = tour.graph
    model = build_model(graph, transitions)
    model.warm_up()
    tracker = Tracker(model, tracker_params)
    goal = graph.n_locations - 1
    costs = cost_to_goal(graph, goal, CostParams())
    frame_fine = np.empty(graph.n_fine, np.int64)
    frame_fine[tour.fine_frame] = np.arange(graph.n_fine)
    rng = np.random.default_rng(0)
    action = Action.navigate(None)
    times: list[float] = []
    smooth: list[float] = []
    for i in range(steps):
        lik = rng.uniform(1e-3, 0.3, graph.n_fine)
        lik[frame_fine[(n_images // 3 + i) % n_images]] = 1.0
        t0 = time.perf_counter()
        summary = tracker.step(action, lik, v=SPEED, dt=FRAME_DT)
        decision = decide(graph, summary.belief, goal, costs)
        t1 = time.perf_counter()
        action = next_action(decision.action, action_mode)
        if i % 10 == 0:
            t2 = time.perf_counter()
            tracker.smoothed()
            smooth.append((time.perf_counter() - t2) * 1e3)
        times.append((t1 - t0) * 1e3)
    warm = times[10:]
    return {
        "images": graph.n_images,
        "fine_states": graph.n_fine,
        "steps": len(warm),
        "action": action_mode,
        "step_ms": stats(warm),
        "smoother_ms": stats(smooth),
    }


# ------------------------------------------------------------------------------ plots


def _canvas(w: int, h: int) -> Image:
    return np.full((h, w, 3), 255, np.uint8)


def _text(img: Image, s: str, xy: tuple[int, int], scale: float = 0.45) -> None:
    import cv2

    cv2.putText(img, s, xy, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 1, cv2.LINE_AA)


COLOURS: dict[str, tuple[int, int, int]] = {
    "ir_only": (40, 40, 220),  # BGR red
    "tracker": (200, 90, 20),  # blue
    "smoother": (40, 160, 40),  # green
}


def _axes(
    img: Image, box: tuple[int, int, int, int], xmax: float, ymax: float, xlabel: str, ylabel: str
) -> None:
    import cv2

    x0, y0, x1, y1 = box
    cv2.rectangle(img, (x0, y0), (x1, y1), (0, 0, 0), 1)
    for k in range(6):
        fx = x0 + (x1 - x0) * k // 5
        fy = y1 - (y1 - y0) * k // 5
        cv2.line(img, (fx, y1), (fx, y1 + 4), (0, 0, 0), 1)
        cv2.line(img, (x0 - 4, fy), (x0, fy), (0, 0, 0), 1)
        cv2.line(img, (x0 + 1, fy), (x1 - 1, fy), (225, 225, 225), 1)
        _text(img, _fmt(xmax * k / 5), (fx - 10, y1 + 18), 0.4)
        _text(img, _fmt(ymax * k / 5), (x0 - 42, fy + 4), 0.4)
    _text(img, xlabel, ((x0 + x1) // 2 - 60, y1 + 38))
    _text(img, ylabel, (6, y0 - 10))


def _fmt(v: float) -> str:
    return f"{v:.0f}" if v >= 10 or float(v).is_integer() else f"{v:.1f}"


def plot_recall(curves: dict[str, Sequence[float]], title: str, path: Path) -> None:
    """Recall@1 vs tolerance (frames) for each method: a PNG drawn with OpenCV."""
    import cv2

    w, h = 640, 420
    img = _canvas(w, h)
    box = (60, 50, w - 150, h - 60)
    tmax = float(len(CURVE_TOLERANCES) - 1)
    _axes(img, box, tmax, 1.0, "tolerance (frames)", "recall@1")
    x0, y0, x1, y1 = box

    def xy(t: float, r: float) -> tuple[int, int]:
        return int(x0 + (x1 - x0) * t / tmax), int(y1 - (y1 - y0) * r)

    for k, (name, ys) in enumerate(curves.items()):
        col = COLOURS.get(name, (0, 0, 0))
        pts = [xy(t, r) for t, r in zip(CURVE_TOLERANCES, ys, strict=False)]
        for a, b in itertools.pairwise(pts):
            cv2.line(img, a, b, col, 2, cv2.LINE_AA)
        for p in pts:
            cv2.circle(img, p, 3, col, -1, cv2.LINE_AA)
        cv2.line(img, (x1 + 12, y0 + 20 + 22 * k), (x1 + 36, y0 + 20 + 22 * k), col, 2)
        _text(img, name, (x1 + 42, y0 + 25 + 22 * k))
    _text(img, title, (x0, 30), 0.5)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img)


def plot_belief(result: Replay, gt: GroundTruth, title: str, path: Path) -> None:
    """The tracker's most likely reference frame (blue) and image retrieval's pick (red dots)
    against the query frame; the grey band is the ground truth."""
    import cv2

    w, h = 640, 520
    img = _canvas(w, h)
    box = (60, 50, w - 20, h - 60)
    x0, y0, x1, y1 = box
    q = np.asarray(result.query, np.float64)
    refs = np.asarray(result.tracker + result.ir_only, np.float64)
    qmax = float(q.max())
    rmax = max(float(refs.max()), qmax, 1.0)
    _axes(img, box, qmax, rmax, "query frame", "reference frame (most likely)")

    def xy(a: float, b: float) -> tuple[int, int]:
        return int(x0 + (x1 - x0) * a / max(qmax, 1.0)), int(y1 - (y1 - y0) * b / rmax)

    for qf in result.query:
        truths: tuple[int, ...] = (qf,) if gt.matches is None else gt.matches.get(qf, ())
        for t in truths:
            cv2.circle(img, xy(qf, t), 2, (200, 200, 200), -1)
    for qf, r in zip(result.query, result.ir_only, strict=True):
        cv2.circle(img, xy(qf, r), 1, COLOURS["ir_only"], -1)
    pts = [xy(a, b) for a, b in zip(result.query, result.tracker, strict=True)]
    for a, b in itertools.pairwise(pts):
        cv2.line(img, a, b, COLOURS["tracker"], 1, cv2.LINE_AA)
    _text(img, title, (x0, 20), 0.5)
    _text(img, "grey: truth   red: ir_only   blue: tracker", (x1 - 330, y1 + 52), 0.42)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img)


# ------------------------------------------------------------------------------ run


@dataclass(frozen=True)
class RunSettings:
    """How every direction of one invocation is run (from the command line).

    ``location_every``: frames per location of the taught tour; ``learn``: learn the signature
    weights on each direction's reference tour (``--weights learned``); ``action``: ``"policy"``
    or ``"navigate"`` (see :func:`next_action`); ``learn_params``: how they are learned.
    """

    location_every: int
    engine: EngineParams
    learn: bool
    transitions: TransitionParams
    tracker: TrackerParams
    action: str
    learn_params: LearnParams = field(default_factory=lambda: _learn_params(0))


@dataclass(frozen=True)
class DirectionPlan:
    """What one direction of an invocation replays.

    ``reference`` is taught, ``query`` replayed; ``ref_frames`` / ``qry_frames`` are the
    original frame numbers used (after ``--skip-first``, ``--limit`` and ``--half``); ``gt``
    maps query frames to reference frames, ``gt_spec`` describes it in the JSON.
    """

    name: str
    reference: Path
    query: Path
    gt: GroundTruth
    gt_spec: str
    ref_frames: list[int]
    qry_frames: list[int]


@dataclass(frozen=True)
class DirectionRun:
    """One direction's replay: ``errors`` maps each method to ``(len(plan.qry_frames),)``
    float64 errors in frames (``inf`` where the query frame has no truth); ``build_s``: seconds
    to extract the reference and build its index."""

    plan: DirectionPlan
    tour: Tour
    index: TourIndex
    ref_feats: list[ImageFeatures]
    replay: Replay
    errors: dict[str, FloatArray]
    build_s: float


def run_direction(plan: DirectionPlan, settings: RunSettings) -> DirectionRun:
    """Teach the plan's reference frames, replay its query frames, score every estimate."""
    from server.vision.features import extract

    ref_files, qry_files = list_frames(plan.reference), list_frames(plan.query)
    ref_frames, qry_frames = plan.ref_frames, plan.qry_frames
    print(
        f"{plan.name}: reference {plan.reference} frames {ref_frames[0]}..{ref_frames[-1]}, "
        f"query {plan.query} frames {qry_frames[0]}..{qry_frames[-1]}, a location every "
        f"{settings.location_every}"
    )
    t0 = time.perf_counter()
    ref_feats = [extract(read_image(ref_files[k]), settings.engine.features) for k in ref_frames]
    tour = build_tour(ref_frames, settings.location_every)
    index = make_index(
        ref_feats,
        tour.graph,
        settings.engine,
        learn=settings.learn,
        image_of=lambda p: read_image(ref_files[ref_frames[p]]),
        learn_params=settings.learn_params,
    )
    build_s = time.perf_counter() - t0
    qry_images = [read_image(qry_files[k]) for k in qry_frames]
    res = replay(
        tour,
        index,
        qry_frames,
        qry_images,
        transitions=settings.transitions,
        tracker_params=settings.tracker,
        action_mode=settings.action,
    )
    estimates = {"ir_only": res.ir_only, "tracker": res.tracker, "smoother": res.smoother}
    errs = {m: errors(res.query, estimates[m], plan.gt) for m in METHODS}
    return DirectionRun(plan, tour, index, ref_feats, res, errs, build_s)


def per_frame(res: Replay) -> dict[str, Any]:
    """The per query frame estimates of a replay, as the JSON stores them."""
    return {
        "query": res.query,
        "ir_only": res.ir_only,
        "tracker": res.tracker,
        "smoother": res.smoother,
        "localised": [f is not None for f in res.localised_frames],
        "localised_span": [None if f is None else [min(f), max(f)] for f in res.localised_frames],
        "changed": [round(x, 4) for x in res.changed],
        "light_change": [round(x, 4) for x in res.light_change],
    }


def direction_summary(
    d: DirectionRun, *, tolerance: int, weights: str, halves: bool
) -> dict[str, Any]:
    """One entry of the JSON's ``directions``: recall at :func:`report_tolerances`, convergence
    and wrong localised runs at ``tolerance``, the weights used, the frames; with ``halves``
    also :func:`halves_scores` (for a run over the whole traversal)."""
    from server.vision.features import signature_blocks

    tols = report_tolerances(tolerance)
    conv = converged_after(d.errors["tracker"] <= tolerance)
    res, plan = d.replay, d.plan
    out: dict[str, Any] = {
        "reference": str(plan.reference),
        "query": str(plan.query),
        "gt": plan.gt_spec,
        "tolerance": tolerance,
        "frames": len(plan.qry_frames),
        "query_span": [plan.qry_frames[0], plan.qry_frames[-1]],
        "scored_frames": int(np.isfinite(d.errors["tracker"]).sum()),
        "reference_frames": len(plan.ref_frames),
        "reference_span": [plan.ref_frames[0], plan.ref_frames[-1]],
        "tour": {
            "locations": d.tour.graph.n_locations,
            "edges": d.tour.graph.n_edges,
            "images": d.tour.graph.n_images,
        },
        "recall_at": recall_at(d.errors, tols),
        "converged_after": conv["first_run"],
        "stays_right_after": conv["stays_right"],
        "max_wrong_localised_run": max_wrong_localised_run(
            res.query, res.localised_frames, plan.gt, tolerance
        ),
        "localised_fraction": float(np.mean([f is not None for f in res.localised_frames])),
        **ambiguity_figures(res.query, res.localised_frames, plan.gt, tolerance, FRAME_DT),
        "weights": weights,
        "weights_used": [round(float(x), 4) for x in d.index.weights],
        "weight_blocks": [b for b, _ in signature_blocks(d.index.params.features)],
        "appearance_models": [[round(float(x), 4) for x in w] for w in d.index.model_weights()],
        "changed_model_mean": float(np.mean(res.changed)) if res.changed else 0.0,
        "build_s": d.build_s,
        "per_frame": per_frame(res),
    }
    if halves:
        out["halves"] = halves_scores(d.errors, tols)
    return out


def plan_directions(
    args: argparse.Namespace, gt: GroundTruth, ref_frames: list[int], qry_frames: list[int]
) -> list[DirectionPlan]:
    """The forward run and, with ``--both-directions``, the reverse one (the traversals
    swapped, the ground truth inverted), each restricted to ``--half``; ``ValueError`` if a
    run would have too few frames."""
    qry, ref = select_half(qry_frames, ref_frames, gt, args.half)
    plans = [DirectionPlan("forward", args.reference, args.query, gt, args.gt, ref, qry)]
    if args.both_directions:
        inv = gt.inverted()
        qry, ref = select_half(ref_frames, qry_frames, inv, args.half)
        spec = args.gt if gt.matches is None else f"{args.gt} (inverted)"
        plans.append(DirectionPlan("reverse", args.query, args.reference, inv, spec, ref, qry))
    for plan in plans:
        if len(plan.ref_frames) < 2 or not plan.qry_frames:
            raise ValueError(f"not enough frames for the {plan.name} run")
    return plans


def run(args: argparse.Namespace) -> int:
    """Run the benchmark described in the module doc; 0 on success, 2 on bad input."""
    from server.belief.appearance import AppearanceParams
    from server.belief.model import TransitionParams
    from server.belief.tracker import TrackerParams
    from server.vision.features import FeatureParams
    from server.vision.index import CHANGED_WEIGHTS, EngineParams

    pin_threads()
    for folder in (args.reference, args.query):
        if not folder.is_dir():
            print(f"no frames at {folder}")
            return 2
    gt = GroundTruth.parse(args.gt)
    lo = max(0, int(args.skip_first))
    hi_r, hi_q = len(list_frames(args.reference)), len(list_frames(args.query))
    if args.limit is not None:
        hi_r, hi_q = min(hi_r, lo + args.limit), min(hi_q, lo + args.limit)
    if hi_r - lo < 2 or hi_q <= lo:
        print("not enough frames")
        return 2
    try:
        weights = parse_weights(args.weights)
        plans = plan_directions(args, gt, list(range(lo, hi_r)), list(range(lo, hi_q)))
    except ValueError as exc:
        print(exc)
        return 2
    learn = args.weights == "learned"
    params = EngineParams(weights=weights, features=FeatureParams(descriptor=args.descriptor))
    if args.appearance == "models":
        params = dataclasses.replace(params, changed_weights=CHANGED_WEIGHTS)
    transitions = bench_transitions() if args.transitions == "bench" else TransitionParams()
    try:
        changed_power = _changed_power(args.changed_likelihood_power)
    except ValueError as exc:
        print(exc)
        return 2
    tracker_params = TrackerParams(
        smoother_lag=args.lag,
        likelihood_power=args.likelihood_power,
        changed_likelihood_power=changed_power,
        appearance=AppearanceParams(change_gate=not args.no_change_gate),
    )
    settings = RunSettings(
        args.location_every,
        params,
        learn,
        transitions,
        tracker_params,
        args.action,
        _learn_params(args.learn_changed),
    )
    tol = int(args.tolerance)
    print(f"tolerance {tol}, half {args.half}")
    runs = [run_direction(plan, settings) for plan in plans]
    summaries = {
        d.plan.name: direction_summary(
            d, tolerance=tol, weights=args.weights, halves=args.half == "all"
        )
        for d in runs
    }
    fwd, f = runs[0], summaries["forward"]
    res = fwd.replay
    result: dict[str, Any] = {
        "reference": str(args.reference),
        "query": str(args.query),
        "gt": args.gt,
        "tolerance": tol,
        "half": args.half,
        "both_directions": bool(args.both_directions),
        "frames": len(fwd.plan.qry_frames),
        "first_frame": fwd.plan.qry_frames[0],
        "reference_frames": len(fwd.plan.ref_frames),
        "location_every": args.location_every,
        "tour": f["tour"],
        "transitions": args.transitions,
        "weights": args.weights,
        "weights_used": f["weights_used"],
        "appearance_models": f["appearance_models"],
        "changed_model_mean": f["changed_model_mean"],
        "weight_blocks": f["weight_blocks"],
        "descriptor": args.descriptor,
        "action": args.action,
        "smoother_lag": args.lag,
        "smoother_estimate": "oldest frame of the window (lag - 1 frames late)",
        "likelihood_power": tracker_params.likelihood_power,
        "changed_likelihood_power": tracker_params.changed_likelihood_power,
        "build_s": fwd.build_s,
    }
    for name, e in fwd.errors.items():
        result[name] = score(e, tol)
    result["recall_at"] = f["recall_at"]
    if "halves" in f:
        result["halves"] = f["halves"]
    for key in ("converged_after", "stays_right_after", "max_wrong_localised_run"):
        result[key] = f[key]
    for key in ("first_right_localised_s", "wrong_claims"):
        if key in f:
            result[key] = f[key]
    result["localised_fraction"] = f["localised_fraction"]
    result["recall_curve"] = {
        "tolerance": list(CURVE_TOLERANCES),
        **{
            name: [s["recall@1"] for s in score_at(e, CURVE_TOLERANCES).values()]
            for name, e in fwd.errors.items()
        },
    }
    step = stats(res.step_ms[5:])
    result["step_ms_p50"] = step["p50"]
    result["step_ms"] = step
    result["smoother_ms"] = stats(res.smooth_ms[5:])
    result["engine_ms"] = stats(res.engine_ms)
    result["extract_ms"] = stats(res.extract_ms)
    if not args.no_table1:
        t1 = table1(fwd.ref_feats, args.location_every, params, learn=learn)
        result["table1_error_rate"] = t1["error_rate"]
        result["table1"] = t1
    if args.size_10k > 0:
        big = step_time_synthetic(
            args.size_10k, transitions, tracker_params, action_mode=args.action
        )
        result["step_ms_p50_10k"] = big["step_ms"]["p50"]
        result["step_10k"] = big
    result["per_frame"] = f["per_frame"]
    result["directions"] = summaries
    _print(result)
    name = f"{args.query.name} -> {args.reference.name}"  # query -> reference
    if args.plot is not None:
        plot_belief(
            res, fwd.plan.gt, f"{name}: belief over time ({len(res.query)} frames)", args.plot
        )
        print(f"saved {args.plot}")
    if args.recall_plot is not None:
        curves = {k: v for k, v in result["recall_curve"].items() if k != "tolerance"}
        plot_recall(curves, f"{name}: recall@1 vs tolerance", args.recall_plot)
        print(f"saved {args.recall_plot}")
    write_json(args.json, result)
    return 0


def _print(r: dict[str, Any]) -> None:
    for name, d in r["directions"].items():
        blocks = ", ".join(
            f"{b} {w:.2f}" for b, w in zip(d["weight_blocks"], d["weights_used"], strict=True)
        )
        print(
            f"{name}: {Path(d['query']).name} -> {Path(d['reference']).name}, "
            f"{d['frames']} query frames ({d['scored_frames']} with a truth), "
            f"{d['reference_frames']} reference frames; weights {d['weights']} ({blocks})"
        )
        _print_recall(d["recall_at"], "  ")
        for half, h in d.get("halves", {}).items():
            at = h["recall_at"]
            cells = ", ".join(
                f"{m} " + "/".join(f"{at[t][m]['recall@1']:.3f}" for t in at) for m in METHODS
            )
            print(f"  {half} half ({h['frames']} frames), recall@1 at {'/'.join(at)}: {cells}")
        print(
            f"  converged after {d['converged_after']} frames (stays right after "
            f"{d['stays_right_after']}), max wrong localised run "
            f"{d['max_wrong_localised_run']} (tolerance {d['tolerance']})"
        )
        first = d["first_right_localised_s"]
        line = (
            f"  first right 'localised' after {'-' if first is None else f'{first:.1f} s'}, "
            f"wrong claims {d['wrong_claims']}"
        )
        print(line)
    print(
        f"belief + policy step p50 {r['step_ms_p50']:.3f} ms, engine p50 "
        f"{r['engine_ms']['p50']:.2f} ms/frame (forward)"
    )
    if "table1_error_rate" in r:
        print(f"Table 1 protocol error rate {r['table1_error_rate']:.3f}")
    if "step_ms_p50_10k" in r:
        print(
            f"belief + policy step p50 at {r['step_10k']['images']} images: "
            f"{r['step_ms_p50_10k']:.3f} ms"
        )


def _print_recall(at: dict[str, dict[str, dict[str, float]]], indent: str) -> None:
    """Recall@1 (mean error in frames) per tolerance and method."""
    print(indent + "tol  " + "".join(f"{m:>20s}" for m in METHODS) + "   recall@1 (mean error)")
    for tol, scores in at.items():
        cells = "".join(
            f"{scores[m]['recall@1']:>10.3f} ({scores[m]['mean_error_frames']:7.2f})"
            for m in METHODS
        )
        print(f"{indent}{tol:>3s}  {cells}")


__all__ = [
    "DirectionPlan",
    "DirectionRun",
    "GroundTruth",
    "Replay",
    "RunSettings",
    "Tour",
    "add_arguments",
    "bench_transitions",
    "build_tour",
    "half_frames",
    "invert_matches",
    "plan_directions",
    "recall_at",
    "replay",
    "run",
    "run_direction",
    "score_at",
    "select_half",
    "table1",
]


def _changed_power(value: str) -> float | None:
    """``--changed-likelihood-power``: navigation's own, none, or a positive number."""
    from server.belief.tracker import TrackerParams

    if value == "navigation":
        return TrackerParams().changed_likelihood_power
    if value == "none":
        return None
    try:
        power = float(value)
    except ValueError:
        power = math.nan
    if not (math.isfinite(power) and power > 0):
        raise ValueError(
            f"--changed-likelihood-power must be a positive number, 'navigation' or 'none', "
            f"got {value!r}"
        )
    return power


def _learn_params(changed_images: int) -> LearnParams:
    """Learning as the server does, with ``changed_images`` changed-light views."""
    from server.vision.learning import LearnParams

    return LearnParams(changed_images=changed_images)
