"""The path tracker: regulated pure pursuit joins a path from an offset and keeps to it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from server.domain import Edge
from server.navigation.geometry import EdgePath
from server.navigation.pursuit import PursuitParams, lookahead_point, pursue
from server.navigation.tracking import move


def path_of(v: np.ndarray, w: np.ndarray) -> EdgePath:
    n = len(v)
    return EdgePath.of(Edge(0, 1, tuple(range(n)), np.arange(n) * 0.1, v, w))


def drive(path: EdgePath, start: np.ndarray, steps: int = 600) -> list[tuple[float, float]]:
    """Close the loop on a perfect pose: (along, lateral) after every step."""
    p = PursuitParams()
    pose = start.copy()
    out = []
    for _ in range(steps):
        s, lat = path.project(pose[:2])
        if path.length - s < 0.05:
            break
        target = lookahead_point(path, s, lat, p)
        v, w = pursue(pose, target, params=p, remaining_m=path.length - s)
        pose = move(pose, v, w, 0.1)
        out.append((s, lat))
    return out


@pytest.mark.parametrize("offset", [0.5, 1.0, 2.0, -1.5])
def test_a_robot_beside_a_straight_path_joins_it(offset: float) -> None:
    path = path_of(np.full(160, 0.25), np.zeros(160))  # 4 m
    trace = drive(path, np.array([0.0, offset, 0.3]))  # turned 17 degrees to the left
    s, lat = trace[-1]
    assert s > 3.9 and abs(lat) < 0.05
    # on the path (within 0.1 m) before it has gone its offset + 1.5 m along it
    assert all(abs(lat) < 0.1 for s, lat in trace if s > abs(offset) + 1.5)


def test_a_curved_path_is_followed_closely_and_slower_on_the_curve() -> None:
    v = np.full(200, 0.25)
    w = np.where((np.arange(200) > 60) & (np.arange(200) < 120), 0.4, 0.0)
    path = path_of(v, w)
    trace = drive(path, np.zeros(3), steps=1000)
    assert max(abs(lat) for _, lat in trace) < 0.08
    p = PursuitParams()
    straight = pursue(np.zeros(3), np.array([0.5, 0.0]), params=p)
    tight = pursue(np.zeros(3), np.array([0.3, 0.3]), params=p)
    assert tight[0] < straight[0]


def test_speed_falls_near_obstacles_and_the_end_and_far_targets_turn_on_the_spot() -> None:
    p = PursuitParams()
    free = pursue(np.zeros(3), np.array([0.6, 0.0]), params=p)
    near = pursue(np.zeros(3), np.array([0.6, 0.0]), params=p, nearest_m=0.35)
    end = pursue(np.zeros(3), np.array([0.6, 0.0]), params=p, remaining_m=0.1)
    assert free[0] == p.speed and near[0] < free[0] and end[0] < free[0]
    behind = pursue(np.zeros(3), np.array([-0.5, 0.1]), params=p)
    assert behind[0] == 0.0 and behind[1] > 0
    assert math.isclose(abs(pursue(np.zeros(3), np.array([0.0, -1.0]), params=p)[1]), p.max_w)
