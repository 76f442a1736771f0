"""The local plan round obstacles back to the taught path: the obstacle memory against the
poses it was seen from, the plan's way against a naive Dijkstra, and a robot beside the path
with a sofa between them, driven by pure pursuit and obstacle avoidance as the navigator
drives it: with the plan it goes round the sofa onto the path, without it it turns to and
fro in front of the sofa."""

from __future__ import annotations

import heapq
import math
from dataclasses import replace

import numpy as np
import pytest
from navigation_testkit import FOV, B, observation, room_profile, runtime
from test_navigation_topometric import estimate

from server.belief.model import Action
from server.domain import Edge
from server.motion import MotionParams, avoid_obstacles, avoid_side
from server.navigation.behaviours import Follow
from server.navigation.geometry import EdgePath, relative
from server.navigation.localplan import (
    LocalPlanner,
    LocalPlanParams,
    ObstacleMemory,
    blocked,
    carry,
    cell_clearance,
    cell_costs,
    goals_ahead,
    route,
    waypoint,
)
from server.navigation.pursuit import PursuitParams, lookahead_point, lookahead_s, pursue
from server.navigation.tracking import move

P = LocalPlanParams()


def test_carried_points_are_where_the_moved_robot_sees_them() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        world = rng.uniform(-2, 2, (5, 2))
        v, w, dt = rng.uniform(-0.3, 0.3), rng.uniform(-1, 1), rng.uniform(0.05, 0.5)
        after = move(np.zeros(3), v, w, dt)
        naive = np.array([relative(after, [*p, 0.0])[:2] for p in world])
        assert np.allclose(carry(world, v, w, dt), naive, atol=1e-12)


def test_the_memory_keeps_what_turned_out_of_view_and_forgets_the_old_and_the_seen_through() -> (
    None
):
    m = ObstacleMemory(P, FOV)
    wall = np.full(31, np.inf)
    wall[10:21] = 0.8  # something 0.8 m ahead
    m.update(0.0, 0.0, 0.0, wall)
    seen = len(m.points)
    assert seen == 11
    # the robot turns 90 degrees left: the obstacle is out of the depth fan, still remembered
    m.update(0.0, math.pi / 2, 1.0, np.full(31, np.inf))
    assert len(m.points) >= seen - 1 and np.all(m.points[:, 1] < -0.5)  # now on its right
    # it turns back: the rays reach through where it was (it moved away): forgotten
    m.update(0.0, -math.pi / 2, 1.0, np.full(31, np.inf))
    assert len(m.points) == 0
    # seen once, then never looked at again: forgotten after memory_s
    m.update(0.0, 0.0, 0.0, wall)
    for _ in range(int(P.memory_s / 0.5) + 1):
        m.update(0.0, math.pi, 0.5, None)  # turning, no depth
    assert len(m.points) == 0


def test_the_memory_holds_one_hit_per_cell() -> None:
    m = ObstacleMemory(P, FOV)
    wall = np.full(31, 1.0)
    for _ in range(30):
        m.update(0.0, 0.0, 0.1, wall)
    cells = np.floor(m.points / P.cell_m).astype(int)
    assert len(np.unique(cells, axis=0)) == len(cells) <= 31


def test_the_clearance_is_exactly_the_naive_distance_to_the_nearest_hit_cell() -> None:
    # exact, not within a tolerance: a last bit that differs between calls chose another
    # way round an obstacle in one run of a trial and not in the next
    rng = np.random.default_rng(3)
    c = round(P.extent_m / P.cell_m)
    n = 2 * c + 1
    cells = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), axis=-1)
    for k in (1, 5, 40):
        points = rng.uniform(-2.3, 2.3, (k, 2))  # some outside the grid
        clearance = cell_clearance(points, P)
        hits = np.rint(points / P.cell_m).astype(np.int64) + c
        hits = hits[np.all((hits >= 0) & (hits < n), axis=1)]
        if len(hits) == 0:
            assert np.all(np.isinf(clearance))
            continue
        squared = ((cells[:, :, None, :] - hits[None, None, :, :]) ** 2).sum(axis=-1).min(axis=-1)
        assert np.array_equal(clearance, np.sqrt(squared.astype(np.float64)) * P.cell_m)
        assert np.array_equal(clearance, cell_clearance(points.copy(), P))
    assert np.all(np.isinf(cell_clearance(np.array([[5.0, 5.0]]), P)))


def test_blocked_agrees_with_a_densely_sampled_segment() -> None:
    rng = np.random.default_rng(1)
    for _ in range(200):
        points = rng.uniform(-1.5, 1.5, (rng.integers(1, 6), 2))
        target = rng.uniform(-1.5, 1.5, 2)
        samples = np.linspace(0, 1, 4001)[:, None] * target[None, :]
        gap = np.min(np.linalg.norm(points[:, None, :] - samples[None, :, :], axis=2))
        if abs(gap - P.closed_m) < 1e-3:
            continue
        assert blocked(points, target, P) == (gap < P.closed_m)
    assert not blocked(np.zeros((0, 2)), [1.0, 0.0], P)


def naive_cost(points: np.ndarray, goals: np.ndarray, p: LocalPlanParams) -> float:
    """The cheapest way's cost by Dijkstra with a heap, cell by cell."""
    costs = cell_costs(points, p)
    n = len(costs)
    c = n // 2
    best = {(c, c): 0.0}
    heap = [(0.0, c, c)]
    while heap:
        d, i, j = heapq.heappop(heap)
        if d > best[(i, j)]:
            continue
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                a, b = i + di, j + dj
                if (di, dj) == (0, 0) or not (0 <= a < n and 0 <= b < n):
                    continue
                nd = d + math.hypot(di, dj) * (costs[i, j] + costs[a, b]) / 2
                if math.isfinite(nd) and nd < best.get((a, b), math.inf):
                    best[(a, b)] = nd
                    heapq.heappush(heap, (nd, a, b))
    out, along = math.inf, 0.0
    for k, g in enumerate(goals):
        if k:
            along += float(np.linalg.norm(g - goals[k - 1]))
        ij = tuple(int(x) for x in np.rint(g / p.cell_m).astype(int) + c)
        out = min(out, best.get(ij, math.inf) + along / p.cell_m)
    return out


def test_the_way_costs_what_a_naive_dijkstra_finds_and_avoids_closed_cells() -> None:
    small = replace(P, extent_m=0.8)
    rng = np.random.default_rng(2)
    for _ in range(10):
        points = rng.uniform(-0.8, 0.8, (8, 2))
        points = points[np.hypot(points[:, 0], points[:, 1]) > 0.3]
        goals = np.stack([np.linspace(0.3, 0.7, 5), np.full(5, rng.uniform(-0.7, 0.7))], axis=1)
        found = route(points, goals, small)
        naive = naive_cost(points, goals, small)
        if found is None:
            assert naive == math.inf
            continue
        way, cost = found
        assert cost == pytest.approx(naive, rel=1e-6)
        assert np.allclose(way[0], 0.0)
        assert np.min(np.linalg.norm(way[-1] - goals, axis=1)) <= small.cell_m
        c = len(cell_costs(points, small)) // 2
        ij = np.rint(way / small.cell_m).astype(int) + c
        assert np.all(np.isfinite(cell_costs(points, small)[ij[:, 0], ij[:, 1]]))


def test_in_free_space_it_heads_for_the_nearest_goal() -> None:
    goals = np.stack([np.linspace(1.0, 2.0, 11), np.full(11, 1.0)], axis=1)
    found = route(np.zeros((0, 2)), goals, P)
    assert found is not None
    wp = waypoint(found[0], P)
    assert np.hypot(*wp) == pytest.approx(P.waypoint_m, abs=P.cell_m)
    assert math.atan2(wp[1], wp[0]) == pytest.approx(math.pi / 4, abs=0.15)


# -- closed loop: a robot beside the path, a sofa between them --------------------------------

ROOM = [  # 6 m x 3 m; the taught path runs along y = 2.0, a sofa 0.3 m deep below it
    (0, 0, 6, 0),
    (6, 0, 6, 3),
    (6, 3, 0, 3),
    (0, 3, 0, 0),
    (1.0, 1.35, 3.2, 1.35),
    (3.2, 1.35, 3.2, 1.65),
    (3.2, 1.65, 1.0, 1.65),
    (1.0, 1.65, 1.0, 1.35),
]
PATH_START = np.array([0.5, 2.0, 0.0])


def clearance(x: float, y: float) -> float:
    """Metres from (x, y) to the nearest of the room's segments."""
    out = math.inf
    for x0, y0, x1, y1 in ROOM:
        a, b, q = np.array([x0, y0]), np.array([x1, y1]), np.array([x, y])
        f = float(np.clip((q - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1))
        out = min(out, float(np.linalg.norm(q - (a + f * (b - a)))))
    return out


def drive(
    local: LocalPlanParams, heading: float = math.pi / 2, steps: int = 400
) -> tuple[list[float], float]:
    """Drive from 1 m beside the path, 0.35 m from the sofa between them, ``heading`` rad
    from the path's direction (pi / 2: facing the sofa), by pure pursuit (round obstacles by
    the local plan when it is on) with obstacle avoidance blended in as the navigator does;
    the truth is the estimate. The lateral offset after every step, the least clearance."""
    n = 25
    edge = Edge(0, 1, tuple(range(n)), np.arange(n) * 0.8, np.full(n, 0.25), np.zeros(n))
    path = EdgePath.of(edge)  # 4.8 m straight on
    pp, mp = PursuitParams(), MotionParams()
    planner = LocalPlanner(local, FOV)
    truth = np.array([1.6, 1.0, heading])
    v = w = 0.0
    side = 0
    offsets, least = [], math.inf
    for step in range(steps):
        truth = move(truth, v, w, 0.1)
        least = min(least, clearance(truth[0], truth[1]))
        depth = room_profile(*truth, walls=ROOM)
        planner.update(v, w, 0.1 if step else 0.0, depth)
        pose = relative(PATH_START, truth)  # in the path's frame
        s, lateral = path.project(pose[:2])
        offsets.append(lateral)
        if s > path.length - 0.5:
            break
        s0 = lookahead_s(s, lateral, pp)
        goals = goals_ahead(path, pose, s0, local)
        way = planner.steer(goals) if local.enabled else None
        if way is not None:
            v, w = pursue(np.zeros(3), way, params=pp, remaining_m=path.length - s)
        else:
            target = lookahead_point(path, s, lateral, pp)
            v, w = pursue(pose, target, params=pp, remaining_m=path.length - s)
        side = avoid_side(depth, mp, side)
        v, w = avoid_obstacles(v, w, depth, mp, side=side)
    return offsets, least


def test_beside_the_path_with_a_sofa_between_the_plan_takes_it_round_onto_the_path() -> None:
    offsets, least = drive(P)
    assert abs(offsets[-1]) < 0.25 and len(offsets) < 400  # on the path, at its end
    assert least > 0.18  # the simulated robot's radius: never touched the sofa
    stuck, _ = drive(replace(P, enabled=False))
    assert len(stuck) == 400 and abs(stuck[-1]) > 0.5  # still below the sofa


def test_the_way_planned_last_is_kept_so_the_robot_does_not_choose_each_end_in_turn() -> None:
    # set off along the path: the sofa's far end is beyond the depth's reach, its near end
    # behind the robot; turning, it sees more of one end, then of the other
    offsets, least = drive(P, heading=0.0)
    assert abs(offsets[-1]) < 0.25 and len(offsets) < 400 and least > 0.18
    afresh, _ = drive(replace(P, keep=0.0), heading=0.0)  # planned afresh every frame
    assert len(afresh) == 400 and abs(afresh[-1]) > 0.5


def test_follow_steers_round_a_remembered_obstacle() -> None:
    rt = runtime()
    obs = observation(rt, action=Action.navigate(0), active_edge=0, goal=B)
    beside = replace(obs, path=estimate(rt, along=0.0, lateral=-0.6), depth=None)
    follow = Follow(rt)
    straight = follow.propose(beside)
    assert straight is not None and "tracking the path" in straight.reason
    assert straight.command.w > 0  # 0.6 m right of the path: it steers left, onto it
    # a wall between it and the path, seen a moment ago: round it, turning right first
    memory = follow.local.memory
    memory.points = np.stack([np.linspace(-0.2, 1.5, 35), np.full(35, 0.3)], axis=1)
    memory.ages = np.zeros(35)
    follow.local.update(0.0, 0.0, 0.1, None)
    around = follow.propose(beside)
    assert around is not None and "round an obstacle" in around.reason
    # the way leads back past the wall's near end, clear of it on the right: turn first
    assert around.command.w < 0 and around.command.v == 0
