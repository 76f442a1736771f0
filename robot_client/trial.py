"""One navigation trial in the simulated home, judged against the simulator's ground truth.

Used by ``teachrepeat demo``, ``teachrepeat bench navigate`` and the closed-loop test. The
navigator never sees the ground truth; only this judge does.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import networkx as nx
import numpy as np
import numpy.typing as npt

from robot_client.client import ApiError, TeachRepeatClient
from robot_client.judge_localisation import LocalisationJudge
from robot_client.navigate import LoopParams, StepHook, drive
from robot_client.sim.floorplan import FloorPlan
from robot_client.sim.paths import NoPathError, path_length, shortest_path
from robot_client.sim.robot import SimulatedRobot
from robot_client.sim.world import Pose
from server import schemas

SUCCESS_RADIUS_M = 0.5
"""A trial succeeds when the robot says "arrived" within this distance of the goal place."""

FINAL_WINDOW_S = 20.0
"""The end of a failed trial that says why it failed (robot seconds; see :func:`cause`)."""
START_CLEARANCE_M = 0.35
"""A trial starts at least this far from walls and furniture (as taught and as moved)."""
STUCK_M = 0.25
"""A robot that stays within this many metres through the final window made no progress."""

CAUSES = ("wrong place", "off target", "stuck", "lost", "timeout")

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class TaughtTruth:
    """Where the teaching robot really drove each taught edge (the simulator's truth, for the
    judge only): edge id -> ``(n, 3)`` true poses of its images, in teaching order."""

    edges: dict[int, FloatArray]

    @classmethod
    def of(cls, tour: schemas.TourGraphPublic, steps: Sequence[Any]) -> TaughtTruth:
        """Pair the tour's edges (in id order, as they were taught) with the runs of path
        frames between the marks of the recorded tour ``steps``
        (:class:`robot_client.tour_recording.RecordedStep`, with true poses)."""
        runs: list[list[tuple[float, float, float]]] = []
        current: list[tuple[float, float, float]] = []
        for step in steps:
            if step.kind == "frame" and step.pose is not None:
                current.append(step.pose)
            elif step.kind == "mark":
                if current:
                    runs.append(current)
                current = []
        edges: dict[int, FloatArray] = {}
        queue = list(runs)
        for edge in sorted(tour.edges, key=lambda e: e.id):
            while queue and len(queue[0]) != edge.image_count:
                queue.pop(0)  # a path the server did not keep (too short)
            if not queue:
                break
            edges[edge.id] = np.asarray(queue.pop(0), dtype=np.float64)
        return cls(edges)

    def error(self, edge: int, x: float, y: float) -> float | None:
        """Metres from ``(x, y)`` to the nearest point of ``edge``'s true path (its images'
        positions joined), or ``None`` for an edge it does not know."""
        poses = self.edges.get(edge)
        if poses is None or len(poses) == 0:
            return None
        pts = poses[:, :2]
        p = np.array([x, y])
        if len(pts) == 1:
            return float(np.linalg.norm(p - pts[0]))
        a, b = pts[:-1], pts[1:]
        ab = b - a
        ab2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12)
        f = np.clip(np.einsum("ij,ij->i", p - a, ab) / ab2, 0.0, 1.0)
        near = a + f[:, None] * ab
        return float(np.sqrt(np.min(np.einsum("ij,ij->i", p - near, p - near))))

    def locate(self, edge: int, along: float, lateral: float) -> tuple[float, float] | None:
        """Where a path estimate ``along`` metres along ``edge`` and ``lateral`` metres to
        its left puts the robot in the world (m): the point that far along the true path
        (its images' positions joined; clamped to its ends), moved ``lateral`` to the left
        of the path's direction there (of the heading taught there where the path has no
        length, a turn on the spot). ``None`` for an edge it does not know."""
        poses = self.edges.get(edge)
        if poses is None or len(poses) == 0:
            return None
        pts = poses[:, :2]
        seg = np.hypot(*np.diff(pts, axis=0).T) if len(pts) > 1 else np.zeros(0)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        along = float(np.clip(along, 0.0, s[-1]))
        i = int(np.clip(np.searchsorted(s, along, side="right") - 1, 0, max(len(pts) - 2, 0)))
        if len(seg) and seg[i] > 1e-9:
            f = (along - s[i]) / seg[i]
            point = pts[i] + f * (pts[i + 1] - pts[i])
            direction = (pts[i + 1] - pts[i]) / seg[i]
        else:
            point = pts[i]
            theta = float(poses[i, 2])
            direction = np.array([np.cos(theta), np.sin(theta)])
        left = np.array([-direction[1], direction[0]])
        x, y = point + lateral * left
        return float(x), float(y)


"""Why a trial failed, in the order they are tested (see :func:`cause`)."""


@dataclass(frozen=True)
class StepLog:
    """What the judge keeps of one step: robot time (s), true position (m), the command's
    forward speed (m/s), action and behaviour, and whether the belief was localised."""

    t: float
    x: float
    y: float
    v: float
    action: str
    behaviour: str
    localised: bool


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
    behaviours: dict[str, int]  # frames per behaviour of the motion layer
    final_behaviour: str | None  # the behaviour of the last frame
    final_reason: str | None  # why that behaviour chose the last command
    cause: str | None  # why it failed (one of CAUSES), None on success
    # localisation against the truth (robot_client.judge_localisation)
    first_correct_s: float | None = None  # from the start to the first right "localised"
    wrong_claims: int = 0  # runs of frames "localised" on a wrong state
    wrong_claim_frames: int = 0
    # topometric repeat: metres from the robot to the true path of the edge it follows, on
    # every frame it follows one by its pose relative to the path (the simulator's truth)
    tracking_error_m: tuple[float, ...] = ()

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


def cause(
    *,
    success: bool,
    state: str,
    reason: str | None,
    wrong_arrival: bool,
    log: Sequence[StepLog],
    window_s: float = FINAL_WINDOW_S,
    stuck_m: float = STUCK_M,
) -> str | None:
    """Why a trial failed (``None`` when it succeeded), the first that applies:

    * ``wrong place``: it said "arrived" nearer another place than the goal;
    * ``off target``: it said "arrived" at the goal, but more than 0.5 m from it;
    * ``stuck``: the server said so, or through the last ``window_s`` of robot time the robot
      stayed within ``stuck_m`` of where it was while trying to drive on at least half of the
      frames (Navigate, or a forward or backward speed of 2 cm/s or more);
    * ``lost``: the server gave up on its position, or the belief was not localised on at
      least half of the frames of the last ``window_s``;
    * ``timeout``: time ran out while it was still making its way.
    """
    if success:
        return None
    if state == "arrived":
        return "wrong place" if wrong_arrival else "off target"
    reason = reason or ""
    if reason.startswith("stuck"):
        return "stuck"
    if reason.startswith("lost"):
        return "lost"
    if log:
        end = log[-1].t
        tail = [s for s in log if s.t >= end - window_s]
        x0, y0 = tail[0].x, tail[0].y
        stayed = max(math.hypot(s.x - x0, s.y - y0) for s in tail) < stuck_m
        driving = sum(s.action == "navigate" or abs(s.v) >= 0.02 for s in tail)
        long_enough = end - log[0].t >= window_s
        if long_enough and stayed and driving >= 0.5 * len(tail):
            return "stuck"
        if sum(not s.localised for s in tail) >= 0.5 * len(tail):
            return "lost"
    return "timeout"


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
    record: bool | None = None,
    truth: TaughtTruth | None = None,
    depth_sensor: bool = True,
) -> TrialResult:
    """Send the robot to ``goal`` from wherever it stands and drive until the task ends.

    ``tour`` (the taught graph) gives the shortest taught route for the path ratio;
    ``record``: ask the server to record the task (``None``: its setting decides);
    ``truth``: where the taught paths really are, for the tracking error; ``depth_sensor``
    False: the robot sends no depth profile (a one-webcam robot)."""
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
    log: list[StepLog] = []
    behaviours: dict[str, int] = {}
    localisation = LocalisationJudge(plan, tour)

    tracking: list[float] = []

    def judge(step: int, result: schemas.NavigationFrameResult) -> None:
        pose, command = robot.pose, result.command
        localisation.observe(robot.now(), pose.x, pose.y, pose.theta, result)
        name = command.behaviour or "none"
        behaviours[name] = behaviours.get(name, 0) + 1
        path = result.path
        if truth is not None and path is not None and path.locked and name == "follow":
            error = truth.error(path.edge, pose.x, pose.y)
            if error is not None:
                tracking.append(round(error, 4))
        log.append(
            StepLog(
                robot.now(),
                pose.x,
                pose.y,
                command.v,
                command.action,
                name,
                result.belief.localised,
            )
        )
        if on_step is not None:
            on_step(step, result)

    client.goto(robot_name, goal, tour=None if tour is None else tour.id, record=record)
    outcome = drive(
        client,
        robot_name,
        camera=robot,
        motors=robot,
        clock=robot,
        depth=robot if depth_sensor else None,
        params=LoopParams(max_steps=max_steps, wait_for_answer=True),
        on_step=judge,
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
    success = arrived and distance <= SUCCESS_RADIUS_M
    wrong = arrived and near != goal
    return TrialResult(
        goal=goal,
        start=start,
        state=state,
        reason=reason,
        success=success,
        wrong_arrival=wrong,
        distance_m=distance,
        nearest_place=near,
        time_s=robot.now() - t0,
        driven_m=robot.odometer - odo0,
        shortest_m=shortest,
        taught_m=taught,
        steps=outcome.steps,
        explore_fraction=explore / outcome.steps if outcome.steps else 0.0,
        actions=outcome.actions,
        behaviours=behaviours,
        final_behaviour=log[-1].behaviour if log else None,
        final_reason=None if outcome.last is None else outcome.last.command.reason,
        cause=cause(success=success, state=state, reason=reason, wrong_arrival=wrong, log=log),
        tracking_error_m=tuple(tracking),
        **localisation.summary(),
    )


def draw_trial(plan: FloorPlan, seed: int, trial: int) -> tuple[Pose, str, int]:
    """Start pose, goal and noise seed of trial number ``trial`` of a run seeded ``seed``.

    They depend on ``(seed, trial)`` and the plan alone, not on which other trials run or in
    what order (so trials can be run alone, in any order, on any number of workers), and are
    the same in every condition: the start is free in the home as taught and as moved. Every
    fourth trial of a plan with look-alike places starts within 0.8 m of one of them (in turn),
    where telling them apart is hardest; the others start anywhere free.
    """
    from robot_client.sim.world import PlanGeometry

    rng = np.random.default_rng([seed, trial])
    goal = plan.places[int(rng.integers(len(plan.places)))].name
    noise = int(rng.integers(2**31))
    key = "trial.geometries"
    if key not in plan._cache:
        plan._cache[key] = (PlanGeometry(plan), PlanGeometry(plan, condition="moved"))
    geometries = plan._cache[key]

    def free(x: float, y: float) -> bool:
        inside = plan.room_at(x, y) is not None
        return inside and not any(g.collides(x, y, START_CLEARANCE_M) for g in geometries)

    aliases = [name for pair in plan.aliases for name in pair]
    if aliases and trial % 4 == 3:
        place = plan.place(aliases[trial // 4 % len(aliases)])
        for _ in range(100):
            x = place.x + rng.uniform(-0.8, 0.8)
            y = place.y + rng.uniform(-0.8, 0.8)
            if free(x, y):
                return Pose(float(x), float(y), float(rng.uniform(-math.pi, math.pi))), goal, noise
    x0, y0, x1, y1 = plan.bounds
    for _ in range(10_000):
        x, y = rng.uniform(x0, x1), rng.uniform(y0, y1)
        if free(x, y):
            return Pose(float(x), float(y), float(rng.uniform(-math.pi, math.pi))), goal, noise
    raise RuntimeError(f"no free start pose in plan {plan.name!r}")
