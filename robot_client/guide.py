"""The teaching guide: a scripted person walks the simulated robot through the home.

It uses the same client and REST API a real user would: start teaching, stream the frames of
each path with the motion being executed, say "this is the kitchen" on arrival, spin there
(the spin images become the place's images), and finish. Steering uses the simulator's ground
truth, as a person leading the robot would use their eyes.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field

from robot_client.client import TeachRepeatClient
from robot_client.sim.floorplan import FloorPlan
from robot_client.sim.paths import FollowParams, Step, drive_to, spin, turn_to
from robot_client.sim.robot import SimulatedRobot
from robot_client.sim.world import Pose
from server import schemas
from server.imaging import encode_jpeg

DEFAULT_ROUTE: tuple[str, ...] = (
    "entry",
    "living room",
    "hall",
    "bedroom",
    "hall",
    "guest room",
    "hall",
    "bathroom",
    "hall",
    "office",
    "hall",
    "kitchen",
    "hall",
    "living room",
    "kitchen",
    "living room",
    "entry",
)
"""A walk that teaches every place, and every pair of neighbouring places both ways."""


@dataclass(frozen=True)
class GuideParams:
    """``spin_every`` (3): keep every n-th frame of a spin as a place image (about 10 degrees
    apart at the default spin speed). ``spin_w`` (0.6 rad/s). ``jpeg_quality`` (90).
    ``clearance_m`` (0.3): how far from walls the guide walks."""

    spin_every: int = 3
    spin_w: float = 0.6
    jpeg_quality: int = 90
    clearance_m: float = 0.3
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
    route: Sequence[str] = DEFAULT_ROUTE,
    params: GuideParams = GuideParams(),
) -> Iterator[TourStep]:
    """Walk ``route`` (place names of ``plan``) and say what happens at every step.

    The robot is first put at the route's first place. Each arrival is a ``mark``; every place
    is spun at (one full turn, every ``spin_every``-th step kept) on its first visit only.
    """
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


def teach_route(
    client: TeachRepeatClient,
    robot_name: str,
    robot: SimulatedRobot,
    plan: FloorPlan,
    *,
    tour: str,
    route: Sequence[str] = DEFAULT_ROUTE,
    params: GuideParams = GuideParams(),
    on_frame: ProgressHook | None = None,
) -> schemas.TourGraphPublic:
    """Teach ``tour`` by walking ``route`` (place names of ``plan``); returns the tour graph.

    The robot is first put at the route's first place. Every place is spun at on its first
    visit only; later visits just close the path into it.
    """
    check_route(plan, route)  # before anything is sent
    steps = guided_tour_steps(robot, plan, route, params)
    tour_id = client.tour_named(tour, create=True).id
    client.start_teaching(robot_name, tour_id)

    def jpeg() -> bytes:
        image = robot.read()
        if image is None:
            raise RuntimeError("the simulated camera returned no frame")
        return encode_jpeg(image, params.jpeg_quality)

    try:
        for item in steps:
            if item.kind == "mark":
                client.mark_location(robot_name, item.place)
                continue
            st = item.step
            if st is None:  # only marks have no control step
                continue
            if item.kind == "spin":
                client.upload_spin_image(robot_name, jpeg(), timestamp=st.t, v=st.v, w=st.w)
                label = f"spin {item.place}"
            else:
                client.upload_frame(robot_name, jpeg(), timestamp=st.t, v=st.v, w=st.w)
                label = f"to {item.place}"
            if on_frame:
                on_frame(label)
        ended = client.finish_teaching(robot_name)
    except BaseException:
        client.abort_teaching(robot_name)
        raise
    return ended.tour


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
