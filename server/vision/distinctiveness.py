"""How distinctive every taught image is: the entropy of its retrieval scores (seed 000, eq. 1).

Mariottini & Roumeliotis query their visual memory with each training image and take the
entropy of the normalised score function as that image's distinctiveness: low when only the
image's own spot scores high, high when look-alikes elsewhere score as high as it does. Here:

1. Each *sampled* taught image is queried against the tour with the engine's two-pass query
   (:meth:`TourIndex.query`, the scores the belief tracker sees). Edge images are sampled every
   ``spacing_m`` metres along their edge (neighbouring frames a few centimetres apart look the
   same and have the same distinctiveness); every spin image is sampled.
2. The scores are pooled into bins: one bin for the image's own *spot* (every image taught
   within ``near_m`` of it along its own edge, and at a place it is within ``near_m`` of: the
   place's spin images and the ends of its edges), then one bin per upper state with the
   state's best score among its other images (eq. 2 of 001: a state is as similar as its best
   image). Without the spot bin the frames just before and after an image, which are the same
   view, would make every image look ambiguous.
3. ``p = bins ** sharpness / sum``; the entropy ``H = -sum p log p`` (nats) is the image's
   distinctiveness. ``sharpness`` (4) turns the engine's relative scores (the best candidate
   scores 1, the worst 0, eq. 4) into a distribution as peaked as the evidence of a few frames
   (the tracker multiplies about that many likelihoods before it trusts a place).
4. Images between two sampled ones on an edge take the linear interpolation of their
   entropies along the edge.

:func:`image_entropy` returns the ``(n_images,)`` entropies. Everything here works on per-image
arrays in the index's order (the caller derives them from its tour graph:
:meth:`server.navigation.TourRuntime.distinctiveness`).

This module imports NumPy and :mod:`server.vision` only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from server.vision.features import ImageFeatures
from server.vision.index import TourIndex

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

__all__ = [
    "DistinctivenessParams",
    "ImageLayout",
    "image_entropy",
    "interpolate",
    "retrieval_entropy",
    "sample_images",
    "spot_mask",
]


@dataclass(frozen=True)
class DistinctivenessParams:
    """How the distinctiveness of taught images is computed.

    * ``near_m`` (1.0 m): images taught within this distance of each other along an edge, or
      within it of the same place, are one spot (one bin of the score distribution).
    * ``sharpness`` (4.0): exponent turning scores into a distribution (``p ~ score **
      sharpness``); about the number of frames of evidence the tracker weighs before it
      trusts a place. 1 makes every image look ambiguous (the floor of thousands of weak
      scores dominates), 8 makes nearly every image look distinctive.
    * ``spacing_m`` (0.25 m): one edge image is queried per this many metres along its edge
      (the others are interpolated); every spin image is queried.
    """

    near_m: float = 1.0
    sharpness: float = 4.0
    spacing_m: float = 0.25

    def __post_init__(self) -> None:
        for name in ("near_m", "sharpness", "spacing_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"DistinctivenessParams.{name} must be finite and > 0")


@dataclass(frozen=True)
class ImageLayout:
    """Where the images of a tour are, per image in the index's order.

    * ``state``: ``(n,)`` upper state (places first; a state's images are contiguous).
    * ``along``: ``(n,)`` metres along its edge (0 for a place's spin images).
    * ``ends``: ``(n, 2)`` the places at the start and end of its edge (a spin image: its
      own place twice).
    * ``n_place_images``: the first ``n_place_images`` images are spin images.
    * ``n_states``: number of upper states.
    """

    state: IntArray
    along: FloatArray
    ends: IntArray
    n_place_images: int
    n_states: int

    @property
    def n_images(self) -> int:
        return len(self.state)

    def near_places(self, near_m: float) -> tuple[IntArray, IntArray]:
        """``(near_source, near_target)``, each ``(n,)``: the place an image is within
        ``near_m`` of at its edge's start and at its edge's end (-1: none); a spin image is at
        its own place both ways."""
        state = self.state
        length = np.zeros(self.n_images)
        if self.n_images:
            edge_img = np.arange(self.n_images) >= self.n_place_images
            runs = np.flatnonzero(np.concatenate([[True], state[1:] != state[:-1]]))
            run_max = np.maximum.reduceat(self.along, runs)
            length = run_max[np.searchsorted(runs, np.arange(self.n_images), side="right") - 1]
        else:
            edge_img = np.zeros(0, dtype=bool)
        near_src = np.where(~edge_img | (self.along <= near_m), self.ends[:, 0], -1)
        near_tgt = np.where(~edge_img | (self.along >= length - near_m), self.ends[:, 1], -1)
        return near_src.astype(np.int64), near_tgt.astype(np.int64)


def spot_mask(
    query: npt.ArrayLike,
    state: npt.ArrayLike,
    along: npt.ArrayLike,
    near_source: npt.ArrayLike,
    near_target: npt.ArrayLike,
    near_m: float,
) -> BoolArray:
    """``(m, n) bool``: which images are the same spot as each of the ``m`` ``query`` images.

    ``state``, ``along`` (m), ``near_source`` and ``near_target`` (place index or -1) are
    ``(n,)`` per image (:meth:`ImageLayout.near_places`). Two images are one spot when they
    are on the same state within ``near_m`` of each other along it, or both within ``near_m``
    of one place.
    """
    q = np.asarray(query, dtype=np.int64)
    st = np.asarray(state, dtype=np.int64)
    a = np.asarray(along, dtype=np.float64)
    ns = np.asarray(near_source, dtype=np.int64)
    nt = np.asarray(near_target, dtype=np.int64)
    same = (st[q][:, None] == st[None, :]) & (np.abs(a[q][:, None] - a[None, :]) <= near_m)
    for place in (ns[q], nt[q]):
        p = place[:, None]
        same |= (p >= 0) & ((p == ns[None, :]) | (p == nt[None, :]))
    return np.asarray(same, dtype=bool)


def retrieval_entropy(
    scores: npt.ArrayLike,
    same_spot: npt.ArrayLike,
    state_starts: npt.ArrayLike,
    *,
    sharpness: float = 4.0,
) -> FloatArray:
    """Entropy (nats) of the score distribution of each query.

    Args:
        scores: ``(m, n)`` the engine's similarity of every image (canonical order, >= 0) to
            each of ``m`` query images.
        same_spot: ``(m, n) bool`` the images of each query's own spot (:func:`spot_mask`).
        state_starts: ``(n_states_with_images,)`` first canonical index of each run of images
            of one state (canonical order keeps a state's images together).
        sharpness: exponent of the scores (see :class:`DistinctivenessParams`).

    Returns:
        ``(m,)`` entropies. The bins are the best score in the own spot, then per state the
        best score outside the spot; ``p = bin ** sharpness``, normalised. A query whose bins
        are all 0 has entropy 0.
    """
    s = np.asarray(scores, dtype=np.float64)
    spot = np.asarray(same_spot, dtype=bool)
    starts = np.asarray(state_starts, dtype=np.int64)
    if s.ndim != 2 or spot.shape != s.shape:
        raise ValueError(f"scores {s.shape} and same_spot {spot.shape} must be the same (m, n)")
    if not np.all(np.isfinite(s)) or np.any(s < 0):
        raise ValueError("scores must be finite and >= 0")
    own = np.where(spot, s, 0.0).max(axis=1, initial=0.0)
    far = np.maximum.reduceat(np.where(spot, 0.0, s), starts, axis=1) if s.shape[1] else s
    bins = np.concatenate([own[:, None], far], axis=1) ** float(sharpness)
    total = bins.sum(axis=1, keepdims=True)
    p = np.divide(bins, total, out=np.zeros_like(bins), where=total > 0)
    logp = np.log(p, out=np.zeros_like(p), where=p > 0)
    entropy: FloatArray = -(p * logp).sum(axis=1)
    return entropy


def sample_images(layout: ImageLayout, spacing_m: float) -> IntArray:
    """Indices of the images to query: every spin image, and on every edge its first and last
    image and one per ``spacing_m`` metres between (the first image at or past each multiple
    of ``spacing_m``)."""
    picks = [np.arange(layout.n_place_images, dtype=np.int64)]
    state = layout.state
    edge = state[layout.n_place_images :]
    if len(edge):  # one run per edge
        first = np.concatenate([[True], edge[1:] != edge[:-1]])
        starts = layout.n_place_images + np.flatnonzero(first)
        ends = np.concatenate([starts[1:], [layout.n_images]])
    else:  # places only (a tour of one place, or no path taught yet)
        starts = ends = np.zeros(0, np.int64)
    for lo, hi in zip(starts.tolist(), ends.tolist(), strict=True):  # one run per edge
        a = layout.along[lo:hi]
        marks = np.arange(0.0, a[-1] + spacing_m, spacing_m)
        k = np.searchsorted(a, marks - 1e-9)
        k = np.unique(np.concatenate([[0], np.clip(k, 0, hi - lo - 1), [hi - lo - 1]]))
        picks.append(lo + k.astype(np.int64))
    return np.concatenate(picks)


def interpolate(layout: ImageLayout, sampled: IntArray, values: FloatArray) -> FloatArray:
    """Values of every image from those of the sampled ones (edge images: linear in metres
    along the edge between the sampled images of that edge)."""
    n = layout.n_images
    along = layout.along
    out = np.empty(n)
    out[sampled] = values
    state = layout.state
    for s in np.unique(state):
        idx = np.flatnonzero(state == s)
        rows = np.flatnonzero(state[sampled] == s)
        if len(rows) == len(idx):
            continue
        pos = along[sampled[rows]]
        order = np.argsort(pos, kind="stable")
        pos, rows = pos[order], rows[order]
        out[idx] = np.interp(along[idx], pos, values[rows])
        out[sampled[rows]] = values[rows]
    return out


def image_entropy(
    index: TourIndex,
    features: Sequence[ImageFeatures],
    layout: ImageLayout,
    params: DistinctivenessParams | None = None,
) -> FloatArray:
    """The distinctiveness of every image of ``layout`` (see the module docstring): ``(n_images,)
    float64`` entropies in nats, canonical image order.

    ``index`` holds the tour's images in the layout's order (with its weights set) and
    ``features[i]`` are image ``i``'s features. One engine query per sampled image.
    """
    p = params if params is not None else DistinctivenessParams()
    n = layout.n_images
    if index.n_images != n or len(features) != n:
        raise ValueError(
            f"the index holds {index.n_images} images and {len(features)} features are given "
            f"for a tour of {n} images"
        )
    if n == 0:
        return np.zeros(0)
    near_src, near_tgt = layout.near_places(p.near_m)
    sampled = sample_images(layout, p.spacing_m)
    state = layout.state
    scores = np.stack(
        [index.query(features[int(i)], n_states=layout.n_states).image for i in sampled]
    )
    spot = spot_mask(sampled, state, layout.along, near_src, near_tgt, p.near_m)
    starts = np.flatnonzero(np.concatenate([[True], state[1:] != state[:-1]]))
    entropy = retrieval_entropy(scores, spot, starts, sharpness=p.sharpness)
    return interpolate(layout, sampled, entropy)
