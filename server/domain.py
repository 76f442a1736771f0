"""The tour graph as the pure core sees it: locations, edges and the canonical image order.

This module imports NumPy only. Storage builds a :class:`TourGraph` from the database; the
similarity engine, the belief tracker and the policy consume it and never touch storage.

Conventions used everywhere in the core
---------------------------------------
* **Upper states** (``n_states = n_locations + n_edges``): location ``k`` is state ``k``,
  edge ``j`` is state ``n_locations + j``.
* **Fine states** (``n_fine = n_locations + sum(len(edge.images))``): one per location, then
  one per image of each edge in order. Fine state of edge ``j``'s ``k``-th image is
  ``n_locations + edge_offsets[j] + k``.
* **Canonical image order** (``n_images``): every location's spin images (locations in
  order), then every edge's images (edges in order). The engine index is built in this order;
  ``image_ids``, ``image_state`` and ``image_fine`` are aligned with it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import numpy.typing as npt

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Location:
    """A named place. ``image_ids`` are the storage ids of its spin images, in order."""

    name: str
    image_ids: tuple[int, ...] = ()
    id: int = -1  # storage id, -1 when the graph was built by hand


@dataclass(frozen=True)
class Edge:
    """A taught path between two locations (indices into ``TourGraph.locations``).

    ``timestamps`` (s), ``v`` (m/s) and ``w`` (rad/s) are aligned with ``image_ids``:
    the capture time of each image and the motion command being executed when it was taken.
    """

    source: int
    target: int
    image_ids: tuple[int, ...]
    timestamps: FloatArray
    v: FloatArray
    w: FloatArray
    id: int = -1  # storage id, -1 when the graph was built by hand

    @property
    def n_images(self) -> int:
        return len(self.image_ids)

    @property
    def duration(self) -> float:
        """Traversal time in seconds: last timestamp minus first."""
        if len(self.timestamps) < 2:
            return 0.0
        return float(self.timestamps[-1] - self.timestamps[0])

    def metres_along(self) -> FloatArray:
        """``(n_images,)`` metres the taught robot had driven along the edge at each image: its
        speeds ``|v|`` integrated over the timestamps (a step with a missing or backward
        timestamp adds nothing)."""
        if self.n_images == 0:
            return np.zeros(0)
        dt = np.diff(np.asarray(self.timestamps, dtype=np.float64))
        steps = np.abs(np.asarray(self.v, dtype=np.float64)[:-1]) * np.clip(dt, 0.0, None)
        return np.concatenate([[0.0], np.cumsum(np.where(np.isfinite(steps), steps, 0.0))])


@dataclass(frozen=True)
class TourGraph:
    """An immutable snapshot of one tour's graph, with the index maps the core needs."""

    locations: tuple[Location, ...]
    edges: tuple[Edge, ...] = field(default=())

    @property
    def n_locations(self) -> int:
        return len(self.locations)

    @property
    def n_edges(self) -> int:
        return len(self.edges)

    @property
    def n_states(self) -> int:
        """Number of upper states: locations then edges."""
        return self.n_locations + self.n_edges

    @cached_property
    def edge_offsets(self) -> IntArray:
        """``(n_edges + 1,)`` int: start of each edge's images among the edge fine states."""
        lengths = np.array([e.n_images for e in self.edges], dtype=np.int64)
        return np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)

    @property
    def n_fine(self) -> int:
        """Number of fine states: one per location plus one per edge image."""
        return self.n_locations + int(self.edge_offsets[-1])

    @cached_property
    def fine_state(self) -> IntArray:
        """``(n_fine,)`` int: the upper state of every fine state."""
        parts = [np.arange(self.n_locations, dtype=np.int64)]
        for j, e in enumerate(self.edges):
            parts.append(np.full(e.n_images, self.n_locations + j, dtype=np.int64))
        return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)

    @cached_property
    def image_ids(self) -> IntArray:
        """``(n_images,)`` int: storage id of every image in canonical order."""
        ids: list[int] = []
        for loc in self.locations:
            ids.extend(loc.image_ids)
        for e in self.edges:
            ids.extend(e.image_ids)
        return np.asarray(ids, dtype=np.int64)

    @property
    def n_images(self) -> int:
        return len(self.image_ids)

    @cached_property
    def image_state(self) -> IntArray:
        """``(n_images,)`` int: upper state of every image in canonical order."""
        parts = [
            np.full(len(loc.image_ids), k, dtype=np.int64) for k, loc in enumerate(self.locations)
        ]
        parts += [
            np.full(e.n_images, self.n_locations + j, dtype=np.int64)
            for j, e in enumerate(self.edges)
        ]
        return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)

    @cached_property
    def image_fine(self) -> IntArray:
        """``(n_images,)`` int: fine state of every image in canonical order."""
        parts = [
            np.full(len(loc.image_ids), k, dtype=np.int64) for k, loc in enumerate(self.locations)
        ]
        parts.append(self.n_locations + np.arange(int(self.edge_offsets[-1]), dtype=np.int64))
        return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)

    def location_index(self, name: str) -> int:
        """Index of the location called ``name``; ``KeyError`` when there is none."""
        for k, loc in enumerate(self.locations):
            if loc.name == name:
                return k
        raise KeyError(name)

    def state_name(self, state: int) -> str:
        """Human-readable name of an upper state: ``"kitchen"`` or ``"kitchen -> office"``."""
        if state < self.n_locations:
            return self.locations[state].name
        e = self.edges[state - self.n_locations]
        return f"{self.locations[e.source].name} -> {self.locations[e.target].name}"
