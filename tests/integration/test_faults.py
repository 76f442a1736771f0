"""Faults: a server killed mid-navigation, a robot gone silent, a server that stops answering,
a full disk and a read-only database.

The process tests run the real server (``teachrepeat serve``) on a copy of one database taught
once per module from the real corridor frames, so each test pays for a server start, not for
teaching.
"""

from __future__ import annotations

import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from conftest import Api, make_jpeg

from robot_client.client import TeachRepeatClient
from robot_client.guide import teach_route
from robot_client.navigate import LoopParams, drive
from robot_client.sim import SimulatedRobot, SimWorld, load_plan
from robot_client.sim.world import Pose
from robot_client.teach import teach_folder
from robot_client.trial import SUCCESS_RADIUS_M, run_trial
from server import schemas
from server.navigation import NavigationParams
from server.process import ADMIN, ServerProcess, start_server
from server.services.navigation import BELIEF_SNAPSHOT_S
from server.storage.repo import Repo

MARKS = {0: "entry", 36: "hall", 73: "office", 110: "kitchen"}
JPEG = {"Content-Type": "image/jpeg"}
SERVE = [sys.executable, "-m", "server.cli", "serve"]


# --- a taught database, copied for each test --------------------------------------------------


@dataclass(frozen=True)
class Taught:
    """A database file with the corridor tour taught and robot ``rover`` registered."""

    db: Path
    token: str
    queries: list[bytes]


@pytest.fixture(scope="module")
def taught_template(shared_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Taught:
    db = tmp_path_factory.mktemp("taught") / "taught.sqlite"
    server = start_server(db)
    try:
        with TeachRepeatClient(server.url, ADMIN) as admin:
            teacher = admin.register_robot("teacher").token
            token = admin.register_robot("rover").token
        with TeachRepeatClient(server.url, teacher) as client:
            teach_folder(
                client,
                tour="corridor",
                frames=shared_data / "corridor" / "ref",
                marks=MARKS,
                progress=False,
            )
            client.goto("teacher", "kitchen")  # prepares the tour: features, weights stored
            client.stop("teacher")
    finally:
        server.stop()
    queries = [p.read_bytes() for p in sorted((shared_data / "corridor" / "query").glob("*.jpg"))]
    return Taught(db, token, queries)


@pytest.fixture()
def taught(taught_template: Taught, tmp_path: Path) -> Taught:
    """A private copy of the taught database."""
    db = tmp_path / "nav.sqlite"
    for suffix in ("", "-wal"):
        src = Path(str(taught_template.db) + suffix)
        if src.exists():
            shutil.copyfile(src, str(db) + suffix)
    return Taught(db, taught_template.token, taught_template.queries)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def serve_on(db: Path, port: int) -> ServerProcess:
    """``teachrepeat serve`` on a fixed port (a restart keeps the URL the robot knows)."""
    env = {**os.environ, "TEACHREPEAT_ADMIN_TOKEN": ADMIN}
    env.pop("TEACHREPEAT_DB", None)
    proc = subprocess.Popen(
        [*SERVE, "--db", str(db), "--port", str(port), "--dashboard-port", "-1"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        text=True,
        env=env,
        cwd=Path(__file__).resolve().parents[2],
    )
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"{url}/health", timeout=1).status_code == 200:
                return ServerProcess(proc, url, db)
        except httpx.TransportError:
            time.sleep(0.05)
    proc.kill()
    raise RuntimeError("the restarted server never answered /health")


@pytest.fixture()
def cleanup() -> Iterator[list[ServerProcess]]:
    """Servers a test started; stopped (and resumed if paused) at the end."""
    servers: list[ServerProcess] = []
    yield servers
    for s in servers:
        if s.proc.poll() is None:
            s.proc.send_signal(signal.SIGCONT)
        s.stop()


def navigate_frames(
    client: TeachRepeatClient, queries: list[bytes], start: int, n: int, t0: float
) -> schemas.NavigationFrameResult:
    last = None
    for k in range(n):
        result = client.upload_frame(
            "rover", queries[(start + k) % len(queries)], timestamp=t0 + k / 10, v=0.3
        )
        assert isinstance(result, schemas.NavigationFrameResult)
        last = result
    assert last is not None
    return last


# --- SIGKILL during navigation ------------------------------------------------------------


def test_sigkill_while_frames_stream_leaves_a_consistent_file(
    taught: Taught, cleanup: list[ServerProcess]
) -> None:
    server = start_server(taught.db)
    cleanup.append(server)
    client = TeachRepeatClient(server.url, taught.token)
    client.goto("rover", "kitchen")
    navigate_frames(client, taught.queries, 0, 5, 0.0)
    failures: list[BaseException] = []
    answered = threading.Event()

    def stream() -> None:
        k = 5
        while True:
            try:
                navigate_frames(client, taught.queries, k, 1, k / 10)
            except Exception as exc:  # the server is being killed
                failures.append(exc)
                return
            answered.set()
            k += 1

    worker = threading.Thread(target=stream)
    worker.start()
    assert answered.wait(30)
    time.sleep(BELIEF_SNAPSHOT_S + 0.2)  # at least one more snapshot written while streaming
    server.kill()
    worker.join(timeout=15)
    client.close()
    assert failures and isinstance(failures[0], httpx.TransportError)

    repo = Repo(taught.db)
    try:
        assert repo.integrity_ok()
        assert repo.short_edges() == []
        row = repo.navigation("rover")
        assert row is not None and row.state == "underway" and row.belief is not None
        belief = np.frombuffer(row.belief, dtype=np.float32)
        assert np.all(np.isfinite(belief)) and belief.sum() == pytest.approx(1.0, abs=1e-3)
    finally:
        repo.close()


def test_navigation_resumes_after_sigkill_from_the_persisted_belief(
    taught: Taught, cleanup: list[ServerProcess]
) -> None:
    port = free_port()
    server = serve_on(taught.db, port)
    cleanup.append(server)
    client = TeachRepeatClient(server.url, taught.token, retries=6, backoff_s=0.2)
    task = client.goto("rover", "kitchen")
    navigate_frames(client, taught.queries, 0, 25, 0.0)  # robot time 0.0-2.4 s
    # the next frame's belief is persisted: a snapshot is due a second of robot time after the last
    before = navigate_frames(client, taught.queries, 25, 1, 2.4 + BELIEF_SNAPSHOT_S)
    assert before.task is not None and before.task.state == "underway"
    server.kill()

    # the robot keeps trying while the server restarts on the same file and port
    restarted: list[ServerProcess] = []

    def restart() -> None:
        time.sleep(0.5)
        restarted.append(serve_on(taught.db, port))

    restarter = threading.Thread(target=restart)
    restarter.start()
    started = time.monotonic()
    state = client.state("rover")  # the first attempts fail: connection refused
    waited = time.monotonic() - started
    restarter.join(timeout=30)
    cleanup.extend(restarted)
    assert waited >= 0.5, "the client answered before the server was back"

    assert state.mode == "navigating"
    nav = state.navigation
    assert nav is not None and nav.task is not None
    assert (nav.task.id, nav.task.state, nav.task.goal) == (task.id, "underway", "kitchen")
    assert nav.belief is not None and before.belief.top
    top_after = [(s.kind, s.name) for s in nav.belief.top]
    top_before = [(s.kind, s.name) for s in before.belief.top]
    assert top_after[0] == top_before[0], (top_before, top_after)
    assert nav.belief.top[0].probability == pytest.approx(
        before.belief.top[0].probability, rel=1e-4
    )
    # and frames are answered with commands again
    after = navigate_frames(client, taught.queries, 26, 3, 2.6)
    assert after.command.ttl_s > 0 and after.task is not None
    assert after.task.id == task.id
    client.close()
    repo = Repo(taught.db)
    try:
        assert repo.integrity_ok() and repo.short_edges() == []
    finally:
        repo.close()


def test_the_first_frame_of_a_task_reports_no_motion_from_before_it(
    taught: Taught, cleanup: list[ServerProcess]
) -> None:
    """Wheel odometry counts since its last reading: what the robot drove before a task (the
    end of the task before, a push by hand) must not reach the first frame of this one."""
    server = start_server(taught.db)
    cleanup.append(server)
    sent: list[tuple[float, float]] = []
    with (
        SimWorld(load_plan(), condition="same", seed=0) as world,
        TeachRepeatClient(server.url, taught.token) as client,
    ):
        robot = SimulatedRobot(world, Pose(6.8, 4.75, 0.0), seed=0)
        robot.command(0.3, 0.5)  # driven, never read
        robot.sleep(0.1)
        robot.stop()
        upload = client.upload_frame

        def spy(*args: Any, **kwargs: Any) -> Any:
            sent.append((kwargs["v"], kwargs["w"]))
            return upload(*args, **kwargs)

        client.upload_frame = spy  # type: ignore[method-assign]
        client.goto("rover", "kitchen")
        drive(
            client,
            "rover",
            camera=LoopCamera(taught.queries),
            motors=robot,
            clock=robot,
            params=LoopParams(max_steps=3, wait_for_answer=True),
        )
    assert len(sent) == 3
    assert sent[0] == (0.0, 0.0)


@pytest.mark.slow
def test_a_robot_whose_server_is_killed_mid_task_still_arrives(
    tmp_path: Path, cleanup: list[ServerProcess]
) -> None:
    """The closed loop through a crash: the simulated robot is sent to a place, the server is
    SIGKILLed mid-way and restarted on the same file and port; the robot's loop waits (its
    client retries with backoff, the motors stop), the task goes on from the persisted belief,
    and the robot arrives where the place really is."""
    db, port = tmp_path / "crash.sqlite", free_port()
    cleanup.append(serve_on(db, port))
    url = f"http://127.0.0.1:{port}"
    with TeachRepeatClient(url, ADMIN) as admin:
        token = admin.register_robot("sim").token
    plan = load_plan()
    killed: list[tuple[int, schemas.TaskPublic | None]] = []

    def crash(step: int, result: schemas.NavigationFrameResult) -> None:
        if step == 40 and not killed:  # the belief persisted last is up to a robot second old
            killed.append((step, result.task))
            cleanup[0].kill()

            def restart() -> None:
                time.sleep(0.5)
                cleanup.append(serve_on(db, port))

            threading.Thread(target=restart, daemon=True).start()

    with (
        TeachRepeatClient(url, token, retries=8, backoff_s=0.2) as client,
        SimWorld(plan, condition="same", seed=1) as world,
    ):
        robot = SimulatedRobot(world, Pose(6.8, 4.75, 0.0), seed=1)
        teach_route(
            client, "sim", robot, plan, tour="three", route=("hall", "bathroom", "hall", "office")
        )
        robot.teleport(Pose(6.0, 4.75, math.pi))
        result = run_trial(client, "sim", robot, plan, "office", max_steps=900, on_step=crash)
        state = client.state("sim")
    assert killed and len(cleanup) == 2, "the server was not killed and restarted"
    assert result.steps > 40 and cleanup[1].proc.poll() is None
    assert result.state == "arrived", result
    assert result.distance_m <= SUCCESS_RADIUS_M and not result.wrong_arrival, result
    task = killed[0][1]
    assert state.navigation is not None and state.navigation.task is not None and task
    assert state.navigation.task.id == task.id  # the same task, resumed, not a new one


@pytest.mark.slow
def test_a_silent_robot_has_its_task_failed_after_the_timeout(
    taught: Taught, cleanup: list[ServerProcess]
) -> None:
    server = start_server(taught.db)
    cleanup.append(server)
    timeout = NavigationParams().frame_timeout_s
    with TeachRepeatClient(server.url, taught.token) as client:
        client.goto("rover", "kitchen")
        navigate_frames(client, taught.queries, 0, 3, 0.0)
        silent_from = time.monotonic()
        time.sleep(timeout - 1.5)
        assert client.state("rover").mode == "navigating"  # not failed too early
        task = None
        while time.monotonic() - silent_from < timeout + 5:
            nav = client.state("rover").navigation
            task = None if nav is None else nav.task
            if task is not None and task.state != "underway":
                break
            time.sleep(0.25)
        failed_after = time.monotonic() - silent_from
    assert task is not None and task.state == "failed", task
    assert task.reason is not None and "timeout" in task.reason
    assert timeout <= failed_after <= timeout + 2.5  # the sweep runs every second
    repo = Repo(taught.db)
    try:
        row = repo.navigation("rover")
        assert row is not None and row.state == "failed"  # persisted, survives a restart
    finally:
        repo.close()


# --- the robot loop against a server that goes away ----------------------------------------


@dataclass
class FakeClock:
    """Robot time: ``sleep`` advances it at once (no real waiting)."""

    t: float = 0.0

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += seconds


@dataclass
class WallClock:
    """Real time, for a server that hangs (the wait happens inside the HTTP call)."""

    t0: float = field(default_factory=time.monotonic)

    def now(self) -> float:
        return time.monotonic() - self.t0

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)


@dataclass
class FakeMotors:
    """Records ``(time, v, w)`` for every command and stop (a stop is ``(t, 0, 0)``)."""

    clock: FakeClock | WallClock
    events: list[tuple[float, float, float]] = field(default_factory=list)

    def command(self, v: float, w: float) -> None:
        self.events.append((self.clock.now(), v, w))

    def odometry(self) -> tuple[float, float]:
        return (self.events[-1][1], self.events[-1][2]) if self.events else (0.0, 0.0)

    def stop(self) -> None:
        self.events.append((self.clock.now(), 0.0, 0.0))

    def longest_drive(self, end: float) -> float:
        """Longest time a non-zero command stayed in force (until the next event or ``end``)."""
        longest = 0.0
        for k, (t, v, w) in enumerate(self.events):
            if v == 0.0 and w == 0.0:
                continue
            until = self.events[k + 1][0] if k + 1 < len(self.events) else end
            longest = max(longest, until - t)
        return longest


@dataclass
class LoopCamera:
    """The corridor query frames, decoded, for ever."""

    frames: list[bytes]
    k: int = 0

    def read(self) -> np.ndarray:
        import cv2

        data = self.frames[self.k % len(self.frames)]
        self.k += 1
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        return np.asarray(image, np.uint8)

    def close(self) -> None:
        pass


@pytest.mark.parametrize("period_s", [0.1, 1.0], ids=["period-under-ttl", "period-over-ttl"])
def test_robot_stops_when_the_server_dies_mid_run(
    taught: Taught, cleanup: list[ServerProcess], period_s: float
) -> None:
    server = start_server(taught.db)
    cleanup.append(server)
    clock = FakeClock()
    motors = FakeMotors(clock)
    ttl = NavigationParams().motion.ttl_s
    with TeachRepeatClient(server.url, taught.token) as client:
        client.goto("rover", "kitchen")

        def kill_at_step(step: int, result: schemas.NavigationFrameResult) -> None:
            if step == 15:
                server.kill()

        params = LoopParams(period_s=period_s, max_retry_total_s=5.0)
        with pytest.raises(httpx.TransportError):
            drive(
                client,
                "rover",
                camera=LoopCamera(taught.queries),
                motors=motors,
                clock=clock,
                params=params,
                on_step=kill_at_step,
            )
    moving = [e for e in motors.events if e[1] != 0.0 or e[2] != 0.0]
    assert moving, "the robot never got a command to move; the test proves nothing"
    assert motors.events[-1][1:] == (0.0, 0.0), "the motors were left running"
    assert motors.longest_drive(clock.now()) <= ttl + 1e-9


def test_robot_stops_within_ttl_when_the_server_hangs(
    taught: Taught, cleanup: list[ServerProcess]
) -> None:
    server = start_server(taught.db)
    cleanup.append(server)
    clock = WallClock()
    motors = FakeMotors(clock)
    ttl = NavigationParams().motion.ttl_s
    with TeachRepeatClient(server.url, taught.token, timeout_s=2.0) as client:
        client.goto("rover", "kitchen")
        paused: list[float] = []

        def pause_at_step(step: int, result: schemas.NavigationFrameResult) -> None:
            if step == 10:
                server.proc.send_signal(signal.SIGSTOP)  # alive, but answers nothing
                paused.append(clock.now())

        with pytest.raises(httpx.TransportError):
            drive(
                client,
                "rover",
                camera=LoopCamera(taught.queries),
                motors=motors,
                clock=clock,
                params=LoopParams(max_retry_total_s=0.1),
                on_step=pause_at_step,
            )
    server.proc.send_signal(signal.SIGCONT)
    assert paused and any(v != 0.0 for _, v, _ in motors.events)
    assert motors.events[-1][1:] == (0.0, 0.0)
    assert motors.longest_drive(clock.now()) <= ttl + 0.2


# --- storage faults, in-process --------------------------------------------------------------


def start_teaching(api: Api) -> dict[str, str]:
    robot = api.register()
    tour = api.client.post("/tours", json={"name": "t"}, headers=robot).json()["id"]
    assert api.client.post(
        "/robots/rover/teach/start", json={"tour": tour}, headers=robot
    ).is_success
    assert api.client.post(
        "/robots/rover/teach/locations", json={"name": "a"}, headers=robot
    ).is_success
    return robot


def post_frame(api: Api, robot: dict[str, str], seed: int, t: float) -> httpx.Response:
    return api.client.post(
        "/robots/rover/frames",
        params={"timestamp": t, "v": 0.2},
        content=make_jpeg(seed, 320, 240),
        headers={**robot, **JPEG},
    )


def test_disk_full_answers_503_and_keeps_the_file_whole(api: Api) -> None:
    robot = start_teaching(api)
    for k in range(3):
        assert post_frame(api, robot, k, k / 10).status_code == 200
    conn = api.client.app.state.services.repo.db.conn
    pages = conn.execute("PRAGMA page_count").fetchone()[0]
    conn.execute(f"PRAGMA max_page_count = {pages}")  # the disk is full from now on
    before = api.dump()
    r = post_frame(api, robot, 10, 1.0)
    assert r.status_code == 503, r.text
    assert r.json()["code"] == "unavailable" and "full" in r.json()["detail"]
    r = api.client.post("/robots/rover/teach/locations", json={"name": "b"}, headers=robot)
    assert r.status_code in (200, 503), r.text  # may still fit in the free pages
    if r.status_code == 503:
        assert "full" in r.json()["detail"]
        assert api.dump() == before
    assert api.client.get("/tours", headers=robot).status_code == 200  # reads still work
    # space is freed: the same robot goes on, nothing half-written is left behind
    conn.execute("PRAGMA max_page_count = 1073741823")
    if r.status_code == 503:
        assert post_frame(api, robot, 11, 1.1).status_code == 200
        assert post_frame(api, robot, 12, 1.2).status_code == 200
        r = api.client.post("/robots/rover/teach/locations", json={"name": "b"}, headers=robot)
        assert r.status_code == 200, r.text
        assert r.json()["edge"]["image_count"] == 5  # 3 before + 2 after, none of the refused
    repo = Repo(api.db_path)
    try:
        assert repo.integrity_ok() and repo.short_edges() == []
    finally:
        repo.close()


def test_read_only_database_answers_503_and_keeps_the_file_whole(api: Api) -> None:
    robot = start_teaching(api)
    assert post_frame(api, robot, 0, 0.0).status_code == 200
    conn = api.client.app.state.services.repo.db.conn
    conn.execute("PRAGMA query_only = ON")  # as a read-only file or mount would behave
    before = api.dump()
    for request in (
        lambda: post_frame(api, robot, 1, 0.1),
        lambda: api.client.post("/robots/rover/teach/locations", json={"name": "b"}, headers=robot),
        lambda: api.client.post("/tours", json={"name": "other"}, headers=robot),
        lambda: api.client.post("/robots", json={"name": "second"}, headers=api.admin),
    ):
        r = request()
        assert r.status_code == 503, r.text
        assert r.json()["code"] == "unavailable" and "read-only" in r.json()["detail"]
    # reads go on, also those that need a consistent snapshot of several tables
    assert api.client.get("/tours", headers=robot).status_code == 200
    r = api.client.get("/robots/rover/state", headers=robot)
    assert r.status_code == 200, r.text
    assert r.json()["teaching"]["open_path_images"] == 1
    tour = r.json()["teaching"]["tour"]
    r = api.client.get(f"/tours/{tour}", headers=robot)
    assert r.status_code == 200, r.text
    assert [loc["name"] for loc in r.json()["locations"]] == ["a"]
    conn.execute("PRAGMA query_only = OFF")
    assert api.dump() == before
    assert post_frame(api, robot, 2, 0.2).status_code == 200
    repo = Repo(api.db_path)
    try:
        assert repo.integrity_ok() and repo.short_edges() == []
    finally:
        repo.close()
