"""Junctions from shared path prefixes (001 section 10.3): refine the taught graph.

001 proposes it as future work: "If two edges start at the same location, we can trace the
similarity of the images, starting from the first image. If the two paths have similar prefixes,
we can decide to unify these prefixes, causing a new location to be added to the graph where the
two paths becomes distinct. We can apply this procedure iteratively until no new locations are
found." Two edges that leave the same place along the same images for a while and then part ways
(kitchen -> office and kitchen -> bathroom both go down the hall first) are taught as two
unrelated edges: while the robot drives the hall, the belief is split between them and the
policy's votes for either goal disagree about which edge the robot is on. The refinement makes
the shared part one edge to a new **junction** (an unnamed location whose one image is the last
shared view) and the two remainders edges from the junction to the original targets; the belief,
the policy and the engine then run on the refined graph unchanged.

**Finding** (:func:`find_junctions`). For every pair of edges ``a``, ``b`` leaving one location
(to different targets) the caller gives the ``(n_a, n_b)`` matrix of the engine's error between
their images (:mod:`server.services.junctions`; lower is more alike). :func:`shared_prefix`
aligns ``b``'s images with ``a``'s from the first ones on (both first images must match: paths
that differ from the first image share nothing), with a bounded speed ratio, and follows the
alignment as long as its images match (``error <= max_error``, a few misses in a row
tolerated); the alignment with the least summed error is taken, which on a self-similar
corridor still follows the true correspondence (measured on the corridor data: within the
ground truth's +-2 images). A pair becomes a junction when both shares are at least
``min_shared`` images and both remainders at least ``min_remainder`` (the paths really part).
Per location, the pair with the longest share is refined first; the search then runs again on
the refined graph, so three edges down one corridor that part at two places give two junctions
in a row.

**Applying** (:func:`refine`). A :class:`Junction` names its edges by their first image's
storage id (image ids never change; edge indices do), so a stored junction applies to the graph
it was found on, in order after the junctions found before it. Edge ``a`` becomes ``source ->
J`` (its shared images but the last) and ``J -> a.target`` (the rest), and the junction place
gets ``a``'s last shared image as its one image (a place without images would never hold the
belief: the tracker would pass from the shared edge straight onto whichever remainder looks most
like the corridor ahead, and the policy would never be asked at the junction; measured in the
simulated apartment, where the robot then drove on to the wrong target). Edge ``b`` becomes ``J
-> b.target`` (its rest), and its shared images are **mapped**: each stands for the image of
``a``'s prefix it was aligned with (the caller adds it to the engine as another appearance of
that image, as it does with a repeat run's experiences). The junction is appended after the
places (place indices do not move); the edges keep their order, ``a`` replaced by its two parts
and ``b`` by its rest. A junction whose edges are not found (the tour changed) is skipped and
reported. Every taught image is in the refined graph exactly once or mapped onto one that is.

This module imports NumPy and :mod:`server.domain` only.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from server.domain import Edge, Location, TourGraph

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

#: The engine's error between two image sequences, by storage image id:
#: ``(ids_a, ids_b) -> (len(ids_a), len(ids_b))``, >= 0, lower = more alike.
PairError = Callable[[IntArray, IntArray], FloatArray]

__all__ = [
    "Junction",
    "JunctionParams",
    "PairError",
    "Refinement",
    "find_junctions",
    "junction_name",
    "refine",
    "shared_prefix",
]


@dataclass(frozen=True)
class JunctionParams:
    """When two edges' first images count as one shared path.

    * ``max_error`` (0.45, engine error units): two images match when the engine's error
      between them is at most this: ``feature_weight * e_features + signature_weight * d``,
      the quantity 001's eq. 4 normalises into the tracker's similarity, before that
      normalisation (which is relative to the other candidates of one query and cannot say
      whether two images show the same place). Chosen in the simulated apartment with the
      simulator's poses as ground truth (two taught paths, living room -> bathroom and
      living room -> office): images of one place (within 0.25 m and 20 degrees) score 0.34
      (median), 0.47 (95th percentile); of different places (over 0.75 m or 40 degrees apart)
      0.46 at the 0.5th percentile, 0.56 at the 5th. Evaluated on the other shipped homes
      (docs/learning.md, "Junctions"). Two traversals of the real corridor data differ more
      than that (0.56-0.66 at one place): there 0.665 separates the corridor from elsewhere,
      but not one place of the corridor from another.
    * ``min_shared`` (8 images), ``min_shared_m`` (1.0 m by the taught speeds): both edges
      must share at least this much; a shorter common start is only the place itself.
    * ``split_back_m`` (0.5 m by the taught speeds): the junction is put this far before the
      last shared image, so both remainders start with views a robot arriving at the junction
      has in front of it. At the last shared image itself the remainders' first views are
      already turned away: the robot stopped at the junction and spun to find its edge, and
      in the middle of a corridor a spin met views of other places (simulated apartment: it
      declared arrival 4.8 m from the goal).
    * ``min_remainder`` (3 images): both edges must go on for at least this many images after
      the split (else one path is the other one's prefix, not a fork).
    * ``max_step`` (2), ``max_stall`` (2): the alignment advances 0 to ``max_step`` images of
      the first edge per image of the second, at most ``max_stall`` zeros in a row (the two
      teaching runs' speeds may differ up to about 2-3 times).
    * ``max_skip`` (1 image): images in a row the second path may miss while the paths still
      count as shared (blur, a person passing).
    """

    max_error: float = 0.45
    min_shared: int = 8
    min_shared_m: float = 1.0
    split_back_m: float = 0.5
    min_remainder: int = 3
    max_step: int = 2
    max_stall: int = 2
    max_skip: int = 1

    def __post_init__(self) -> None:
        if not (math.isfinite(self.max_error) and self.max_error > 0.0):
            raise ValueError("max_error must be finite and > 0")
        if self.min_shared < 2 or self.min_remainder < 1 or self.max_skip < 0:
            raise ValueError("need min_shared >= 2, min_remainder >= 1, max_skip >= 0")
        if not all(math.isfinite(x) and x >= 0.0 for x in (self.min_shared_m, self.split_back_m)):
            raise ValueError("min_shared_m and split_back_m must be finite and >= 0")
        if 0.0 < self.min_shared_m <= self.split_back_m:
            # the remainders share split_back_m of views: searched again, they must not count
            raise ValueError("split_back_m must be less than min_shared_m")
        if self.max_step < 1 or self.max_stall < 0:
            raise ValueError("need max_step >= 1 and max_stall >= 0")


@dataclass(frozen=True)
class Junction:
    """One refinement step: edges that start with images ``keep_first`` (``a``) and
    ``other_first`` (``b``) share ``a``'s first ``keep_shared`` and ``b``'s first
    ``other_shared`` images. ``mapping`` ``(other_shared,)``: the index in ``a``'s prefix each of
    ``b``'s shared images stands for (non-decreasing)."""

    keep_first: int
    other_first: int
    keep_shared: int
    other_shared: int
    mapping: tuple[int, ...]

    def __post_init__(self) -> None:
        if len(self.mapping) != self.other_shared:
            raise ValueError("mapping needs one entry per shared image of the other edge")
        if any(not 0 <= m < self.keep_shared for m in self.mapping):
            raise ValueError("mapping entries must lie in [0, keep_shared)")

    def mapping_bytes(self) -> bytes:
        """``mapping`` as little-endian int32 (for storage)."""
        return np.asarray(self.mapping, dtype="<i4").tobytes()

    @staticmethod
    def mapping_from_bytes(blob: bytes) -> tuple[int, ...]:
        return tuple(int(x) for x in np.frombuffer(blob, dtype="<i4"))


@dataclass(frozen=True)
class Refinement:
    """The refined graph and what became of the taught images.

    * ``graph``: the refined graph (junctions appended after the places, see the module doc).
    * ``mapped``: taught image id -> the image id it now stands for (the other edge's shared
      images); every other taught image is in ``graph`` itself.
    * ``applied``: per junction given, whether it applied (False: its edges were not found).
    * ``junctions``: the place index of each applied junction in ``graph``, in order.
    """

    graph: TourGraph
    mapped: dict[int, int]
    applied: tuple[bool, ...]
    junctions: tuple[int, ...]


def junction_name(k: int) -> str:
    """The name junction ``k`` (1-based, in order of application) gets in the refined graph:
    parentheses, so it cannot be the name of a taught place one would send a robot to."""
    return f"(junction {k})"


def shared_prefix(
    error: npt.ArrayLike,
    max_error: float,
    *,
    max_step: int = 2,
    max_stall: int = 2,
    max_skip: int = 1,
) -> tuple[int, int, IntArray] | None:
    """The shared prefix of two image sequences and how they align (module doc).

    An alignment gives every image ``j`` of ``b`` an image ``i_j`` of ``a``: ``i_0 = 0``, then
    ``i_j - i_(j-1)`` in ``0..max_step`` (at most ``max_stall`` zeros in a row: ``b`` may have
    been taught up to ``max_stall + 1`` times slower, or ``max_step`` times faster). Image ``j``
    *matches* when ``error[i_j, j] <= max_error``; at most ``max_skip`` images in a row may
    miss. The shared prefix ends at the last matching image ``j*`` of the alignment that gets
    furthest along ``b``; among those, the one with the least summed error (a Viterbi pass
    over ``b``'s images; each contributes once, so no alignment is favoured for its length).

    Args:
        error: ``(n_a, n_b)`` engine error of image ``i`` of ``a`` against image ``j`` of ``b``
            (lower: more alike).
        max_error: the largest error that still matches.

    Returns:
        ``(i*, j*, mapping)``: the last shared image of each and ``(j* + 1,)`` int, the image of
        ``a`` each of ``b``'s first ``j* + 1`` images is aligned with; ``None`` when the first
        images do not match.
    """
    e = np.asarray(error, dtype=np.float64)
    if e.ndim != 2 or e.size == 0 or not e[0, 0] <= max_error:
        return None
    n_a, n_b = e.shape
    S, M = max_stall + 1, max_skip + 1
    inf = np.inf
    cost = np.full((S, M, n_a), inf)  # best summed error ending at image i, by stall / miss
    cost[0, 0, 0] = e[0, 0]
    # back[j][s, m, i] = (step, previous s, previous m), -1 where unreachable
    back: list[npt.NDArray[np.int64]] = [np.full((S, M, n_a, 3), -1, dtype=np.int64)]
    best_end = (0, 0, 0, 0)  # (j, s, i) of the furthest matching end, m = 0
    for j in range(1, n_b):
        miss = e[:, j] > max_error
        new = np.full((S, M, n_a), inf)
        ptr = np.full((S, M, n_a, 3), -1, dtype=np.int64)
        for s in range(S):
            for m in range(M):
                prev = cost[s, m]
                if not np.isfinite(prev).any():
                    continue
                for step in range(max_step + 1):
                    s2 = s + 1 if step == 0 else 0
                    if s2 >= S:
                        continue
                    src = np.full(n_a, inf)
                    src[step:] = prev[: n_a - step]
                    cand = src + e[:, j]
                    for m2, rows in ((0, ~miss), (m + 1, miss)):
                        if m2 >= M:
                            continue
                        better = rows & (cand < new[s2, m2])
                        new[s2, m2][better] = cand[better]
                        ptr[s2, m2][better] = (step, s, m)
        cost = new
        back.append(ptr)
        if not np.isfinite(cost).any():
            break
        ends = cost[:, 0]  # (S, n_a) ending on a match
        if np.isfinite(ends).any():
            s_end, i_end = np.unravel_index(int(np.argmin(ends)), ends.shape)
            best_end = (j, int(s_end), 0, int(i_end))
    j_end, s, m, i = best_end
    mapping = np.zeros(j_end + 1, dtype=np.int64)
    for j in range(j_end, 0, -1):
        mapping[j] = i
        step, s, m = (int(x) for x in back[j][s, m, i])
        i -= step
    mapping[0] = i  # 0: every alignment starts at both first images
    return int(mapping[j_end]), j_end, mapping


def _prefix_of(
    a: Edge, b: Edge, error: PairError, params: JunctionParams
) -> tuple[int, int, IntArray] | None:
    """:func:`shared_prefix` of two edges, asking ``error`` only for the images it can reach:
    the first ``n`` images of ``b`` (and the ``max_step * (n - 1) + 1`` of ``a`` an alignment
    can reach by then), ``n`` doubling while an alignment is still alive at image ``n - 1``.
    The answer is the one of the whole matrix (each image of ``b`` only depends on those
    before it)."""
    ids_a, ids_b = np.asarray(a.image_ids), np.asarray(b.image_ids)
    n = min(len(ids_b), 32)
    while True:
        rows = min(len(ids_a), params.max_step * (n - 1) + 1)
        err = np.asarray(error(ids_a[:rows], ids_b[:n]), np.float64)
        if err.shape != (rows, n):
            raise ValueError(f"error gave {err.shape}, expected ({rows}, {n})")
        found = shared_prefix(
            err,
            params.max_error,
            max_step=params.max_step,
            max_stall=params.max_stall,
            max_skip=params.max_skip,
        )
        alive = found is not None and found[1] >= n - 1 - params.max_skip
        if not alive or n == len(ids_b):
            return found
        n = min(len(ids_b), 2 * n)


def _candidates(
    graph: TourGraph, error: PairError, params: JunctionParams
) -> list[tuple[int, Junction]]:
    """Every pair of edges leaving one place that qualifies, as ``(share, junction)``."""
    out: list[tuple[int, Junction]] = []
    for s in range(graph.n_locations):
        leaving = [j for j, e in enumerate(graph.edges) if e.source == s and e.n_images > 0]
        for x, ja in enumerate(leaving):
            for jb in leaving[x + 1 :]:
                a, b = graph.edges[ja], graph.edges[jb]
                if a.target == b.target:
                    continue  # a re-taught path, not a fork
                found = _prefix_of(a, b, error, params)
                if found is None:
                    continue
                i, j, mapping = found
                ka, kb = i + 1, j + 1
                if min(ka, kb) < params.min_shared:
                    continue
                along = a.metres_along()
                metres = min(along[ka - 1], b.metres_along()[kb - 1])
                if metres < params.min_shared_m:
                    continue
                # the junction goes split_back_m before the paths part: its remainders start
                # with views the robot arriving there still has in front of it
                ka = max(
                    2, int(np.searchsorted(along, along[ka - 1] - params.split_back_m, "right"))
                )
                ka = min(ka, i + 1)
                kb = int(np.searchsorted(mapping, ka - 1, "right"))
                mapping = mapping[:kb]
                if min(a.n_images - ka, b.n_images - kb) < params.min_remainder:
                    continue
                junction = Junction(
                    a.image_ids[0], b.image_ids[0], ka, kb, tuple(int(m) for m in mapping)
                )
                out.append((ka + kb, junction))
    return out


def find_junctions(
    graph: TourGraph,
    error: PairError,
    params: JunctionParams | None = None,
    *,
    max_junctions: int = 64,
) -> list[Junction]:
    """The junctions of ``graph`` (module doc), in the order :func:`refine` applies them.

    Args:
        graph: the tour's graph (taught, or already refined by earlier junctions).
        error: the engine's error between two sequences of image ids (:data:`PairError`).
        params: thresholds (:class:`JunctionParams`).
        max_junctions: stop after this many (each adds a place and an edge).
    """
    p = params if params is not None else JunctionParams()
    found: list[Junction] = []
    current = graph
    while len(found) < max_junctions:
        cands = _candidates(current, error, p)
        if not cands:
            break
        # the longest share first; ties: the earlier pair (deterministic)
        best = max(range(len(cands)), key=lambda k: (cands[k][0], -k))
        junction = cands[best][1]
        step = refine(current, [junction], first_name=len(found) + 1 + _n_junctions(current))
        if not step.applied[0]:  # pragma: no cover - a candidate of this very graph applies
            break
        found.append(junction)
        current = step.graph
    return found


def _n_junctions(graph: TourGraph) -> int:
    return sum(1 for loc in graph.locations if loc.junction)


def _slice(edge: Edge, source: int, target: int, lo: int, hi: int) -> Edge:
    return Edge(
        source=source,
        target=target,
        image_ids=edge.image_ids[lo:hi],
        timestamps=np.asarray(edge.timestamps, np.float64)[lo:hi],
        v=np.asarray(edge.v, np.float64)[lo:hi],
        w=np.asarray(edge.w, np.float64)[lo:hi],
        id=edge.id,
    )


def refine(graph: TourGraph, junctions: Sequence[Junction], *, first_name: int = 1) -> Refinement:
    """``graph`` with ``junctions`` applied in order (module doc).

    The refined edges keep the storage id of the taught edge they are part of; junction places
    have id -1 and one image (the kept edge's last shared one) and are named
    :func:`junction_name` (``first_name``, then on).
    ``image_pose`` and ``image_entropy`` follow their images; a mapped image's rows leave with
    it. No junction: the very same ``graph`` object.
    """
    if not junctions:
        return Refinement(graph, {}, (), ())
    locations = list(graph.locations)
    edges = list(graph.edges)
    mapped: dict[int, int] = {}
    applied: list[bool] = []
    added: list[int] = []
    for junction in junctions:
        by_first = {e.image_ids[0]: k for k, e in enumerate(edges) if e.n_images}
        ka_idx = by_first.get(junction.keep_first)
        kb_idx = by_first.get(junction.other_first)
        if ka_idx is None or kb_idx is None or ka_idx == kb_idx:
            applied.append(False)
            continue
        a, b = edges[ka_idx], edges[kb_idx]
        if (
            a.source != b.source
            or not 2 <= junction.keep_shared < a.n_images
            or junction.other_shared >= b.n_images
        ):
            applied.append(False)
            continue
        j = len(locations)
        ka, kb = junction.keep_shared, junction.other_shared
        view = (a.image_ids[ka - 1],)  # the junction's one image: the last shared view
        locations.append(Location(junction_name(first_name + len(added)), view, -1, junction=True))
        for k in range(kb):
            mapped[int(b.image_ids[k])] = int(a.image_ids[junction.mapping[k]])
        new_edges: list[Edge] = []
        for k, e in enumerate(edges):
            if k == ka_idx:
                new_edges += [
                    _slice(e, e.source, j, 0, ka - 1),
                    _slice(e, j, e.target, ka, e.n_images),
                ]
            elif k == kb_idx:
                new_edges.append(_slice(e, j, e.target, kb, e.n_images))
            else:
                new_edges.append(e)
        edges = new_edges
        applied.append(True)
        added.append(j)
    if not added:
        return Refinement(graph, {}, tuple(applied), ())
    # a mapped image that an earlier junction's image was mapped onto: follow to the end
    for src in list(mapped):
        dst = mapped[src]
        while dst in mapped:
            dst = mapped[dst]
        mapped[src] = dst
    refined_ids = [i for loc in locations for i in loc.image_ids]
    refined_ids += [i for e in edges for i in e.image_ids]
    row = {int(i): k for k, i in enumerate(graph.image_ids)}
    take = np.asarray([row[int(i)] for i in refined_ids], dtype=np.int64)
    pose = None if graph.image_pose is None else np.asarray(graph.image_pose)[take]
    entropy = None if graph.image_entropy is None else np.asarray(graph.image_entropy)[take]
    out = TourGraph(tuple(locations), tuple(edges), image_pose=pose, image_entropy=entropy)
    return Refinement(out, mapped, tuple(applied), tuple(added))
