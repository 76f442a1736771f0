"""Junctions from shared path prefixes (issue 25 part 2; docs/learning.md, "Junctions").

``POST /tours/{tour}/junctions`` searches the tour's graph (as its runtime has it: refined by
the junctions applied before) for edges that leave one place along the same images and then
part (:func:`server.belief.junctions.find_junctions`), with the engine's error between the
taught images (:class:`EngineErrors`: the two passes' error the tracker's similarity is
normalised from, with the tour's weights; the mean of both directions). Each junction
found is stored as a learned change of kind 'junction' (migration 7); the taught edges stay
untouched in the database, and the tour's runtime applies the stored junctions when it is built
(:meth:`NavigationService._build`), so deleting the change gives back the earlier graph, index
and behaviour exactly.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from server import schemas
from server.belief.junctions import Junction, JunctionParams, find_junctions, refine
from server.domain import TourGraph
from server.navigation import TourRuntime
from server.services.learning import change_public
from server.services.navigation import NavigationService
from server.storage.repo import Repo

FloatArray = npt.NDArray[np.float64]


class EngineErrors:
    """The engine's error between two sequences of a tour's images (by storage id):
    ``feature_weight * e_features + signature_weight * d``, the second pass's error of 001's
    eq. 4 before it is normalised over a query's candidates (:class:`TourIndex`), with the
    tour's signature weights; symmetric in its two images (the mean of both directions)."""

    def __init__(self, rt: TourRuntime) -> None:
        self.rt = rt
        self.canonical = {int(i): k for k, i in enumerate(rt.graph.image_ids)}
        self.pairs = 0  # image pairs the engine scored (each once: the search asks again)
        self._known: dict[int, dict[int, float]] = {}  # query image -> image -> error

    def one_way(self, ids_a: npt.NDArray[np.int64], ids_b: npt.NDArray[np.int64]) -> FloatArray:
        """``(len(ids_a), len(ids_b))`` error of each image of ``a`` as the query."""
        index, p = self.rt.index, self.rt.index.params
        out = np.empty((len(ids_a), len(ids_b)))
        for r, image_id in enumerate(ids_a):
            known = self._known.setdefault(int(image_id), {})
            missing = [int(i) for i in ids_b if int(i) not in known]
            if missing:
                q = self.rt.features[self.canonical[int(image_id)]]
                cb = np.array([self.canonical[i] for i in missing], dtype=np.int64)
                d = index.signature_distances(q)[cb].astype(np.float64)
                e = p.feature_weight * index.feature_errors(q, cb) + p.signature_weight * d
                known.update(zip(missing, e.tolist(), strict=True))
                self.pairs += len(missing)
            out[r] = [known[int(i)] for i in ids_b]
        return out

    def __call__(self, ids_a: npt.NDArray[np.int64], ids_b: npt.NDArray[np.int64]) -> FloatArray:
        out: FloatArray = 0.5 * (self.one_way(ids_a, ids_b) + self.one_way(ids_b, ids_a).T)
        return out


def junction_public(
    graph: TourGraph, junction: Junction, change: int | None
) -> schemas.JunctionPublic:
    """``junction`` as found on ``graph`` (before it is applied)."""
    by_first = {e.image_ids[0]: e for e in graph.edges if e.n_images}
    a, b = by_first[junction.keep_first], by_first[junction.other_first]
    names = [loc.name for loc in graph.locations]
    return schemas.JunctionPublic(
        source=names[a.source],
        kept_edge=a.id,
        other_edge=b.id,
        kept_target=names[a.target],
        other_target=names[b.target],
        kept_shared=junction.keep_shared,
        other_shared=junction.other_shared,
        change=change,
    )


def junction_dependents(repo: Repo, tour_id: int, change_id: int) -> list[int]:
    """The junction changes of the tour that no longer apply without ``change_id`` (their
    edges are the parts it made); empty when ``change_id`` is not a junction."""
    stored = repo.junctions(tour_id)
    if change_id not in {c for c, _ in stored}:
        return []
    taught = repo.graph(tour_id)
    with_it = refine(taught, [j for _, j in stored]).applied
    rest = [(c, j) for c, j in stored if c != change_id]
    without = refine(taught, [j for _, j in rest]).applied
    was = {c: ok for (c, _), ok in zip(stored, with_it, strict=True)}
    return [c for (c, _), ok in zip(rest, without, strict=True) if was[c] and not ok]


class JunctionService:
    """Finds and applies junctions of a household's tours."""

    def __init__(
        self,
        repo: Repo,
        navigation: NavigationService,
        params: JunctionParams,
        *,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.repo = repo
        self.navigation = navigation
        self.params = params
        self.clock = clock

    def search(
        self, tour_id: int, body: schemas.JunctionSearch, household: int
    ) -> schemas.JunctionResult:
        """Find the tour's junctions; unless ``body.dry_run``, store each as a learned change
        and rebuild the tour's runtime. 404: not the household's tour; 409: no places yet."""
        self.repo.tour(tour_id, household)
        rt = self.navigation.runtime(tour_id)
        graph = rt.graph
        found = find_junctions(graph, EngineErrors(rt), self.params)
        if body.dry_run or not found:
            return schemas.JunctionResult(
                dry_run=body.dry_run,
                junctions=[junction_public(graph, j, None) for j in found],
                changes=[],
            )
        now = self.clock()
        source = f"junction search of the taught paths at {_iso(now)}"
        made: list[tuple[int, schemas.JunctionPublic]] = []
        current = graph
        with self.repo.transaction():
            for junction in found:
                public = junction_public(current, junction, None)
                summary = (
                    f"{public.source} -> {public.kept_target} and {public.source} -> "
                    f"{public.other_target} share their first {public.kept_shared} / "
                    f"{public.other_shared} images: one edge to a junction"
                )
                change = self.repo.add_junction_change(
                    tour_id, junction, source=source, summary=summary, now=now
                )
                made.append((change, public.model_copy(update={"change": change})))
                current = refine(current, [junction], first_name=_n_junctions(current) + 1).graph
        self.navigation.tour_changed(tour_id)
        rows = {r.id: r for r in self.repo.learned_changes(tour_id)}
        return schemas.JunctionResult(
            dry_run=False,
            junctions=[p for _, p in made],
            changes=[change_public(rows[c]) for c, _ in made if c in rows],
        )


def _n_junctions(graph: TourGraph) -> int:
    return sum(1 for loc in graph.locations if loc.junction)


def _iso(t: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t))
