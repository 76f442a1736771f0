"""Junctions from shared path prefixes (001 section 10.3): refine the taught graph.

001 names it as future work: "if two paths share a long common prefix, we could introduce a new
junction location where they split". Two edges that leave the same place along the same images
for a while and then part ways (kitchen -> office and kitchen -> bathroom both go down the
hall first) are taught as two unrelated edges: while the robot drives the hall, the belief is
split between them and the policy's votes for either goal disagree about which edge the robot
is on. The refinement makes the shared part one edge to a new **junction** (an unnamed location
without spin images) and the two remainders edges from the junction to the original targets;
the belief, the policy and the engine then run on the refined graph unchanged.

**Finding** (:func:`find_junctions`). For every pair of edges ``a``, ``b`` leaving one location
the caller gives the ``(n_a, n_b)`` image similarity matrix ``S`` (the engine's similarity,
the same scores the tracker uses; :mod:`server.services.junctions` computes it). A cell
*matches* when ``S[i, j] >= min_similarity``. The shared prefix is the longest monotone path of
matching cells from ``(0, 0)`` (both first images must match: paths that differ from the first
image share nothing), moving by steps ``(di, dj)`` with ``0 <= di, dj <= 1 + max_skip`` (not
both 0): either teaching run may have been slower, and up to ``max_skip`` images in a row may
be blurred or occluded. Its end ``(i*, j*)`` is the reachable cell with the largest ``i + j``
(ties: the smaller ``|i - j|``, then the smaller ``i``); ``a``'s first ``i* + 1`` and ``b``'s
first ``j* + 1`` images are shared. A pair becomes a junction when both shares are at least
``min_shared`` images and both remainders at least ``min_remainder`` (the paths really part).
Per location, the pair with the longest share (``i* + j*``) is refined first; the search then
runs again on the refined graph, so three edges down one corridor that part at two places give
two junctions in a row.

**Applying** (:func:`refine`). A :class:`Junction` names its edges by their first image's
storage id (image ids never change; edge indices do), so a stored junction applies to the graph
it was found on, in order after the junctions found before it. Edge ``a`` becomes
``source -> J`` (its shared images) and ``J -> a.target`` (the rest); edge ``b`` becomes
``J -> b.target`` (its rest), and its shared images are **mapped**: each stands for the image
of ``a``'s prefix it was aligned with (the caller adds it to the engine as another appearance
of that image, as it does with a repeat run's experiences). The junction is appended after the
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

#: The similarity of two image sequences: ``(ids_a, ids_b) -> (len(ids_a), len(ids_b))`` in
#: [0, 1], by storage image id.
PairSimilarity = Callable[[IntArray, IntArray], FloatArray]

__all__ = [
    "Junction",
    "JunctionParams",
    "PairSimilarity",
    "Refinement",
    "find_junctions",
    "junction_name",
    "refine",
    "shared_prefix",
]


@dataclass(frozen=True)
class JunctionParams:
    """When two edges' first images count as one shared path.

    * ``min_similarity`` (0.5): an image pair matches when the engine's similarity of the two
      (eq. 4 of 001, in [floor, 1], the best candidate of a query is 1; the mean of both
      directions, :mod:`server.services.junctions`) is at least this. Chosen on the simulated
      apartment's taught images (docs/learning.md, "Junctions"), the same for every home.
    * ``min_shared`` (8 images): both edges must share at least this many images (at the
      simulator's 2 images per metre about 4 m of corridor); a shorter common start is only
      the place itself.
    * ``min_remainder`` (3 images): both edges must go on for at least this many images after
      the split (else one path is the other one's prefix, not a fork).
    * ``max_skip`` (1 image): images in a row either path may skip while the paths still
      match (blur, a person passing).
    """

    min_similarity: float = 0.5
    min_shared: int = 8
    min_remainder: int = 3
    max_skip: int = 1

    def __post_init__(self) -> None:
        if not (math.isfinite(self.min_similarity) and 0.0 < self.min_similarity <= 1.0):
            raise ValueError("min_similarity must lie in (0, 1]")
        if self.min_shared < 1 or self.min_remainder < 1 or self.max_skip < 0:
            raise ValueError("need min_shared >= 1, min_remainder >= 1, max_skip >= 0")


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


def shared_prefix(match: npt.ArrayLike, max_skip: int = 1) -> tuple[int, int, IntArray] | None:
    """The longest shared prefix of two image sequences (module doc).

    Args:
        match: ``(n_a, n_b)`` bool, whether image ``i`` of ``a`` matches image ``j`` of ``b``.
        max_skip: images either sequence may skip per step.

    Returns:
        ``(i*, j*, mapping)``: the end cell and ``(j* + 1,)`` int, for each image of ``b`` up to
        ``j*`` the image of ``a`` it is aligned with (an image ``b`` skipped takes the aligned
        one before it); ``None`` when the first images do not match.
    """
    m = np.asarray(match, dtype=bool)
    if m.ndim != 2 or m.size == 0 or not m[0, 0]:
        return None
    n_a, n_b = m.shape
    reach = np.zeros((n_a, n_b), dtype=bool)
    prev = np.full((n_a, n_b, 2), -1, dtype=np.int64)
    reach[0, 0] = True
    step = 1 + max_skip
    # cells in order of i + j: every predecessor of a cell has a smaller i + j
    for s in range(1, n_a + n_b - 1):
        for i in range(max(0, s - n_b + 1), min(n_a, s + 1)):
            j = s - i
            if not m[i, j]:
                continue
            for di in range(0, step + 1):
                for dj in range(0, step + 1):
                    if di == dj == 0 or i - di < 0 or j - dj < 0:
                        continue
                    if reach[i - di, j - dj]:
                        reach[i, j] = True
                        prev[i, j] = (i - di, j - dj)
                        break
                if reach[i, j]:
                    break
    cells = np.argwhere(reach)
    key = np.lexsort((cells[:, 0], np.abs(cells[:, 0] - cells[:, 1]), -(cells[:, 0] + cells[:, 1])))
    i_end, j_end = (int(x) for x in cells[key[0]])
    aligned = np.full(j_end + 1, -1, dtype=np.int64)
    i, j = i_end, j_end
    while i >= 0:
        if aligned[j] < 0:
            aligned[j] = i
        i, j = (int(x) for x in prev[i, j])
    for jj in range(1, j_end + 1):  # an image of b the path skipped: the one before
        if aligned[jj] < 0:
            aligned[jj] = aligned[jj - 1]
    return i_end, j_end, aligned


def _candidates(
    graph: TourGraph, similarity: PairSimilarity, params: JunctionParams
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
                sim = np.asarray(
                    similarity(np.asarray(a.image_ids), np.asarray(b.image_ids)), np.float64
                )
                if sim.shape != (a.n_images, b.n_images):
                    raise ValueError(
                        f"similarity gave {sim.shape}, expected ({a.n_images}, {b.n_images})"
                    )
                found = shared_prefix(sim >= params.min_similarity, params.max_skip)
                if found is None:
                    continue
                i, j, mapping = found
                ka, kb = i + 1, j + 1
                if min(ka, kb) < params.min_shared:
                    continue
                if min(a.n_images - ka, b.n_images - kb) < params.min_remainder:
                    continue
                junction = Junction(
                    a.image_ids[0], b.image_ids[0], ka, kb, tuple(int(m) for m in mapping)
                )
                out.append((ka + kb, junction))
    return out


def find_junctions(
    graph: TourGraph,
    similarity: PairSimilarity,
    params: JunctionParams | None = None,
    *,
    max_junctions: int = 64,
) -> list[Junction]:
    """The junctions of ``graph`` (module doc), in the order :func:`refine` applies them.

    Args:
        graph: the tour's graph (taught, or already refined by earlier junctions).
        similarity: image similarity of two sequences of image ids (:data:`PairSimilarity`).
        params: thresholds (:class:`JunctionParams`).
        max_junctions: stop after this many (each adds a place and an edge).
    """
    p = params if params is not None else JunctionParams()
    found: list[Junction] = []
    current = graph
    while len(found) < max_junctions:
        cands = _candidates(current, similarity, p)
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
    have id -1 and no images and are named :func:`junction_name` (``first_name``, then on).
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
            or junction.keep_shared >= a.n_images
            or junction.other_shared >= b.n_images
        ):
            applied.append(False)
            continue
        j = len(locations)
        locations.append(Location(junction_name(first_name + len(added)), (), -1, junction=True))
        ka, kb = junction.keep_shared, junction.other_shared
        for k in range(kb):
            mapped[int(b.image_ids[k])] = int(a.image_ids[junction.mapping[k]])
        new_edges: list[Edge] = []
        for k, e in enumerate(edges):
            if k == ka_idx:
                new_edges += [_slice(e, e.source, j, 0, ka), _slice(e, j, e.target, ka, e.n_images)]
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
