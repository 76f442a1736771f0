"""Shortest paths on the floor plan, and a scripted guide that drives the robot along them.

* :func:`shortest_path` - A* on an occupancy grid of the plan inflated by a clearance, with a soft
  cost for hugging walls (paths go through the middle of doorways), then shortened by line of sight.
  Deterministic. Used by the teaching guide and by benchmarks ("taught optimum" path lengths).
* :func:`follow`, :func:`spin`, :func:`turn_to`, :func:`drive_to` -
  generators that drive a :class:`SimulatedRobot` through ``command()`` / ``sleep()`` and yield
  after every step, so a caller can grab frames, send them to the server or draw them. They
  steer by the ground-truth pose: they play the person walking the robot around, not the
  navigation stack.
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from robot_client.sim.floorplan import FloorPlan
from robot_client.sim.robot import SimulatedRobot
from robot_client.sim.world import PlanGeometry, Pose, SimWorld

Point = tuple[float, float]


GUIDE_CLEARANCE_M = 0.3
"""How far from walls and furniture the teaching guide walks the robot, metres."""


class NoPathError(ValueError):
    """No collision-free path joins the two points at the requested clearance."""


@dataclass(frozen=True)
class GridParams:
    """Path planning grid.

    Attributes:
        resolution_m: cell size, metres.
        wall_penalty: extra cost factor for cells closer than ``comfort_m`` to an obstacle.
        comfort_m: clearance beyond which a cell costs nothing extra, metres.
        snap_m: an endpoint inside the inflated obstacles is moved to the nearest free cell
            within this distance, metres.
    """

    resolution_m: float = 0.05
    wall_penalty: float = 3.0
    comfort_m: float = 0.6
    snap_m: float = 0.5


class _Grid:
    """Clearance sampled at the cell centres of the plan's bounding box."""

    def __init__(self, geometry: PlanGeometry, resolution: float) -> None:
        x0, y0, x1, y1 = geometry.plan.bounds
        self.x0, self.y0, self.res = x0, y0, resolution
        self.nx = math.ceil((x1 - x0) / resolution)
        self.ny = math.ceil((y1 - y0) / resolution)
        xs = x0 + (np.arange(self.nx) + 0.5) * resolution
        ys = y0 + (np.arange(self.ny) + 0.5) * resolution
        gx, gy = np.meshgrid(xs, ys)  # (ny, nx)
        clear = geometry.clearance_map(gx, gy)
        # distance to the outer boundary counts as an obstacle too
        edge = np.minimum.reduce([gx - x0, x1 - gx, gy - y0, y1 - gy])
        self.clearance: npt.NDArray[np.float64] = np.minimum(clear, edge)

    def cell(self, p: Point) -> tuple[int, int]:
        i = int(np.clip((p[1] - self.y0) / self.res, 0, self.ny - 1))
        j = int(np.clip((p[0] - self.x0) / self.res, 0, self.nx - 1))
        return i, j

    def centre(self, c: tuple[int, int]) -> Point:
        return (self.x0 + (c[1] + 0.5) * self.res, self.y0 + (c[0] + 0.5) * self.res)


def _geometry(where: FloorPlan | SimWorld | PlanGeometry) -> PlanGeometry:
    if isinstance(where, PlanGeometry):
        return where
    if isinstance(where, SimWorld):
        return where.geometry
    return PlanGeometry(where)


def _grid(geometry: PlanGeometry, resolution: float) -> _Grid:
    key = ("paths.grid", resolution)
    grid = geometry.cache.get(key)
    if not isinstance(grid, _Grid):
        grid = _Grid(geometry, resolution)
        geometry.cache[key] = grid
    return grid


def shortest_path(
    where: FloorPlan | SimWorld | PlanGeometry,
    start: Point,
    goal: Point,
    *,
    clearance: float = 0.3,
    params: GridParams = GridParams(),
) -> list[Point]:
    """A short collision-free path from ``start`` to ``goal`` keeping ``clearance`` from obstacles.

    Args:
        where: the home (a plan means its ``same`` geometry; pass a world for ``moved``).
        start, goal: ``(x, y)`` metres.
        clearance: minimum distance from the path to any wall or furniture, metres (at least the
            robot's radius).
    Returns:
        waypoints ``[(x, y), ...]`` in metres, from ``start`` to ``goal`` inclusive.
    Raises:
        NoPathError: an endpoint is inside an obstacle, or the two are not connected.
    """
    geometry = _geometry(where)
    grid = _grid(geometry, params.resolution_m)
    free = grid.clearance >= clearance
    s = _snap(grid, free, start, params.snap_m, "start")
    g = _snap(grid, free, goal, params.snap_m, "goal")
    cells = _astar(grid, free, s, g, clearance, params)
    if cells is None:
        raise NoPathError(
            f"no path from {start} to {goal} with {clearance} m clearance; "
            "try a smaller clearance or check that the rooms are joined by doors"
        )
    raw = [start] + [grid.centre(c) for c in cells[1:-1]] + [goal]
    return _shorten(grid, raw, clearance)


def path_length(points: Sequence[Point]) -> float:
    """Length of the polyline through ``points``, metres."""
    return float(sum(math.dist(a, b) for a, b in itertools.pairwise(points)))


def _snap(
    grid: _Grid, free: npt.NDArray[np.bool_], p: Point, snap_m: float, what: str
) -> tuple[int, int]:
    c = grid.cell(p)
    if free[c]:
        return c
    r = math.ceil(snap_m / grid.res)
    i0, j0 = c
    best: tuple[float, tuple[int, int]] | None = None
    for i in range(max(0, i0 - r), min(grid.ny, i0 + r + 1)):
        for j in range(max(0, j0 - r), min(grid.nx, j0 + r + 1)):
            if free[i, j]:
                d = (i - i0) ** 2 + (j - j0) ** 2
                if best is None or d < best[0]:
                    best = (d, (i, j))
    if best is None or best[0] > r * r:
        raise NoPathError(f"{what} {p} is inside an obstacle (no free cell within {snap_m} m)")
    return best[1]


_NEIGHBOURS = [
    (di, dj, math.hypot(di, dj)) for di in (-1, 0, 1) for dj in (-1, 0, 1) if (di, dj) != (0, 0)
]


def _astar(
    grid: _Grid,
    free: npt.NDArray[np.bool_],
    s: tuple[int, int],
    g: tuple[int, int],
    clearance: float,
    params: GridParams,
) -> list[tuple[int, int]] | None:
    """8-connected A* over free cells; ties broken by insertion order (deterministic)."""
    comfort = max(params.comfort_m, clearance + 1e-6)
    penalty = 1.0 + params.wall_penalty * np.clip(
        (comfort - grid.clearance) / (comfort - clearance), 0.0, 1.0
    )
    nx, ny = grid.nx, grid.ny
    free_flat = free.reshape(-1)
    pen_flat = penalty.reshape(-1)
    start, goal = s[0] * nx + s[1], g[0] * nx + g[1]
    gi, gj = g
    best = {start: 0.0}
    parent = {start: start}
    heap = [(0.0, 0, start)]
    counter = 0
    done = set()
    while heap:
        _, _, cur = heapq.heappop(heap)
        if cur == goal:
            path = [cur]
            while path[-1] != start:
                path.append(parent[path[-1]])
            return [(k // nx, k % nx) for k in reversed(path)]
        if cur in done:
            continue
        done.add(cur)
        ci, cj = divmod(cur, nx)
        base = best[cur]
        for di, dj, step in _NEIGHBOURS:
            i, j = ci + di, cj + dj
            if not (0 <= i < ny and 0 <= j < nx):
                continue
            k = i * nx + j
            if not free_flat[k] or k in done:
                continue
            cost = base + step * 0.5 * (pen_flat[cur] + pen_flat[k])
            if cost < best.get(k, math.inf):
                best[k] = cost
                parent[k] = cur
                counter += 1
                h = math.hypot(i - gi, j - gj)
                heapq.heappush(heap, (cost + h, counter, k))
    return None


def _line_clear(grid: _Grid, a: Point, b: Point, clearance: float) -> bool:
    n = max(2, int(math.dist(a, b) / (grid.res * 0.5)) + 1)
    for t in np.linspace(0.0, 1.0, n):
        c = grid.cell((a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])))
        if grid.clearance[c] < clearance:
            return False
    return True


def _shorten(grid: _Grid, raw: list[Point], clearance: float) -> list[Point]:
    """Greedy line-of-sight shortcutting; keeps a margin where the raw path had one."""
    out = [raw[0]]
    i = 0
    while i < len(raw) - 1:
        j = len(raw) - 1
        while j > i + 1 and not _line_clear(grid, raw[i], raw[j], clearance + 0.5 * grid.res):
            j -= 1
        out.append(raw[j])
        i = j
    return out


# -- scripted driving ------------------------------------------------------------------------------


@dataclass(frozen=True)
class FollowParams:
    """Pure-pursuit path following for the scripted guide.

    Attributes:
        lookahead_m: distance along the path to the point steered at, metres.
        v_max: cruise speed, m/s. w_max: largest turn rate, rad/s.
        turn_in_place_rad: heading errors above this are turned on the spot first, radians.
        goal_tol_m: arrival radius, metres.
        dt: control period (one yielded step), seconds.
        timeout_s: give up after this long, seconds.
    """

    lookahead_m: float = 0.45
    v_max: float = 0.3
    w_max: float = 1.0
    turn_in_place_rad: float = 0.9
    goal_tol_m: float = 0.08
    dt: float = 0.1
    timeout_s: float = 300.0


@dataclass(frozen=True)
class Step:
    """One control step of a scripted motion.

    Attributes:
        t: simulated time after the step, seconds. pose: ground truth after the step.
        v, w: the command executed during the step (m/s, rad/s).
        done: True on the last step (arrived or, when ``failed``, gave up).
        failed: the motion could not be completed (timeout).
    """

    t: float
    pose: Pose
    v: float
    w: float
    done: bool = False
    failed: bool = False


def _closest_on_path(
    points: npt.NDArray[np.float64],
    cum: npt.NDArray[np.float64],
    p: npt.NDArray[np.float64],
    from_s: float,
) -> float:
    """Arc length of the point of the path closest to ``p``, not going back before ``from_s``."""
    best_s, best_d = from_s, math.inf
    for k in range(len(points) - 1):
        if cum[k + 1] < from_s - 1e-9:
            continue
        a, b = points[k], points[k + 1]
        ab = b - a
        L = float(cum[k + 1] - cum[k])
        t = 0.0 if L == 0 else float(np.clip(np.dot(p - a, ab) / (L * L), 0.0, 1.0))
        s = float(cum[k] + t * L)
        if s < from_s:
            s, t = from_s, (from_s - cum[k]) / L if L else 0.0
        q = a + t * ab
        d = float(np.linalg.norm(p - q))
        if d < best_d - 1e-9:
            best_s, best_d = s, d
    return best_s


def _point_at(
    points: npt.NDArray[np.float64], cum: npt.NDArray[np.float64], s: float
) -> npt.NDArray[np.float64]:
    s = float(np.clip(s, 0.0, cum[-1]))
    k = int(np.searchsorted(cum, s, side="right") - 1)
    k = min(max(k, 0), len(points) - 2)
    L = cum[k + 1] - cum[k]
    t = 0.0 if L == 0 else (s - cum[k]) / L
    return points[k] + t * (points[k + 1] - points[k])


def follow(
    robot: SimulatedRobot, waypoints: Sequence[Point], *, params: FollowParams = FollowParams()
) -> Iterator[Step]:
    """Drive ``robot`` along ``waypoints`` (metres) by pure pursuit; yield after every step.

    The robot stops at the end. The last yielded step has ``done=True`` (``failed=True`` on
    timeout). Steering uses the ground-truth pose (this is the guide, not the navigator).
    """
    if len(waypoints) == 0:
        return
    pts = np.asarray(waypoints, dtype=np.float64).reshape(-1, 2)
    if len(pts) == 1:
        pts = np.vstack([[robot.pose.x, robot.pose.y], pts])
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    goal = pts[-1]
    s_prog = 0.0
    t_end = robot.now() + params.timeout_s
    while True:
        pose = robot.pose
        p = np.array([pose.x, pose.y])
        if float(np.linalg.norm(goal - p)) <= params.goal_tol_m:
            robot.stop()
            yield Step(robot.now(), pose, 0.0, 0.0, done=True)
            return
        if robot.now() >= t_end:
            robot.stop()
            yield Step(robot.now(), pose, 0.0, 0.0, done=True, failed=True)
            return
        s_prog = _closest_on_path(pts, cum, p, s_prog)
        target = _point_at(pts, cum, s_prog + params.lookahead_m)
        to_goal = float(np.linalg.norm(goal - p))
        if cum[-1] - s_prog < params.lookahead_m:
            target = goal
        dx, dy = target - p
        alpha = _wrap(math.atan2(dy, dx) - pose.theta)
        if abs(alpha) > params.turn_in_place_rad:
            v, w = 0.0, math.copysign(params.w_max, alpha)
        else:
            v = params.v_max * max(0.0, math.cos(alpha)) * min(1.0, 0.3 + to_goal / 0.5)
            dist = max(float(np.hypot(dx, dy)), 1e-6)
            w = float(
                np.clip(2.0 * max(v, 0.05) * math.sin(alpha) / dist, -params.w_max, params.w_max)
            )
        robot.command(v, w)
        robot.sleep(params.dt)
        yield Step(robot.now(), robot.pose, v, w)


def turn_to(
    robot: SimulatedRobot, yaw: float, *, w: float = 0.8, dt: float = 0.1, tol: float = 0.03
) -> Iterator[Step]:
    """Turn on the spot to heading ``yaw`` (radians); yield after every step."""
    while True:
        err = _wrap(yaw - robot.pose.theta)
        if abs(err) <= tol:
            robot.stop()
            yield Step(robot.now(), robot.pose, 0.0, 0.0, done=True)
            return
        rate = math.copysign(min(w, abs(err) / dt), err)
        robot.command(0.0, rate)
        robot.sleep(dt)
        yield Step(robot.now(), robot.pose, 0.0, rate)


def spin(
    robot: SimulatedRobot, *, turns: float = 1.0, w: float = 0.8, dt: float = 0.1
) -> Iterator[Step]:
    """Turn on the spot by ``turns`` full revolutions (counter-clockwise for ``w > 0``);
    yield after every step. Used at a place to photograph it all round."""
    total = 2 * math.pi * turns
    turned = 0.0
    while turned < total - 1e-9:
        rate = math.copysign(min(abs(w), (total - turned) / dt), w)
        before = robot.pose.theta
        robot.command(0.0, rate)
        robot.sleep(dt)
        turned += abs(_wrap(robot.pose.theta - before))
        last = turned >= total - 1e-6
        if last:
            robot.stop()
        yield Step(robot.now(), robot.pose, 0.0, rate, done=last)


def drive_to(
    robot: SimulatedRobot,
    goal: Point,
    *,
    clearance: float = 0.3,
    params: FollowParams = FollowParams(),
) -> Iterator[Step]:
    """Plan a shortest path from the robot's true position to ``goal`` and follow it."""
    path = shortest_path(robot.world, (robot.pose.x, robot.pose.y), goal, clearance=clearance)
    yield from follow(robot, path, params=params)


def _wrap(angle: float) -> float:
    return math.atan2(math.sin(angle), math.cos(angle))
