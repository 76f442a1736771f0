"""A local plan around obstacles back to the taught path.

The path follower (:mod:`server.navigation.pursuit`) steers straight at a point ahead on the
taught path. When furniture stands between the robot and that point (the robot was pushed
beside the path, or a chair was moved onto it), steering straight at it and obstacle
avoidance turning away from the furniture cancel frame by frame: the robot turns to and fro
in front of the obstacle until the task times out (in the seed 700 and 600 benchmarks, 32 of
51 failed trials, against 12 of 93 that arrived). This module gives the follower one plan
instead of two commands that cancel:

* :class:`ObstacleMemory` remembers the depth profile's hits around the robot for a few
  seconds, moved with the odometry (the depth sensor sees 90 degrees ahead; once the robot
  turns away from an obstacle it would otherwise forget it and turn back into it). A hit
  seen again nearer than a ray now reaches through it is forgotten (a moved chair, drift).
* :func:`blocked` says whether the straight line to the point steered at passes an
  obstacle.
* :func:`route` finds the cheapest way on a grid around the robot, from the robot to any of
  the path's points ahead (cells near obstacles cost more, cells too near are closed, space
  never seen counts as free); :func:`waypoint` is the point on it to steer at.
* :class:`LocalPlanner` holds the memory and the way planned last, and keeps that way while
  it stays nearly as cheap as the best new one.

All positions are in the robot's frame (metres ahead, metres to the left). Pure: NumPy,
SciPy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
import numpy.typing as npt
from scipy.ndimage import distance_transform_edt
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from server.navigation.geometry import EdgePath, relative
from server.navigation.scanmatch import ScanParams, profile_points
from server.navigation.tracking import move

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class LocalPlanParams:
    """Settings of the local plan; metres and seconds.

    Attributes:
        enabled (True): plan around an obstacle between the robot and the point steered at;
            False: steer straight at it (obstacle avoidance alone keeps the robot off things).
        memory_s (10.0): how long a depth hit is remembered (robot seconds).
        range_m (1.5): depth readings nearer than this are remembered as obstacles.
        extent_m (2.0): the plan's grid spans this far around the robot each way; hits
            further away are forgotten.
        cell_m (0.05): the grid's cell.
        closed_m (0.2): cells nearer than this to a hit are not passable (the simulated
            robot's radius is 0.18 m; plans leave doorways 0.23 m either side).
        wary_m (0.45): cells nearer than this to a hit cost more, up to ``wary_cost`` times
            a free cell's at ``closed_m``.
        wary_cost (5.0): see ``wary_m``.
        join_m (1.5): the plan's goal is the path from the point steered at to this much
            further on; a point further along costs its extra distance.
        waypoint_m (0.4): the plan's point this far from the robot is steered at.
        keep (1.3): the way planned on the last frame is kept while it costs at most this
            many times the cheapest new one (0: planned afresh every frame; then, and with
            1, a robot setting off beside a sofa saw more of one end, then of the other, as
            it turned, and chose each in turn without moving).
    """

    enabled: bool = True
    memory_s: float = 10.0
    range_m: float = 1.5
    extent_m: float = 2.0
    cell_m: float = 0.05
    closed_m: float = 0.2
    wary_m: float = 0.45
    wary_cost: float = 5.0
    join_m: float = 1.5
    waypoint_m: float = 0.4
    keep: float = 1.3

    def __post_init__(self) -> None:
        if not 0 < self.closed_m < self.wary_m:
            raise ValueError("need 0 < closed_m < wary_m")
        if self.cell_m <= 0 or self.extent_m <= self.cell_m:
            raise ValueError("need 0 < cell_m < extent_m")
        if self.memory_s <= 0 or self.range_m <= 0 or self.waypoint_m <= 0:
            raise ValueError("memory_s, range_m and waypoint_m must be positive")
        if self.keep < 0.0:
            raise ValueError("keep must not be negative")


def carry(points: FloatArray, v: float, w: float, dt: float) -> FloatArray:
    """``(n, 2)`` points of the robot's old frame in its new one, after it drove ``v`` m/s
    and turned ``w`` rad/s for ``dt`` s (on an arc)."""
    return seen_from(move(np.zeros(3), v, w, dt), points)


def seen_from(pose: npt.ArrayLike, points: npt.ArrayLike) -> FloatArray:
    """``(n, 2)`` points ``(n, 2)`` seen from ``pose`` ``(3,)`` (both in one frame): metres
    ahead of it and to its left (:func:`server.navigation.geometry.relative`)."""
    xy = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    out: FloatArray = relative(pose, np.column_stack([xy, np.zeros(len(xy))]))[:, :2]
    return out


def goals_ahead(
    path: EdgePath, pose: npt.ArrayLike, s0: float, params: LocalPlanParams
) -> FloatArray:
    """``(m, 2)`` the plan's goals in the frame of ``pose`` (the robot's, in the path's
    frame): the path from ``s0`` metres along to ``join_m`` further, every two cells
    (clamped to the path's end)."""
    ahead = np.arange(s0, s0 + params.join_m + 1e-9, 2 * params.cell_m)
    return seen_from(pose, np.array([path.point_at(s) for s in ahead]))


class ObstacleMemory:
    """The depth profile's recent hits around the robot, in its frame, moved with odometry.

    One per task; :meth:`update` once per frame with the frame's odometry and depth."""

    def __init__(self, params: LocalPlanParams, fov_deg: float) -> None:
        self.params = params
        self.fov_deg = fov_deg
        self.points: FloatArray = np.zeros((0, 2))
        self.ages: FloatArray = np.zeros(0)
        self._near = replace(ScanParams(), max_range_m=params.range_m)

    def update(self, v: float, w: float, dt: float, depth: npt.ArrayLike | None) -> None:
        """Move the remembered hits by the motion of the last ``dt`` s, forget the old, the
        far and those a ray now reaches through, and add this frame's hits."""
        p = self.params
        points = carry(self.points, v, w, dt)
        ages = self.ages + dt
        if depth is not None and len(np.atleast_1d(depth)):
            ranges = np.asarray(depth, dtype=np.float64).ravel()
            keep = ~_seen_through(points, ranges, self.fov_deg, p.cell_m * 2)
            points, ages = points[keep], ages[keep]
            new = profile_points(ranges, self.fov_deg, self._near)
            points = np.concatenate([new, points])
            ages = np.concatenate([np.zeros(len(new)), ages])
        near = (ages <= p.memory_s) & (np.abs(points).max(axis=1, initial=0.0) <= p.extent_m)
        points, ages = points[near], ages[near]
        # one hit per cell (the newest): the memory stays as small as the grid
        cells = np.floor(points / p.cell_m).astype(np.int64)
        _, first = np.unique(cells, axis=0, return_index=True)
        first.sort()
        self.points, self.ages = points[first], ages[first]


def _seen_through(
    points: FloatArray, ranges: FloatArray, fov_deg: float, tol: float
) -> npt.NDArray[np.bool_]:
    """``(n,)`` whether each point lies inside the depth profile's fan, nearer by ``tol``
    than the ray toward it reaches (so it is no longer there)."""
    n = len(ranges)
    if n < 2 or len(points) == 0:
        return np.zeros(len(points), dtype=bool)
    half = math.radians(fov_deg) / 2
    bearing = np.arctan2(points[:, 1], points[:, 0])  # rays evenly from +half to -half
    dist = np.hypot(points[:, 0], points[:, 1])
    inside = np.abs(bearing) <= half
    ray = np.clip(np.rint((half - bearing) / (2 * half) * (n - 1)), 0, n - 1).astype(np.int64)
    reach = np.where(np.isfinite(ranges), ranges, np.inf)[ray]
    return inside & (dist < reach - tol)


def blocked(points: FloatArray, target: npt.ArrayLike, params: LocalPlanParams) -> bool:
    """Whether the straight line from the robot to ``target`` ``(2,)`` passes nearer than
    ``closed_m`` to a remembered hit ``(n, 2)``."""
    if len(points) == 0:
        return False
    t = np.asarray(target, dtype=np.float64)
    length2 = float(t @ t)
    if length2 < 1e-12:
        return False
    f = np.clip(points @ t / length2, 0.0, 1.0)
    gap = np.linalg.norm(points - f[:, None] * t[None, :], axis=1)
    return bool(gap.min() < params.closed_m)


def _half_cells(params: LocalPlanParams) -> int:
    """Cells from the grid's centre (the robot) to its edge."""
    return round(params.extent_m / params.cell_m)


def _cell_of(xy: FloatArray, params: LocalPlanParams) -> IntArray:
    """``(k, 2)`` the grid's (row, column) of each point ``(k, 2)`` (possibly outside it)."""
    out: IntArray = np.rint(xy / params.cell_m).astype(np.int64) + _half_cells(params)
    return out


@lru_cache(maxsize=4)
def _near_robot(n: int, cell_m: float, radius_m: float) -> npt.NDArray[np.bool_]:
    """``(n, n)`` the grid's cells within ``radius_m`` of its centre (the robot)."""
    c = n // 2
    r = np.hypot(*np.meshgrid(np.arange(n) - c, np.arange(n) - c, indexing="ij")) * cell_m
    return r <= radius_m


@lru_cache(maxsize=4)
def _grid_edges(n: int) -> tuple[IntArray, IntArray, FloatArray]:
    """The 8-neighbour links of an ``n`` x ``n`` grid, each once: ``(from, to, length)`` in
    cells (flat indices, row-major)."""
    idx = np.arange(n * n).reshape(n, n)
    froms, tos, lengths = [], [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        r0, r1 = max(0, -dr), n - max(0, dr)
        c0, c1 = max(0, -dc), n - max(0, dc)
        a, b = idx[r0:r1, c0:c1], idx[r0 + dr : r1 + dr, c0 + dc : c1 + dc]
        froms.append(a.ravel())
        tos.append(b.ravel())
        lengths.append(np.full(a.size, math.hypot(dr, dc)))
    return np.concatenate(froms), np.concatenate(tos), np.concatenate(lengths)


def cell_clearance(points: FloatArray, params: LocalPlanParams) -> FloatArray:
    """``(n, n)`` metres from the centre of each cell of the grid around the robot (as
    :func:`cell_costs` lays it out) to the nearest cell holding a remembered hit ``(n, 2)``;
    ``inf`` everywhere when none lies inside the grid. Exact (float64), so the same in every
    call and process (OpenCV's precise transform is float32 and its last bit varies between
    calls: the plan round an obstacle, and a trial's outcome, varied between runs)."""
    p = params
    n = 2 * _half_cells(p) + 1
    ij = _cell_of(points, p)
    inside = np.all((ij >= 0) & (ij < n), axis=1)
    if not inside.any():
        return np.full((n, n), np.inf)
    free = np.ones((n, n), dtype=bool)
    free[ij[inside, 0], ij[inside, 1]] = False
    out: FloatArray = distance_transform_edt(free) * p.cell_m
    return out


def cell_costs(points: FloatArray, params: LocalPlanParams) -> FloatArray:
    """``(n, n)`` what crossing each cell of the grid around the robot costs per cell
    (1 in free space, more near a hit, ``inf`` too near). Row ``i`` is ``x = (i - c) *
    cell_m`` ahead, column ``j`` is ``y = (j - c) * cell_m`` to the left, ``c = n // 2``."""
    p = params
    clearance = cell_clearance(points, p)
    n = len(clearance)
    wary = np.clip((p.wary_m - clearance) / (p.wary_m - p.closed_m), 0.0, 1.0)
    costs = 1.0 + (p.wary_cost - 1.0) * wary
    closed = clearance < p.closed_m
    # the robot may stand nearer than closed_m to something (avoidance lets it come to
    # 0.25 m): the cells it stands on stay passable, at the highest cost
    closed &= ~(_near_robot(n, p.cell_m, p.closed_m) & (clearance > 0.0))
    return np.where(closed, np.inf, costs)


def route(
    points: FloatArray, goals: npt.ArrayLike, params: LocalPlanParams
) -> tuple[FloatArray, float] | None:
    """The cheapest way from the robot to one of ``goals`` ``(m, 2)`` (the path ahead,
    nearest first: each costs its distance along the goals, in cells, on top of the way to
    it) around the remembered hits ``points`` ``(n, 2)``: ``(k, 2)`` the cells' centres
    from the robot's to the goal's, and the cost (cells, weighted by :func:`cell_costs`);
    ``None`` when no goal inside the grid can be reached."""
    return _route(cell_costs(points, params), _goals(goals), params)


def _goals(goals: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """``(m, 2)`` goals and ``(m,)`` metres along them from the first."""
    g = np.asarray(goals, dtype=np.float64).reshape(-1, 2)
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(g, axis=0), axis=1))])
    return g, along


def _route(
    costs: FloatArray, goals: tuple[FloatArray, FloatArray], params: LocalPlanParams
) -> tuple[FloatArray, float] | None:
    """:func:`route` on the grid's ``costs`` ``(n, n)``."""
    p = params
    c = _half_cells(p)
    n = 2 * c + 1
    g, along = goals
    gij = _cell_of(g, p)
    inside = np.all((gij >= 0) & (gij < n), axis=1)
    if not inside.any():
        return None
    flat = costs.ravel()
    a, b, length = _grid_edges(n)
    weight = length * (flat[a] + flat[b]) / 2
    ok = np.isfinite(weight)
    graph = csr_matrix((weight[ok], (a[ok], b[ok])), shape=(n * n, n * n))
    start = c * n + c
    dist, pred = dijkstra(graph, directed=False, indices=start, return_predecessors=True)
    goal_cells = gij[inside, 0] * n + gij[inside, 1]
    total = dist[goal_cells] + along[inside] / p.cell_m
    best = int(np.argmin(total))
    if not np.isfinite(total[best]):
        return None
    way = [int(goal_cells[best])]
    while way[-1] != start:
        way.append(int(pred[way[-1]]))
    cells = np.array(way[::-1])
    return (np.stack([cells // n, cells % n], axis=1) - c) * p.cell_m, float(total[best])


def way_cost(
    way: FloatArray,
    costs: FloatArray,
    goals: tuple[FloatArray, FloatArray],
    params: LocalPlanParams,
) -> float:
    """What following ``way`` ``(k, 2)`` (a way planned before, in the robot's frame now)
    costs on the grid's ``costs`` from its point nearest the robot, as :func:`route` counts
    it; ``inf`` when it crosses a closed cell, leaves the grid or no longer ends at one of
    ``goals``."""
    p = params
    n = len(costs)
    g, along = goals
    if len(way) == 0 or len(g) == 0:
        return math.inf
    end = np.linalg.norm(g - way[-1], axis=1)
    if end.min() > 2 * p.cell_m:
        return math.inf
    k = int(np.argmin(np.linalg.norm(way, axis=1)))
    pts = np.concatenate([np.zeros((1, 2)), way[k:]])
    ij = _cell_of(pts, p)
    if np.any((ij < 0) | (ij >= n)):
        return math.inf
    cc = costs[ij[:, 0], ij[:, 1]]
    steps = np.linalg.norm(np.diff(pts, axis=0), axis=1) / p.cell_m
    return float(np.sum(steps * (cc[:-1] + cc[1:]) / 2) + along[int(np.argmin(end))] / p.cell_m)


def waypoint(way: FloatArray, params: LocalPlanParams) -> FloatArray:
    """``(2,)`` the point of ``way`` ``(k, 2)`` to steer at: the first ``waypoint_m`` or
    further from the robot (its end, when nearer)."""
    far = np.nonzero(np.hypot(way[:, 0], way[:, 1]) >= params.waypoint_m)[0]
    out: FloatArray = way[far[0]] if len(far) else way[-1]
    return out


class LocalPlanner:
    """The obstacle memory and the way last planned, both moved with odometry: one per
    task; :meth:`update` once per frame, :meth:`steer` when following the path."""

    def __init__(self, params: LocalPlanParams, fov_deg: float) -> None:
        self.params = params
        self.memory = ObstacleMemory(params, fov_deg)
        self.way: FloatArray | None = None

    def update(self, v: float, w: float, dt: float, depth: npt.ArrayLike | None) -> None:
        """The frame's odometry (m/s, rad/s over ``dt`` s) and depth profile."""
        self.memory.update(v, w, dt, depth)
        if self.way is not None:
            self.way = carry(self.way, v, w, dt)

    def steer(self, goals: npt.ArrayLike) -> FloatArray | None:
        """``(2,)`` the point to steer at when a remembered obstacle lies on the straight
        line to the first of ``goals`` ``(m, 2)`` (the path ahead, nearest first): on the
        way planned last frame while it costs at most ``keep`` times the cheapest new way,
        else on the new one. ``None`` when the line is clear or no way is found."""
        p = self.params
        g = _goals(goals)
        points = self.memory.points
        if len(g[0]) == 0 or len(points) == 0 or not blocked(points, g[0][0], p):
            self.way = None
            return None
        costs = cell_costs(points, p)
        found = _route(costs, g, p)
        kept = math.inf if self.way is None else way_cost(self.way, costs, g, p)
        way = self.way if math.isfinite(kept) else None
        if found is not None and kept > p.keep * found[1]:
            way = found[0]
        self.way = way
        return None if way is None else waypoint(way, p)
