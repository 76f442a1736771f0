"""What the dashboard shows of ambiguity (docs/ambiguity.md): the distinctiveness of the taught
images as colours along the edges, and the pose relative to the taught path the robot tracks.

Pure functions from the core's values to colours, points and markdown; the dashboard places
them (kept apart from it so that its layout can change without touching these)."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from server.domain import TourGraph
from server.navigation.pathtrack import PathEstimate

FloatArray = npt.NDArray[np.float64]
ColorArray = npt.NDArray[np.uint8]

DISTINCT = np.array([34, 139, 84], dtype=np.float64)
"""Colour of a distinctive image (entropy 0): green."""
AMBIGUOUS = np.array([214, 60, 48], dtype=np.float64)
"""Colour of an image as ambiguous as :data:`FULL_NATS` or more: red."""
FULL_NATS = math.log(3.0)
"""Entropy drawn fully red: three equal look-alikes."""


def entropy_colors(entropy: npt.ArrayLike) -> ColorArray:
    """``(n, 3) uint8``: green (distinctive) to red (look-alikes elsewhere) for ``(n,)``
    entropies in nats; grey where unknown (NaN)."""
    h = np.asarray(entropy, dtype=np.float64)
    t = np.clip(np.nan_to_num(h, nan=0.0) / FULL_NATS, 0.0, 1.0)[:, None]
    out = (1.0 - t) * DISTINCT + t * AMBIGUOUS
    out[np.isnan(h)] = 150.0
    return np.round(out).astype(np.uint8)


def edge_entropy(graph: TourGraph) -> tuple[FloatArray, ...]:
    """``(n_images_e,)`` entropies of every edge's images (NaN where unknown)."""
    n_loc_images = graph.n_images - int(graph.edge_offsets[-1])
    h = (
        np.full(graph.n_images, np.nan)
        if graph.image_entropy is None
        else np.asarray(graph.image_entropy, dtype=np.float64)
    )
    return tuple(
        h[n_loc_images + int(graph.edge_offsets[j]) : n_loc_images + int(graph.edge_offsets[j + 1])]
        for j in range(graph.n_edges)
    )


def edge_entropy_colors(graph: TourGraph) -> tuple[ColorArray, ...]:
    """``(n_images_e, 3)`` colours of every edge's images by their entropy."""
    return tuple(entropy_colors(h) for h in edge_entropy(graph))


def place_entropy(graph: TourGraph) -> FloatArray:
    """``(n_locations,)`` mean entropy of each place's spin images (NaN when unknown)."""
    out = np.full(graph.n_locations, np.nan)
    if graph.image_entropy is None:
        return out
    h = np.asarray(graph.image_entropy, dtype=np.float64)
    start = 0
    for k, loc in enumerate(graph.locations):
        n = len(loc.image_ids)
        if n:
            out[k] = float(np.mean(h[start : start + n]))
        start += n
    return out


def distinctiveness_text(graph: TourGraph | None) -> str:
    """One line saying how the edges are coloured and which places look most alike."""
    if graph is None or not graph.has_entropy:
        return "Distinctiveness: not computed yet (it is, shortly after teaching changes a tour)."
    places = place_entropy(graph)
    order = np.argsort(-np.nan_to_num(places, nan=-1.0))
    worst = ", ".join(
        f"{graph.locations[k].name} {places[k]:.2f}" for k in order[:2] if math.isfinite(places[k])
    )
    return (
        "Distinctiveness along the paths: green = only this spot looks like it, red = "
        f"look-alikes elsewhere (entropy, nats). Most ambiguous places: {worst}"
    )


def path_text(est: PathEstimate, graph: TourGraph) -> str:
    """Markdown line of the path tracker's estimate: which path, where along and beside it,
    how sure, and whether it steers by it."""
    name = graph.state_name(graph.n_locations + est.edge) if est.edge < graph.n_edges else "?"
    how = "locked: following it" if est.locked else "not sure enough to steer by"
    return (
        f"On the taught path {name}: {est.along_m:.2f} of {est.length_m:.2f} m along, "
        f"{est.lateral_m:+.2f} m to its side (sd {est.sigma_lateral:.2f} m), heading "
        f"{math.degrees(est.heading_error):+.0f} deg (sd {math.degrees(est.sigma_heading):.0f}); "
        f"{how}"
    )


def step_lines(graph: TourGraph, path: PathEstimate | None = None) -> str:
    """The markdown a navigating step adds: the pose relative to the taught path (while the
    path tracker tracks one); empty otherwise."""
    return "" if path is None else f"\n\n{path_text(path, graph)}"
