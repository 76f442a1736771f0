"""One navigation trial in the simulated home, judged against the simulator's ground truth.

Used by ``teachrepeat demo``, ``teachrepeat bench navigate`` and the closed-loop test. The
navigator never sees the ground truth; only this judge does.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import asdict, dataclass
from typing import Any

import networkx as nx

from robot_client.client import ApiError, TeachRepeatClient
from robot_client.navigate import LoopParams, StepHook, drive
from robot_client.sim.floorplan import FloorPlan
from robot_client.sim.paths import NoPathError, path_length, shortest_path
from robot_client.sim.robot import SimulatedRobot
from server import schemas

SUCCESS_RADIUS_M = 0.5
"""A trial succeeds when the robot says "arrived" within this distance of the goal place."""


@dataclass(frozen=True)
class TrialResult:
    goal: str
    start: tuple[float, float, float]
    state: str  # arrived | failed | cancelled | underway (ran out of steps)
    reason: str | None
    success: bool
    wrong_arrival: bool  # said "arrived" nearer another place than the goal
    distance_m: float  # from the goal place when the trial ended
    nearest_place: str
    time_s: float  # simulated seconds
    driven_m: float
    shortest_m: float  # free-space shortest path from start to goal (A* on the plan)
    taught_m: float  # shortest taught route: to a place through free space, then taught edges
    steps: int
    explore_fraction: float
    actions: dict[str, int]

    @property
    def path_ratio(self) -> float:
        """Driven metres / the shortest taught route (the issue's path ratio)."""
        return self.driven_m / self.taught_m if self.taught_m > 0 else math.nan

    @property
    def free_space_ratio(self) -> float:
        """Driven metres / the free-space shortest path (stricter: ignores what was taught)."""
        return self.driven_m / self.shortest_m if self.shortest_m > 0 else math.nan

    def row(self) -> dict[str, Any]:
        return {
            **asdict(self),
            "path_ratio": self.path_ratio,
            "free_space_ratio": self.free_space_ratio,
        }


def taught_route_m(
    world: Any,
    plan: FloorPlan,
    tour: schemas.TourGraphPublic,
    start: tuple[float, float],
    goal: str,
) -> float:
    """Length of the shortest taught route from ``start`` to ``goal``: through free space to
    some place, then along taught edges (their taught lengths); the best such place."""
    graph = nx.DiGraph()
    for e in tour.edges:
        w = e.length_m
        if graph.has_edge(e.source_name, e.target_name):
            w = min(w, graph[e.source_name][e.target_name]["weight"])
        graph.add_edge(e.source_name, e.target_name, weight=w)
    if goal not in graph:
        return math.nan
    to_goal = nx.single_source_dijkstra_path_length(graph.reverse(copy=False), goal)
    best = math.inf
    for place in plan.places:
        if place.name not in to_goal:
            continue
        try:
            walk = path_length(shortest_path(world, start, (place.x, place.y)))
        except NoPathError:
            continue
        best = min(best, walk + to_goal[place.name])
    return best if math.isfinite(best) else math.nan


def nearest_place(plan: FloorPlan, x: float, y: float) -> tuple[str, float]:
    best = min(plan.places, key=lambda p: math.hypot(p.x - x, p.y - y))
    return best.name, math.hypot(best.x - x, best.y - y)


def run_trial(
    client: TeachRepeatClient,
    robot_name: str,
    robot: SimulatedRobot,
    plan: FloorPlan,
    goal: str,
    *,
    tour: schemas.TourGraphPublic | None = None,
    max_steps: int = 2000,
    on_step: StepHook | None = None,
) -> TrialResult:
    """Send the robot to ``goal`` from wherever it stands and drive until the task ends.

    ``tour`` (the taught graph) gives the shortest taught route for the path ratio."""
    place = next(p for p in plan.places if p.name == goal)
    pose = robot.pose
    start = (pose.x, pose.y, pose.theta)
    try:
        shortest = path_length(shortest_path(robot.world, (pose.x, pose.y), (place.x, place.y)))
    except NoPathError:
        shortest = math.nan
    taught = math.nan
    if tour is not None:
        taught = taught_route_m(robot.world, plan, tour, (pose.x, pose.y), goal)
    t0, odo0 = robot.now(), robot.odometer
    client.goto(robot_name, goal)
    outcome = drive(
        client,
        robot_name,
        camera=robot,
        motors=robot,
        clock=robot,
        depth=robot,
        params=LoopParams(max_steps=max_steps, wait_for_answer=True),
        on_step=on_step,
    )
    state: str = "underway"
    reason: str | None = "ran out of steps"
    if outcome.task is not None:
        state, reason = outcome.task.state, outcome.task.reason
    if state == "underway":
        with contextlib.suppress(ApiError):  # it may have ended in the meantime
            client.stop(robot_name)
        reason = f"ran out of {max_steps} steps"
    robot.stop()
    end = robot.pose
    distance = math.hypot(end.x - place.x, end.y - place.y)
    near, _ = nearest_place(plan, end.x, end.y)
    arrived = state == "arrived"
    explore = outcome.actions.get("explore", 0)
    return TrialResult(
        goal=goal,
        start=start,
        state=state,
        reason=reason,
        success=arrived and distance <= SUCCESS_RADIUS_M,
        wrong_arrival=arrived and near != goal,
        distance_m=distance,
        nearest_place=near,
        time_s=robot.now() - t0,
        driven_m=robot.odometer - odo0,
        shortest_m=shortest,
        taught_m=taught,
        steps=outcome.steps,
        explore_fraction=explore / outcome.steps if outcome.steps else 0.0,
        actions=outcome.actions,
    )
