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
  ``image_ids``, ``image_state``, ``image_fine``, ``image_pose`` and ``image_entropy`` are
  aligned with it.
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
    """An immutable snapshot of one tour's graph, with the index maps the core needs.

    Two optional per-image arrays, in canonical image order, travel with it:

    * ``image_pose``: ``(n_images, 3) float64`` the pose each image was taught at (x, y in
      metres, heading in radians, in the teaching robot's odometry frame); a row of NaN where
      the robot sent none; ``None``: no image has one.
    * ``image_entropy``: ``(n_images,) float64`` the distinctiveness of every image, the
      entropy of its retrieval scores against the whole tour in nats (seed 000; low =
      distinctive, see :mod:`server.vision.distinctiveness`); NaN where not computed yet;
      ``None``: not computed.
    """

    locations: tuple[Location, ...]
    edges: tuple[Edge, ...] = field(default=())
    image_pose: FloatArray | None = None
    image_entropy: FloatArray | None = None

    def __post_init__(self) -> None:
        n = sum(len(loc.image_ids) for loc in self.locations) + sum(e.n_images for e in self.edges)
        if self.image_pose is not None and np.shape(self.image_pose) != (n, 3):
            raise ValueError(f"image_pose has shape {np.shape(self.image_pose)}, expected ({n}, 3)")
        if self.image_entropy is not None and np.shape(self.image_entropy) != (n,):
            raise ValueError(
                f"image_entropy has shape {np.shape(self.image_entropy)}, expected ({n},)"
            )

    @property
    def has_poses(self) -> bool:
        """Whether every image carries a taught pose (a metric map of the taught paths)."""
        return self.image_pose is not None and bool(np.all(np.isfinite(self.image_pose)))

    @property
    def has_entropy(self) -> bool:
        """Whether every image's distinctiveness is known."""
        return self.image_entropy is not None and bool(np.all(np.isfinite(self.image_entropy)))

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

    @cached_property
    def image_along(self) -> FloatArray:
        """``(n_images,)`` metres the taught robot had driven along its edge at each image
        (:meth:`Edge.metres_along`); 0 for a place's spin images."""
        parts = [np.zeros(self.n_images - int(self.edge_offsets[-1]))]
        parts += [e.metres_along() for e in self.edges]
        return np.concatenate(parts)

    @cached_property
    def image_ends(self) -> IntArray:
        """``(n_images, 2)`` int: the places at the start and the end of each image's edge
        (a spin image: its own place, twice)."""
        n_place = self.n_images - int(self.edge_offsets[-1])
        out = np.empty((self.n_images, 2), dtype=np.int64)
        out[:n_place] = self.image_state[:n_place, None]
        for j, e in enumerate(self.edges):
            lo = n_place + int(self.edge_offsets[j])
            out[lo : lo + e.n_images] = (e.source, e.target)
        return out

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
