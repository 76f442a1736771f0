"""The teaching guide: a scripted person walks the simulated robot through the home.

It uses the same client and REST API a real user would: start teaching, stream the frames of
each path with the robot's odometry, say "this is the kitchen" on arrival, spin there (the spin
images become the place's images), and finish. Steering uses the simulator's ground truth, as a
person leading the robot would use their eyes; the truth is never sent to the server.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field

from robot_client.client import TeachRepeatClient, wire_range
from robot_client.sim.floorplan import FloorPlan
from robot_client.sim.paths import (
    GUIDE_CLEARANCE_M,
    FollowParams,
    Step,
    drive_to,
    spin,
    turn_to,
)
from robot_client.sim.robot import SimulatedRobot
from robot_client.sim.route import teaching_route
from robot_client.sim.world import Pose
from robot_client.tour_recording import RecordedStep, TourRecording
from server import schemas
from server.imaging import encode_jpeg


@dataclass(frozen=True)
class GuideParams:
    """``spin_every`` (3): keep every n-th frame of a spin as a place image (about 10 degrees
    apart at the default spin speed). ``spin_w`` (0.6 rad/s). ``jpeg_quality`` (90).
    ``clearance_m`` (0.3): how far from walls the guide walks."""

    spin_every: int = 3
    spin_w: float = 0.6
    jpeg_quality: int = 90
    clearance_m: float = GUIDE_CLEARANCE_M
    follow: FollowParams = field(default_factory=FollowParams)


ProgressHook = Callable[[str], None]


def check_route(plan: FloorPlan, route: Sequence[str]) -> None:
    """``ValueError`` naming the places of ``route`` that ``plan`` does not have."""
    places = {p.name for p in plan.places}
    unknown = [name for name in route if name not in places]
    if not route or unknown:
        raise ValueError(f"route names unknown places {unknown}; the plan has {sorted(places)}")


@dataclass(frozen=True)
class TourStep:
    """One moment of a guided tour: ``kind`` is ``"frame"`` (a step along the path to
    ``place``; upload the camera frame), ``"spin"`` (a kept step of the spin at ``place``) or
    ``"mark"`` (the robot has just arrived at ``place``: name it). ``step`` is the control
    step (time, ground-truth pose, motion); ``None`` for a mark."""

    kind: str
    place: str
    step: Step | None = None


def guided_tour_steps(
    robot: SimulatedRobot,
    plan: FloorPlan,
    route: Sequence[str] | None = None,
    params: GuideParams = GuideParams(),
) -> Iterator[TourStep]:
    """Walk ``route`` (place names of ``plan``; default: :func:`teaching_route`) and say what
    happens at every step.

    The robot is first put at the route's first place. Each arrival is a ``mark``; every place
    is spun at (one full turn, every ``spin_every``-th step kept) on its first visit only.
    """
    route = teaching_route(plan) if route is None else tuple(route)
    check_route(plan, route)
    places = {p.name: p for p in plan.places}
    first = places[route[0]]
    robot.teleport(Pose(first.x, first.y, first.yaw))
    visited: set[str] = set()

    def arrive(name: str) -> Iterator[TourStep]:
        yield TourStep("mark", name)
        if name in visited:
            return
        visited.add(name)
        for k, step in enumerate(spin(robot, turns=1.0, w=params.spin_w, dt=params.follow.dt)):
            if k % params.spin_every == 0:
                yield TourStep("spin", name, step)

    yield from arrive(route[0])
    for name in route[1:]:
        place = places[name]
        for step in walk_to(robot, place.x, place.y, place.yaw, params):
            yield TourStep("frame", name, step)
        yield from arrive(name)


def recorded_steps(
    robot: SimulatedRobot, steps: Iterable[TourStep], params: GuideParams = GuideParams()
) -> Iterator[RecordedStep]:
    """The camera's JPEG at every frame and spin step of ``steps`` (marks pass through), with
    the robot's odometry since the image before (what a real robot reports: its measured
    speeds, noise and all, never the commanded ones), its depth profile, and the simulator's
    true pose for the judge (:class:`RecordedStep`: never uploaded)."""
    robot.odometry()  # counts from the first image: what the wheels did before is not the tour's
    for item in steps:
        if item.kind == "mark" or item.step is None:
            yield RecordedStep(item.kind, item.place, 0.0, 0.0, 0.0, None)
            continue
        image = robot.read()
        if image is None:
            raise RuntimeError("the simulated camera returned no frame")
        st = item.step
        jpeg = encode_jpeg(image, params.jpeg_quality)
        v, w = robot.odometry()
        pose = (st.pose.x, st.pose.y, st.pose.theta)
        depth = tuple(wire_range(float(r)) for r in robot.profile())
        yield RecordedStep(item.kind, item.place, st.t, v, w, jpeg, pose, depth)


def record_tour(
    robot: SimulatedRobot,
    plan: FloorPlan,
    route: Sequence[str] | None = None,
    params: GuideParams = GuideParams(),
) -> TourRecording:
    """Walk the route and keep everything the server would be sent (for a benchmark to teach
    many servers the same tour without walking it again)."""
    route = teaching_route(plan) if route is None else tuple(route)
    steps = tuple(recorded_steps(robot, guided_tour_steps(robot, plan, route, params), params))
    return TourRecording(plan_sha256=plan.sha256, route=route, steps=steps)


def upload_tour(
    client: TeachRepeatClient,
    robot_name: str,
    steps: Iterable[RecordedStep],
    *,
    tour: str,
    on_frame: ProgressHook | None = None,
) -> schemas.TourGraphPublic:
    """Teach ``tour`` through the REST API from recorded steps; returns the tour graph. A failure
    part-way aborts the teaching (the open path is discarded, the places named so far stay)."""
    tour_id = client.tour_named(tour, create=True).id
    client.start_teaching(robot_name, tour_id)
    try:
        for item in steps:
            if item.kind == "mark":
                client.mark_location(robot_name, item.place)
                continue
            if item.jpeg is None:  # only marks have no image
                continue
            # the true pose stays with the recording (for the judge): a robot sends only what
            # it could know, its frames and odometry
            if item.kind == "spin":
                client.upload_spin_image(
                    robot_name, item.jpeg, timestamp=item.t, v=item.v, w=item.w, depth=item.depth
                )
                label = f"spin {item.place}"
            else:
                client.upload_frame(
                    robot_name, item.jpeg, timestamp=item.t, v=item.v, w=item.w, depth=item.depth
                )
                label = f"to {item.place}"
            if on_frame:
                on_frame(label)
        ended = client.finish_teaching(robot_name)
    except BaseException:
        client.abort_teaching(robot_name)
        raise
    return ended.tour


def teach_route(
    client: TeachRepeatClient,
    robot_name: str,
    robot: SimulatedRobot,
    plan: FloorPlan,
    *,
    tour: str,
    route: Sequence[str] | None = None,
    params: GuideParams = GuideParams(),
    on_frame: ProgressHook | None = None,
) -> schemas.TourGraphPublic:
    """Teach ``tour`` by walking ``route`` (place names of ``plan``; default: the plan's
    teaching route) and streaming each frame as it is taken; returns the tour graph.

    The robot is first put at the route's first place. Every place is spun at on its first
    visit only; later visits just close the path into it.
    """
    route = teaching_route(plan) if route is None else tuple(route)
    check_route(plan, route)  # before anything is sent
    steps = recorded_steps(robot, guided_tour_steps(robot, plan, route, params), params)
    return upload_tour(client, robot_name, steps, tour=tour, on_frame=on_frame)


@dataclass(frozen=True)
class Rehearsal:
    """What teaching a route will take: ``uploads`` images (frames and spin images) over
    ``seconds`` of robot time."""

    uploads: int
    seconds: float


def rehearse(
    plan: FloorPlan, route: Sequence[str] | None = None, params: GuideParams = GuideParams()
) -> Rehearsal:
    """Walk the guide through ``route`` without a camera (collisions only, no noise): the
    total and ETA of a teaching progress bar. Exact for a robot without noise; within a few
    percent of a noisy one. About half a second for the apartment."""
    from robot_client.sim.robot import RobotParams
    from robot_client.sim.world import PlanGeometry

    route = teaching_route(plan) if route is None else tuple(route)
    quiet = RobotParams(actuation_noise=0.0, odom_noise_v=0.0, odom_noise_w=0.0)
    first = plan.place(route[0])
    robot = SimulatedRobot(PlanGeometry(plan), Pose(first.x, first.y, first.yaw), params=quiet)
    uploads = sum(s.kind != "mark" for s in guided_tour_steps(robot, plan, route, params))
    return Rehearsal(uploads=uploads, seconds=robot.now())


def walk_to(
    robot: SimulatedRobot, x: float, y: float, yaw: float, params: GuideParams
) -> Iterator[Step]:
    """Drive to ``(x, y)`` and face ``yaw``, yielding each control step (fails loudly when the
    robot gets stuck)."""
    for step in drive_to(robot, (x, y), clearance=params.clearance_m, params=params.follow):
        if step.failed:
            raise RuntimeError(f"the guide got stuck at {step.pose} on its way to ({x}, {y})")
        yield step
    yield from turn_to(robot, yaw, dt=params.follow.dt)
