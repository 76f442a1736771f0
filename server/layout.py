"""The taught paths laid out in the plane: where every place and every taught image is drawn.

From the taught odometry when every path has it (the paths dead-reckoned as the path tracker
has them, :mod:`server.navigation.geometry`, chained from the first place), else a seeded
networkx layout with straight paths. Used by the dashboard's 3D scene and top-down map and by
the recordings' Foxglove scene; :func:`tracked_position` puts the path tracker's estimate on
the drawing. Pure: NumPy and networkx.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import networkx as nx
import numpy as np
import numpy.typing as npt

from server.domain import Edge, TourGraph
from server.navigation.geometry import dead_reckon

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class GraphLayout:
    """Where the graph is drawn (metres when ``odometry``; arbitrary units otherwise).

    * ``places``: ``(n_locations, 3)`` float32 position of every location.
    * ``edge_points``: per edge, ``(n_images_e, 3)`` float32 position of each of its images.
    * ``segments``: ``(n_segments, 2, 3)`` float32 line segments of all edges;
      ``segment_edge``: ``(n_segments,)`` the edge each segment belongs to.
    * ``extent``: size of the drawing (>= 1), to scale markers; ``center``: its middle.
    """

    places: npt.NDArray[np.float32]
    edge_points: tuple[npt.NDArray[np.float32], ...]
    segments: npt.NDArray[np.float32]
    segment_edge: npt.NDArray[np.int64]
    odometry: bool
    extent: float
    center: npt.NDArray[np.float32]


def has_odometry(edge: Edge) -> bool:
    """True when the edge recorded timestamps and a non-zero motion to integrate."""
    t = np.asarray(edge.timestamps, dtype=np.float64)
    if len(t) < 2 or not np.all(np.isfinite(t)) or t[-1] <= t[0]:
        return False
    v = np.asarray(edge.v, dtype=np.float64)
    return bool(np.sum(np.abs(v[:-1]) * np.diff(t)) > 1e-3)


def integrate_edge(edge: Edge) -> FloatArray:
    """``(n_images + 2, 3)`` poses ``(x, y, heading)`` along an edge in its start frame:
    the source place, every image, then the target place.

    The images dead-reckoned from the taught odometry as the path tracker has them
    (:func:`server.navigation.geometry.dead_reckon`); the places one median frame interval
    before the first image and after the last, at the speed taught there.
    """
    t = np.asarray(edge.timestamps, dtype=np.float64)
    n = len(t)
    if n == 0:
        return np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    dt0 = float(np.median(np.diff(t))) if n > 1 else 0.1
    images = dead_reckon(t, edge.v, edge.w)
    v = np.abs(np.asarray(edge.v, dtype=np.float64))
    step_in = float(v[1] if n > 1 else v[0]) * dt0
    step_out = float(v[-1]) * dt0
    first, last = images[0], images[-1]
    before = first - step_in * np.array([math.cos(first[2]), math.sin(first[2]), 0.0])
    after = last + step_out * np.array([math.cos(last[2]), math.sin(last[2]), 0.0])
    poses = np.vstack([before, images, after])
    poses[:, :2] -= before[:2]
    return poses


def _fit(raw: FloatArray, start: FloatArray, end: FloatArray) -> FloatArray:
    """Map a path ``raw`` (m, 2) whose first point is the origin onto ``start`` -> ``end`` by a
    rotation and scale (straight line when the raw path returns to where it began)."""
    d_raw = raw[-1] - raw[0]
    d_act = end - start
    n_raw = float(np.hypot(*d_raw))
    if n_raw < 1e-9:
        s = np.linspace(0.0, 1.0, len(raw))[:, None]
        return start + s * d_act
    angle = math.atan2(d_act[1], d_act[0]) - math.atan2(d_raw[1], d_raw[0])
    scale = float(np.hypot(*d_act)) / n_raw
    c, s_ = math.cos(angle), math.sin(angle)
    rot = np.array([[c, -s_], [s_, c]])
    return start + scale * (raw - raw[0]) @ rot.T


def _odometry_places(graph: TourGraph, raws: list[FloatArray]) -> FloatArray:
    """``(n_locations, 2)`` positions by chaining edges from location 0 (spanning tree);
    ``raws`` are the ``(n_images + 2, 3)`` poses of every edge in its start frame."""
    n = graph.n_locations
    pose: dict[int, tuple[float, float, float]] = {}
    gap = max(1.0, max((float(np.ptp(r[:, 0])) for r in raws), default=1.0))
    while len(pose) < n:
        if not pose or not _grow(graph, raws, pose):
            root = next(k for k in range(n) if k not in pose)
            x0 = max((p[0] for p in pose.values()), default=-gap) + gap
            pose[root] = (x0, 0.0, 0.0)
            continue
    return np.array([[pose[k][0], pose[k][1]] for k in range(n)], dtype=np.float64)


def _grow(
    graph: TourGraph, raws: list[FloatArray], pose: dict[int, tuple[float, float, float]]
) -> bool:
    """Place one more location through an edge that touches a placed one; False if none."""
    for j, e in enumerate(graph.edges):
        raw = raws[j]
        dx, dy, dth = raw[-1]
        if e.source in pose and e.target not in pose:
            x, y, th = pose[e.source]
            c, s = math.cos(th), math.sin(th)
            pose[e.target] = (x + c * dx - s * dy, y + s * dx + c * dy, th + dth)
            return True
        if e.target in pose and e.source not in pose:
            x, y, th = pose[e.target]
            th0 = th - dth
            c, s = math.cos(th0), math.sin(th0)
            pose[e.source] = (x - (c * dx - s * dy), y - (s * dx + c * dy), th0)
            return True
    return False


def _assemble(places2: FloatArray, paths: list[FloatArray], *, odometry: bool) -> GraphLayout:
    """The layout of places at ``(n_locations, 2)`` ``places2`` and one ``(n_images_e + 2, 2)``
    path per edge (its source place, its images, its target place)."""
    n_loc = len(places2)
    edge_points: list[npt.NDArray[np.float32]] = []
    segments: list[FloatArray] = []
    segment_edge: list[int] = []
    for j, path in enumerate(paths):
        path3 = np.concatenate([path, np.zeros((len(path), 1))], axis=1)
        edge_points.append(path3[1:-1].astype(np.float32))
        segments.append(np.stack([path3[:-1], path3[1:]], axis=1))
        segment_edge.extend([j] * (len(path3) - 1))
    places = np.concatenate([places2, np.zeros((n_loc, 1))], axis=1).astype(np.float32)
    all_xy = np.concatenate([places2, *[p[:, :2] for p in edge_points]], axis=0)
    extent, center = 1.0, np.zeros(3)
    if len(all_xy):
        extent = max(1.0, float(np.ptp(all_xy, axis=0).max()))
        center = np.append(0.5 * (all_xy.min(axis=0) + all_xy.max(axis=0)), 0.0)
    return GraphLayout(
        places=places,
        edge_points=tuple(edge_points),
        segments=(
            np.concatenate(segments, axis=0).astype(np.float32)
            if segments
            else np.zeros((0, 2, 3), dtype=np.float32)
        ),
        segment_edge=np.asarray(segment_edge, dtype=np.int64),
        odometry=odometry,
        extent=extent,
        center=center.astype(np.float32),
    )


def posed_layout(graph: TourGraph) -> GraphLayout:
    """The layout of a tour whose every image carries its taught pose (``graph.has_poses``):
    each image where it was taken, each place at the mean of its spin images (or of the ends of
    its edges, for a place without spin images), in the frame the poses were sent in."""
    assert graph.image_pose is not None
    xy = np.asarray(graph.image_pose, dtype=np.float64)[:, :2]
    n_loc = graph.n_locations
    state = graph.image_state
    places2 = np.zeros((n_loc, 2))
    for k in range(n_loc):
        mine = xy[state == k]
        if len(mine) == 0:  # the ends of its edges
            first = graph.n_images - int(graph.edge_offsets[-1]) + graph.edge_offsets
            ends = [
                xy[first[j + 1] - 1] if e.target == k else xy[first[j]]
                for j, e in enumerate(graph.edges)
                if k in (e.source, e.target) and e.n_images
            ]
            mine = np.asarray(ends) if ends else np.zeros((1, 2))
        places2[k] = mine.mean(axis=0)
    paths = [
        np.concatenate([places2[e.source][None], xy[state == n_loc + j], places2[e.target][None]])
        for j, e in enumerate(graph.edges)
    ]
    return _assemble(places2, paths, odometry=True)


def graph_layout(graph: TourGraph, *, seed: int = 0) -> GraphLayout:
    """Positions of every place and edge image: where they were taught when every image has
    its pose (:func:`posed_layout`), else from odometry when every edge has it.

    Otherwise a networkx spring layout with a fixed ``seed`` (the same graph is always drawn
    the same way) and straight paths. Paths between the same two places (both directions, or
    taught twice) bow out to their right so each stays visible.
    """
    if graph.has_poses and graph.n_images:
        return posed_layout(graph)
    n_loc = graph.n_locations
    odometry = graph.n_edges > 0 and all(has_odometry(e) for e in graph.edges)
    raws: list[FloatArray] = []
    if odometry:
        raws = [integrate_edge(e) for e in graph.edges]
        places2 = _odometry_places(graph, raws)
    elif n_loc:
        g = nx.Graph()
        g.add_nodes_from(range(n_loc))
        g.add_edges_from((e.source, e.target) for e in graph.edges if e.source != e.target)
        if n_loc == 1:
            places2 = np.zeros((1, 2))
        else:
            pos = nx.spring_layout(g, seed=seed)
            places2 = np.array([pos[k] for k in range(n_loc)], dtype=np.float64)
            places2 *= 1.5 * math.sqrt(n_loc)
    else:
        places2 = np.zeros((0, 2))

    extent = 1.0
    if n_loc > 1:
        extent = max(1.0, float(np.ptp(places2, axis=0).max()))
    pair_rank: dict[tuple[int, int], int] = {}
    paths: list[FloatArray] = []
    pairs = {(e.source, e.target) for e in graph.edges}
    for j, e in enumerate(graph.edges):
        start, end = places2[e.source], places2[e.target]
        n = e.n_images
        if odometry:
            path = _fit(raws[j][:, :2], start, end)  # (n + 2, 2) incl. both places
        else:
            s = np.linspace(0.0, 1.0, n + 2)[:, None]
            path = start + s * (end - start)
        rank = pair_rank.get((e.source, e.target), 0)
        pair_rank[(e.source, e.target)] = rank + 1
        if e.source == e.target:  # a loop: draw a circle beside the place
            ang = np.linspace(0.0, 2 * math.pi, n + 2)
            radius = 0.08 * extent * (1 + rank)
            path = start + radius * np.stack([np.sin(ang), 1 - np.cos(ang)], axis=1)
        elif (e.target, e.source) in pairs or rank > 0:
            d = end - start
            length = float(np.hypot(*d))
            if length > 1e-9:
                right = np.array([d[1], -d[0]]) / length
                s = np.linspace(0.0, 1.0, len(path))
                bow = 0.06 * max(length, 0.2 * extent) * (1 + rank)
                path = path + (bow * np.sin(math.pi * s))[:, None] * right
        paths.append(path)
    return _assemble(places2, paths, odometry=odometry)


def image_position(layout: GraphLayout, graph: TourGraph, image: int) -> FloatArray | None:
    """Position of canonical image ``image`` (a place's spin image sits on its place)."""
    state = int(graph.image_state[image])
    if state < graph.n_locations:
        return np.asarray(layout.places[state], dtype=np.float64)
    fine = int(graph.image_fine[image])
    return fine_position(layout, graph, fine)


def fine_position(layout: GraphLayout, graph: TourGraph, fine: int) -> FloatArray | None:
    """Position of fine state ``fine`` (a place, or an image along an edge); ``None`` when
    the layout has no point for it."""
    n_loc = graph.n_locations
    if fine < n_loc:
        return np.asarray(layout.places[fine], dtype=np.float64)
    flat = fine - n_loc
    edge = int(np.searchsorted(graph.edge_offsets, flat, side="right")) - 1
    if not 0 <= edge < graph.n_edges:
        return None
    k = flat - int(graph.edge_offsets[edge])
    pts = layout.edge_points[edge]
    return None if k >= len(pts) else np.asarray(pts[k], dtype=np.float64)


def tracked_position(
    layout: GraphLayout, graph: TourGraph, edge: int, index: int, lateral_m: float
) -> FloatArray | None:
    """Where the path tracker's estimate is drawn: image ``index`` of ``edge`` on the layout,
    moved ``lateral_m`` to the left of the drawn path (scaled as the drawing is); ``None``
    when the edge has no drawn images."""
    pts = layout.edge_points[edge]
    if len(pts) == 0:
        return None
    k = int(np.clip(index, 0, len(pts) - 1))
    ahead, behind = pts[min(k + 3, len(pts) - 1)], pts[max(k - 3, 0)]
    d = np.asarray(ahead - behind, dtype=np.float64)[:2]
    length = float(np.hypot(*d))
    at = np.asarray(pts[k], dtype=np.float64).copy()
    if length < 1e-9:
        return at
    along = graph.edges[edge].metres_along()
    taught = float(along[-1]) if len(along) else 0.0
    drawn = float(np.sum(np.linalg.norm(np.diff(pts[:, :2], axis=0), axis=1)))
    scale = drawn / taught if taught > 1e-9 else 1.0
    normal = np.array([-d[1], d[0]]) / length
    at[:2] += lateral_m * scale * normal
    return at
