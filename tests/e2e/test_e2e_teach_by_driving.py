"""End to end: a tour taught entirely from the dashboard by driving a simulated robot, then
"go to" from the dashboard, in headless Chromium.

The real server (``teachrepeat serve`` with its dashboard) runs in its own process; the robot
agent (``teachrepeat robot run --driver sim``) runs in a thread of this one, in the two-room
home. The browser starts teaching a new tour, names the place where the robot stands (the
server spins the robot there), drives it to the other room with the keyboard and the
on-screen arrows, names that place, drives back and names the first again, finishes, then
picks the other place and presses Go, and the robot arrives there (judged with the
simulator's truth, which only this test reads: it steers as a person watching the robot
would).

``AGENT_SCREENSHOTS=DIR`` saves the walk-through's screenshots there (``make screenshot``:
docs/img, shown in docs/robot.md); otherwise they go to the test's temporary folder.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from playwright.sync_api import Error as PlaywrightError
from test_e2e_dashboard import chromium

from robot_client.agent import Agent, AgentParams, run_agent
from robot_client.client import TeachRepeatClient
from robot_client.drivers import sim as sim_driver
from robot_client.drivers.base import RobotIO
from robot_client.sim import SimulatedRobot, load_plan
from robot_client.trial import SUCCESS_RADIUS_M
from server.process import ServerProcess, start_server
from web.bench import headless_browser

PLAN = Path(__file__).resolve().parents[1] / "data" / "plans" / "two_rooms.json"
FIRST, SECOND = "desk", "sofa"  # the plan's places, named as the person teaching says them
SETTINGS = {"TEACHREPEAT_SPIN_W": "1.2"}
"""A quicker spin than the default 0.6 rad/s (one turn in 5 s, about 26 images a place)."""
TURN = 0.6  # rad/s, the dashboard's turn slider as it starts
SPEED = 0.25  # m/s, the dashboard's speed slider as it starts


HIDE = (
    "Object.defineProperty(document, 'hidden', {value: true, configurable: true});"
    "document.dispatchEvent(new Event('visibilitychange'))"
)
"""What a browser does when its tab is hidden (headless Chromium's never is)."""
SHOW = "delete document.hidden"
BLUR = "window.dispatchEvent(new Event('blur'))"


@dataclass
class RobotAgent:
    """The agent running in a thread, and the simulated robot it drives."""

    io: RobotIO
    agent: Agent
    thread: threading.Thread
    stopping: threading.Event
    lines: list[str]

    @property
    def robot(self) -> SimulatedRobot:
        camera = self.io.camera
        assert isinstance(camera, SimulatedRobot)
        return camera


@contextlib.contextmanager
def robot_agent(url: str, token: str) -> Iterator[RobotAgent]:
    """``teachrepeat robot run --driver sim --sim-plan two_rooms.json`` in a thread (the
    simulator is opened in that thread: its OpenGL context belongs to it)."""
    args = argparse.Namespace(
        sim_plan=PLAN,
        sim_condition="same",
        sim_seed=3,
        sim_start=FIRST,
        sim_pose=None,
        sim_speed=1.0,
    )
    ready: dict[str, Any] = {}
    lines: list[str] = []
    stopping = threading.Event()
    started = threading.Event()

    def run() -> None:
        io = sim_driver.open_robot(args)
        ready["io"] = io

        def hold(agent: Agent) -> None:
            ready["agent"] = agent
            started.set()

        try:
            params = AgentParams()
            run_agent(url, token, io, params, log=lines.append, ready=hold, stopping=stopping)
        finally:
            started.set()
            io.close()

    thread = threading.Thread(target=run, name="robot-agent", daemon=True)
    thread.start()
    assert started.wait(60), lines
    assert "agent" in ready, lines
    try:
        yield RobotAgent(ready["io"], ready["agent"], thread, stopping, lines)
    finally:
        stopping.set()
        thread.join(timeout=15)


def wait_for(
    what: str,
    check: Callable[[], bool],
    timeout_s: float,
    every_s: float = 0.1,
    *,
    seen: Callable[[], object] = lambda: None,
) -> None:
    """Wait until ``check()``; on timeout say what ``seen()`` shows."""
    deadline = time.monotonic() + timeout_s
    while not check():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}: {seen()}")
        time.sleep(every_s)


def bearing_error(robot: SimulatedRobot, x: float, y: float) -> float:
    p = robot.pose
    err = math.atan2(y - p.y, x - p.x) - p.theta
    return math.atan2(math.sin(err), math.cos(err))


def heading_error(robot: SimulatedRobot, yaw: float) -> float:
    err = yaw - robot.pose.theta
    return math.atan2(math.sin(err), math.cos(err))


def hold_key(page: Any, key: str, seconds: float) -> None:
    page.keyboard.down(key)
    time.sleep(seconds)
    page.keyboard.up(key)


def turn_to(page: Any, error: Callable[[], float], tol: float = 0.12) -> None:
    """Hold left or right until ``error()`` (rad) is within ``tol``, as a person would."""
    for _ in range(40):
        err = error()
        if abs(err) <= tol:
            return
        hold_key(page, "ArrowLeft" if err > 0 else "ArrowRight", min(1.5, 0.8 * abs(err) / TURN))
        time.sleep(0.3)  # let the last commands land before looking again
    raise AssertionError(f"could not turn: still {error():.2f} rad off")


def drive_to(
    page: Any,
    robot: SimulatedRobot,
    x: float,
    y: float,
    yaw: float,
    *,
    on_the_way: Callable[[], None] | None = None,
) -> None:
    """Drive the robot to ``(x, y)`` facing ``yaw`` with the keys: turn toward it, hold
    forward a stretch at a time, correct, and turn to face ``yaw`` at the end.
    ``on_the_way()`` is called once while forward is held (a screenshot)."""
    for _ in range(40):
        p = robot.pose
        distance = math.hypot(x - p.x, y - p.y)
        if distance <= 0.15:
            break
        turn_to(page, lambda: bearing_error(robot, x, y), tol=0.1 if distance > 0.5 else 0.2)
        seconds = min(6.0, 0.85 * distance / SPEED)
        page.keyboard.down("ArrowUp")
        started = time.monotonic()
        if on_the_way is not None and seconds > 3.0:
            time.sleep(1.0)
            on_the_way()
            on_the_way = None
        time.sleep(max(0.0, seconds - (time.monotonic() - started)))
        page.keyboard.up("ArrowUp")
        time.sleep(0.3)
    else:
        raise AssertionError(f"could not reach ({x}, {y}): at {robot.pose}")
    turn_to(page, lambda: heading_error(robot, yaw))


def close_notices(page: Any) -> None:
    """Close viser's notifications (its software-WebGL notice, our toasts) before a shot."""
    notices = page.locator(".mantine-Notification-closeButton")
    for _ in range(8):
        if notices.count() == 0:
            return
        with contextlib.suppress(PlaywrightError):  # may close by itself first
            notices.first.click(timeout=1000)
        page.wait_for_timeout(200)


def shot(page: Any, folder: Path, name: str, *, show: Any = None) -> None:
    """A screenshot of the page, with the left panel scrolled to ``show`` (a locator)."""
    close_notices(page)
    if show is not None:
        show.scroll_into_view_if_needed()
    page.wait_for_timeout(700)  # the next snapshot (5 Hz) with the camera
    folder.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(folder / name))


def wait_text(page: Any, text: str, timeout_ms: float = 10_000) -> None:
    """Wait until the page shows ``text`` (its rendered text, across elements)."""
    try:
        page.wait_for_function(
            "t => document.body.innerText.replace(/\\s+/g, ' ').includes(t)",
            arg=text,
            timeout=timeout_ms,
        )
    except PlaywrightError:
        shown = " ".join(page.locator("body").inner_text().split())
        raise AssertionError(f"the page never showed {text!r}; it shows: {shown[:1500]}") from None


def text_box(page: Any, label: str) -> Any:
    """A viser text input by its label (viser's labels name no input for the browser)."""
    xpath = f"//label[normalize-space(.)='{label}']/../../following-sibling::*[1]//input"
    return page.locator(f"xpath={xpath}")


def name_place(page: Any, name: str, *, new: bool = True) -> None:
    text_box(page, "Name this place").fill(name)
    page.wait_for_timeout(300)  # as a person moves to the button: the text reaches the server
    page.get_by_role("button", name="Mark", exact=True).click()
    wait_text(page, f"marked {'new' if new else 'known'} place {name}")
    page.evaluate("document.activeElement && document.activeElement.blur()")


@pytest.fixture()
def server(tmp_path: Path) -> Iterator[ServerProcess]:
    proc = start_server(tmp_path / "drive.sqlite", dashboard=True, extra_env=SETTINGS)
    yield proc
    proc.stop()


@pytest.mark.timeout(720)  # the steps' own timeouts say what failed well before this
def test_a_tour_taught_by_driving_from_the_dashboard_then_go_to_a_place(
    server: ServerProcess, tmp_path: Path
) -> None:
    executable = chromium()
    started = time.monotonic()

    def mark(what: str) -> None:
        print(f"{time.monotonic() - started:6.1f} s {what}")

    folder = Path(os.environ.get("AGENT_SCREENSHOTS") or tmp_path / "shots")
    plan = load_plan(PLAN)
    first, second = plan.place(FIRST), plan.place(SECOND)
    token = server.register_robot("rover")
    assert server.dashboard_url is not None
    with (
        TeachRepeatClient(server.url, token) as client,
        robot_agent(server.url, token) as ra,
        headless_browser(server.dashboard_url, executable=executable) as page,
    ):
        robot = ra.robot

        def state() -> Any:
            return client.state("rover")

        page.get_by_text("rover is idle").first.wait_for(timeout=30_000)
        page.get_by_role("button", name="◀ Left").wait_for(timeout=30_000)
        close_notices(page)

        # 1. driving from the dashboard: holding an arrow moves the robot, releasing stops it
        before = robot.pose.theta
        arrow = page.get_by_role("button", name="◀ Left")
        arrow.hover()
        page.mouse.down()
        wait_for("the robot to turn", lambda: abs(heading_error(robot, before)) > 0.3, 5.0)
        page.mouse.up()
        wait_for("the wheels to stop", lambda: robot._w == 0.0 and robot._v == 0.0, 1.0, 0.01)
        stopped_at = robot.pose.theta
        time.sleep(0.5)
        assert abs(heading_error(robot, stopped_at)) < 1e-9, "it turned on after the release"
        # the page hidden (another tab) with an arrow held, then the window losing focus with
        # a key held: the arrows are released and the robot stops
        for lose, hold in ((HIDE, "mouse"), (BLUR, "key")):
            before = robot.pose.theta
            if hold == "mouse":
                arrow.hover()
                page.mouse.down()
            else:
                page.keyboard.down("ArrowRight")
            wait_for("the robot to turn", lambda b=before: abs(heading_error(robot, b)) > 0.2, 5.0)
            page.evaluate(lose)
            wait_for(f"a stop after {hold} {lose!r}", lambda: robot._w == 0.0, 1.0, 0.01)
            if hold == "mouse":
                page.mouse.up()
            else:
                page.keyboard.up("ArrowRight")
            page.evaluate(SHOW)
        turn_to(page, lambda: heading_error(robot, first.yaw))  # back to the place's heading

        mark("drove by hand")
        # 2. start teaching a new tour from the dashboard, name the place where it stands
        text_box(page, "Tour to teach").fill("home")
        page.wait_for_timeout(300)
        page.get_by_role("button", name="Start teaching").click()
        wait_for("teaching", lambda: state().mode == "teaching", 10.0)
        name_place(page, FIRST)
        wait_for("the spin", lambda: spin_of(state()) == (FIRST, "done"), 30.0, 0.3, seen=state)
        spun = state().control.spin
        assert spun.images >= 20, spun

        mark("first place")
        # 3. drive to the other room with the keys, name the place there (the spin)
        arrows = page.get_by_role("button", name="▲ Forward")
        drive_to(
            page,
            robot,
            second.x,
            second.y,
            second.yaw,
            on_the_way=lambda: shot(page, folder, "robot_teach_drive.png", show=arrows),
        )
        name_place(page, SECOND)
        taught = robot.pose  # where the place was named: its spin turns on this spot
        wait_for("the spin", lambda: spin_of(state())[0] == SECOND, 5.0, seen=state)
        time.sleep(2.0)
        shot(page, folder, "robot_teach_spin.png")
        wait_for("the spin", lambda: spin_of(state()) == (SECOND, "done"), 30.0, 0.3, seen=state)
        teaching = state().teaching
        assert teaching is not None and teaching.edges == 1 and teaching.locations == 2

        mark("second place")
        # 4. drive back and name the first place again (a known place: no spin), finish
        drive_to(page, robot, first.x, first.y, first.yaw)
        name_place(page, FIRST, new=False)
        page.get_by_role("button", name="Finish").click()
        wait_text(page, "finished teaching")
        tour = client.tour_named("home")
        graph = client.tour(tour.id)
        assert sorted(loc.name for loc in graph.locations) == sorted((FIRST, SECOND))
        assert len(graph.edges) == 2 and all(e.image_count >= 20 for e in graph.edges), graph
        assert all(loc.image_count >= 20 for loc in graph.locations), graph.locations

        mark("back and finished")
        # 5. "go to" the other place from the dashboard: it arrives
        page.get_by_role("combobox", name="Goal").click()
        page.get_by_role("option", name=SECOND, exact=True).click()
        # the robot's clock runs twice as fast as the wall clock from here: navigation is
        # judged in its own (simulated) time, which stands still while it waits for answers
        clock = ra.io.clock
        assert isinstance(clock, sim_driver.SimClock)
        clock.speed = 2.0
        page.get_by_role("button", name="Go", exact=True).click()
        wait_for("the task", lambda: state().mode == "navigating", 60.0, 0.3)
        wait_for(
            "the task to end",
            lambda: state().mode != "navigating",
            480.0,  # about 40 s on a quiet machine; the suite runs beside other tests
            0.5,
        )
        mark("arrived")
        task = state().navigation.task
        p = robot.pose
        off = math.hypot(p.x - taught.x, p.y - taught.y)
        shot(page, folder, "robot_goto_arrived.png", show=page.get_by_text("arrived after").first)
    # what the robot did, to read a failure by: the place as taught, the task, the commands
    went = (f"{SECOND} taught at {taught}, arrived at {p}", task, ra.agent.stats, ra.lines[-10:])
    assert task is not None and task.state == "arrived", went
    assert off <= SUCCESS_RADIUS_M, (off, *went)
    assert not ra.agent.stats.late or ra.agent.stats.late < 10, ra.agent.stats
    # a guard against a hang, not a speed target
    assert time.monotonic() - started < 600


def spin_of(state: Any) -> tuple[str | None, str | None]:
    """(place, state) of the robot's spin under way or last."""
    control = state.control
    if control is None or control.spin is None:
        return None, None
    return control.spin.place, control.spin.state


def test_closing_the_page_while_driving_stops_the_robot(server: ServerProcess) -> None:
    """A browser that goes away mid-drive (closed, or its connection dropped): the robot
    stops at once when the dashboard sees the connection end, and by the hold's time-to-live
    (0.75 s) at the latest."""
    executable = chromium()
    token = server.register_robot("rover")
    assert server.dashboard_url is not None
    with (
        robot_agent(server.url, token) as ra,
        headless_browser(server.dashboard_url, executable=executable) as page,
    ):
        robot = ra.robot
        page.get_by_role("button", name="◀ Left").wait_for(timeout=30_000)
        before = robot.pose.theta
        page.keyboard.down("ArrowLeft")
        wait_for("the robot to turn", lambda: abs(heading_error(robot, before)) > 0.2, 5.0)
        closed = time.monotonic()
        page.close()
        wait_for("the wheels to stop", lambda: robot._w == 0.0, 2.0, 0.01)
        took = time.monotonic() - closed
        print(f"stopped {took * 1000:.0f} ms after the page closed")
        assert took <= 0.75 + 0.3 + 0.2  # the hold's ttl, the answer's, a frame
