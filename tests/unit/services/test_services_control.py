"""The server's mode logic for streaming robots: stand, teleop, the spin at a new place, and
navigation, on real services over a temporary SQLite file, with a hand-driven clock."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import make_jpeg
from pydantic import SecretStr

from server import schemas
from server.errors import Conflict
from server.services.container import Services
from server.services.control import ControlParams


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture()
def clock() -> Clock:
    return Clock()


@pytest.fixture()
def services(tmp_path: Path, clock: Clock) -> Iterator[Services]:
    from server.app import create_app
    from server.config import Settings

    settings = Settings(
        db=tmp_path / "control.sqlite", admin_token=SecretStr("admin"), dashboard_port=None
    )
    services: Services = create_app(settings).state.services
    services.control.clock = clock
    services.robots.register(schemas.RobotCreate(name="rover"), 1)
    yield services
    services.close()


class Robot:
    """A robot that streams frames: its clock, its odometry, what it was told."""

    def __init__(self, services: Services, clock: Clock) -> None:
        self.services = services
        self.clock = clock
        self.t = 0.0
        self.v = 0.0
        self.w = 0.0
        self.seed = 0

    def frame(self, *, stream: bool = True, dt: float = 0.1) -> schemas.AnyFrameResult:
        """One frame after ``dt`` seconds (robot and server clocks alike), reporting as
        odometry what it was last told; then obeys the answer."""
        self.t += dt
        self.clock.t += dt
        self.seed += 1
        meta = schemas.FrameMeta(timestamp=self.t, v=self.v, w=self.w, stream=stream)
        result = self.services.frame("rover", make_jpeg(self.seed, 64, 48), meta)
        assert result.command is not None
        self.v, self.w = result.command.v, result.command.w
        return result


@pytest.fixture()
def robot(services: Services, clock: Clock) -> Robot:
    return Robot(services, clock)


def teleop(services: Services, v: float, w: float = 0.0, ttl: float = 0.5) -> schemas.TeleopState:
    body = schemas.TeleopCommand(v=v, w=w, ttl_s=ttl)
    return services.control.teleop("rover", body, actor="household:default")


def start_teaching(services: Services) -> int:
    tour = services.tours.create(schemas.TourCreate(name="home"), 1)
    services.teaching.start("rover", schemas.TeachStart(tour=tour.id))
    return tour.id


def mark(services: Services, name: str) -> schemas.MarkResult:
    return services.teaching.mark("rover", schemas.LocationMark(name=name))


def test_an_idle_robot_is_told_to_stand_until_someone_drives_it(
    services: Services, robot: Robot, clock: Clock
) -> None:
    first = robot.frame()
    assert isinstance(first, schemas.IdleFrameResult)
    assert first.command.behaviour == "stand" and (first.command.v, first.command.w) == (0, 0)
    assert first.command.ttl_s == ControlParams().ttl_s == 0.3

    state = teleop(services, 0.2, 0.5, ttl=0.25)
    assert (state.v, state.w, state.clamped, state.mode) == (0.2, 0.5, False, "idle")
    driven = robot.frame(dt=0.05)
    assert driven.command.behaviour == "teleop" and (driven.command.v, driven.command.w) == (
        0.2,
        0.5,
    )
    # never beyond the teleop command's end: 0.2 s of its 0.25 s are left
    assert driven.command.ttl_s == pytest.approx(0.2)
    clock.t += 0.25  # nobody repeats it: it ends by itself
    assert robot.frame().command.behaviour == "stand"


def test_teleop_is_clamped_to_the_speed_limit_and_zero_stops_at_once(
    services: Services, robot: Robot
) -> None:
    robot.frame()
    state = teleop(services, 4.0, -10.0)
    assert (state.v, state.w, state.clamped) == (0.3, -1.0, True)
    assert (state.max_v, state.max_w) == (0.3, 1.0)
    assert robot.frame().command.v == 0.3
    teleop(services, 0.0, 0.0)
    assert robot.frame().command.behaviour == "stand"


def test_teleop_for_a_robot_that_sends_no_frames_is_refused(
    services: Services, robot: Robot, clock: Clock
) -> None:
    with pytest.raises(Conflict, match=r"has never sent a frame.*teachrepeat robot run"):
        teleop(services, 0.2)
    robot.frame(stream=False)  # a client that is not the agent does not count
    with pytest.raises(Conflict, match="not connected"):
        teleop(services, 0.2)
    robot.frame()
    clock.t += 5.0
    with pytest.raises(Conflict, match="sent its last frame 5 s ago"):
        teleop(services, 0.2)


def test_only_the_start_of_a_drive_is_audited(services: Services, robot: Robot) -> None:
    robot.frame()
    for _ in range(5):
        teleop(services, 0.2)
        robot.frame()
    teleop(services, 0.0)
    teleop(services, 0.1)
    rows = [(a.actor, a.action) for a in services.repo.audit(limit=10)]
    assert rows == [("household:default", "teleop start")] * 2


def test_while_teaching_only_frames_driven_by_hand_are_kept_on_the_path(
    services: Services, robot: Robot
) -> None:
    start_teaching(services)
    before = robot.frame()
    assert isinstance(before, schemas.FrameResult) and before.image is None  # no place yet
    assert before.command is not None and "name the place" in (before.command.reason or "")
    teleop(services, 0.2)  # drive before naming: nothing is kept (there is no path yet)
    robot.frame()
    robot.frame()
    assert services.teaching.state("rover").open_path_images == 0  # type: ignore[union-attr]
    services.control.halt("rover")
    robot.frame()
    mark(services, "start")  # not spun at: see the spin tests (the robot is connected...)
    services.control.halt("rover")  # ...so halt that spin here
    robot.frame()
    standing = robot.frame()
    assert isinstance(standing, schemas.FrameResult) and standing.image is None
    teleop(services, 0.2, ttl=1.0)
    told = robot.frame()  # told to drive: this frame was taken standing, not kept
    assert told.image is None and told.command.behaviour == "teleop"  # type: ignore[union-attr]
    kept = [robot.frame() for _ in range(4)]  # each taken while driving: kept
    assert all(isinstance(k, schemas.FrameResult) and k.image for k in kept)
    assert kept[-1].open_path_images == 4  # type: ignore[union-attr]
    teleop(services, 0.0)
    last = robot.frame()  # taken after the last interval of driving: kept
    assert last.image is not None and last.open_path_images == 5  # type: ignore[union-attr]
    assert robot.frame().image is None  # type: ignore[union-attr]


def test_frames_of_a_client_that_decides_itself_are_all_kept_as_before(
    services: Services, robot: Robot
) -> None:
    start_teaching(services)
    mark(services, "start")
    services.teaching.spin_image("rover", make_jpeg(99), schemas.FrameMeta(timestamp=0.01))
    results = [robot.frame(stream=False) for _ in range(3)]
    assert [r.open_path_images for r in results] == [1, 2, 3]  # type: ignore[union-attr]
    assert all(r.command.behaviour == "stand" for r in results)  # type: ignore[union-attr]


def spin_at(services: Services, robot: Robot, name: str) -> list[schemas.AnyFrameResult]:
    """Name a new place and stream frames until the spin ends."""
    result = mark(services, name)
    assert result.created
    frames = []
    for _ in range(200):
        frames.append(robot.frame())
        spin = services.control.public("rover").spin  # type: ignore[union-attr]
        if spin is not None and spin.state != "spinning":
            break
    return frames


def test_a_new_place_is_spun_at_and_the_spin_frames_become_its_images(
    services: Services, robot: Robot
) -> None:
    tour_id = start_teaching(services)
    robot.frame()
    frames = spin_at(services, robot, "hall")
    spin = services.control.public("rover").spin  # type: ignore[union-attr]
    assert spin is not None and spin.state == "done" and spin.place == "hall"
    spinning = [f for f in frames if f.command.behaviour == "spin"]  # type: ignore[union-attr]
    assert spinning and all(f.command.w == 0.6 for f in spinning)  # type: ignore[union-attr]
    # 0.06 rad a frame at 0.6 rad/s and 10 frames/s: one image every 3 frames, ~35 in a turn
    assert 33 <= spin.images <= 36 and spin.turned_deg >= 355
    hall = next(loc for loc in services.tours.graph(tour_id, 1).locations if loc.name == "hall")
    assert hall.image_count == spin.images
    assert frames[-1].command.behaviour == "stand"  # type: ignore[union-attr]
    assert "spun at hall" in (frames[-1].command.reason or "")  # type: ignore[union-attr]
    # then the robot stands, nothing kept, until a person drives it
    assert robot.frame().image is None  # type: ignore[union-attr]
    # a known place is not spun at again
    teleop(services, 0.2, ttl=1.0)
    for _ in range(5):
        robot.frame()
    teleop(services, 0.0)
    robot.frame()
    assert not mark(services, "hall").created
    assert services.control.public("rover").spin.state == "done"  # type: ignore[union-attr]


def test_while_it_spins_teleop_is_refused_and_halt_ends_the_spin(
    services: Services, robot: Robot
) -> None:
    start_teaching(services)
    robot.frame()
    mark(services, "hall")
    robot.frame()
    robot.frame()
    with pytest.raises(Conflict, match=r"turning once at 'hall'.*halt"):
        teleop(services, 0.2)
    assert services.control.halt("rover") == ["the spin at hall"]
    assert services.control.public("rover").spin.state == "stopped"  # type: ignore[union-attr]
    assert robot.frame().command.behaviour == "stand"  # type: ignore[union-attr]
    teleop(services, 0.2)  # and it may be driven again


def test_a_spin_without_odometry_ends_after_its_time(services: Services, robot: Robot) -> None:
    start_teaching(services)
    robot.frame()
    mark(services, "hall")
    for _ in range(300):
        robot.w = 0.0  # the wheels report nothing (blocked, or no odometry)
        robot.frame()
        spin = services.control.public("rover").spin  # type: ignore[union-attr]
        if spin.state != "spinning":  # type: ignore[union-attr]
            break
    assert spin.state == "timeout" and spin.images == 1  # type: ignore[union-attr]
    # 2.5 times the 10.5 s a turn takes at 0.6 rad/s
    assert robot.t == pytest.approx(0.1 + 2.5 * 2 * math.pi / 0.6 + 0.1, abs=0.15)


def test_finishing_teaching_ends_a_spin(services: Services, robot: Robot) -> None:
    start_teaching(services)
    robot.frame()
    mark(services, "hall")
    robot.frame()
    services.teaching.finish("rover")
    assert services.control.public("rover").spin.state == "stopped"  # type: ignore[union-attr]
    assert isinstance(robot.frame(), schemas.IdleFrameResult)


def test_a_place_named_for_a_robot_that_does_not_stream_is_not_spun_at(
    services: Services, robot: Robot
) -> None:
    robot.frame(stream=False)  # idle: answered, but it is not the agent
    start_teaching(services)
    mark(services, "hall")
    assert services.control.public("rover").spin is None  # type: ignore[union-attr]


def taught_and_navigating(services: Services, robot: Robot) -> None:
    """Teach two places joined both ways by hand-driven frames, then go to one."""
    start_teaching(services)
    robot.frame()
    for name in ("a", "b", "a"):
        if name == "a" and services.teaching.state("rover").current_location is None:  # type: ignore[union-attr]
            spin_at(services, robot, name)
            continue
        teleop(services, 0.2, ttl=2.0)
        for _ in range(6):
            robot.frame()
        teleop(services, 0.0)
        robot.frame()
        if name == "b":
            spin_at(services, robot, name)
        else:
            mark(services, name)
    services.teaching.finish("rover")
    services.navigation.goto("rover", schemas.GotoRequest(location="b"))


def test_navigation_answers_as_before_and_refuses_teleop_until_halted(
    services: Services, robot: Robot
) -> None:
    taught_and_navigating(services, robot)
    result = robot.frame()
    assert isinstance(result, schemas.NavigationFrameResult)
    assert result.task is not None and result.task.state == "underway"
    assert result.command.ttl_s == services.navigation.params.motion.ttl_s
    with pytest.raises(Conflict, match="is navigating; stop it first"):
        teleop(services, 0.2)
    assert services.control.halt("rover") == ["task 1 to b (cancelled)"]
    # after the task the belief still tracks, and a person may drive it by hand
    teleop(services, 0.1)
    driven = robot.frame()
    assert isinstance(driven, schemas.NavigationFrameResult)
    assert driven.command.behaviour == "teleop" and driven.command.v == 0.1
    assert services.control.halt("rover") == ["driving by hand"]
    assert services.control.halt("rover") == []
