"""``teachrepeat bench dashboard``: does a watching browser (or recording) slow the robots down?

One process runs the real API (uvicorn, in a thread) and the dashboard on the same services, as
``teachrepeat serve`` does. A robot is taught the 111 frames of ``corridor/ref`` through the robot
client, sent to a place, and streams the ``corridor/query`` frames at the camera rate while the
server's step latency (``StepRecord.step_ms``: features, similarities, belief, policy) and the
client's round trip are recorded. Blocks without and with a headless Chromium showing the
dashboard alternate (A B A B ...), so drift in machine load hits both equally. Target: the
medians differ by less than 5%.

``--compare recording`` alternates blocks whose navigation task is recorded (an MCAP file per
task, :mod:`server.recording`) with blocks whose task is not, no browser; besides the step and
the round trip it measures what the recorder does in the robot's request thread (its
``stepped``), the process's CPU per frame (the recorder's writer thread included) and the bytes
written per frame. Target: the round trip's median grows by at most 10%.

The helpers (:func:`start_live_server`, :func:`teach_corridor`, :class:`FrameStreamer`) are
shared with the end-to-end test of the dashboard.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from server.bench.common import corridor_marks, default_data_dir, stats, write_json

if TYPE_CHECKING:
    import uvicorn

    from robot_client.client import TeachRepeatClient
    from server.services.container import Services
    from web.dashboard import Dashboard


def _ends(marks: dict[int, str]) -> tuple[str, str]:
    """The corridor tour's last and first places (a robot sent back and forth between them)."""
    return marks[max(marks)], marks[min(marks)]


ADMIN_TOKEN = "bench-dashboard-admin"
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", type=Path, default=None, help="image data folder")
    parser.add_argument("--blocks", type=int, default=6, help="alternating blocks (default 6)")
    parser.add_argument("--frames", type=int, default=60, help="frames per block (default 60)")
    parser.add_argument("--fps", type=float, default=10.0, help="camera rate, frames/s")
    parser.add_argument("--chromium", default=CHROMIUM, help="Chromium executable")
    parser.add_argument(
        "--browser-nice",
        type=int,
        default=0,
        help="run Chromium at this niceness (e.g. 10 models a browser on another machine: "
        "on a small box its software WebGL rendering competes with the server for CPU)",
    )
    parser.add_argument(
        "--server-cpus",
        default=None,
        help="comma-separated CPUs for this process (API, dashboard, robot client), e.g. 0",
    )
    parser.add_argument(
        "--browser-cpus",
        default=None,
        help="comma-separated CPUs for Chromium, e.g. 1: with --server-cpus it models a browser "
        "on the user's own device, so only the server's cost of feeding a watcher is measured",
    )
    parser.add_argument(
        "--compare",
        choices=("browser", "recording"),
        default="browser",
        help="what alternates between blocks: a browser watching the dashboard (default), or "
        "recording the task to an MCAP file",
    )
    parser.add_argument("--json", type=Path, default=None, help="write the results here")


def _cpus(text: str | None) -> set[int] | None:
    return None if not text else {int(c) for c in text.split(",") if c.strip()}


# --- a live server in this process -----------------------------------------------------------


@dataclass
class LiveServer:
    """The API served by uvicorn in a thread, plus (optionally) the dashboard, in-process."""

    url: str
    services: Services
    server: uvicorn.Server
    thread: threading.Thread
    dashboard: Dashboard | None = None

    def stop(self) -> None:
        if self.dashboard is not None:
            self.dashboard.stop()
        self.server.should_exit = True
        self.thread.join(timeout=10)


def start_live_server(
    db: Path, *, dashboard: bool = True, admin_token: str = ADMIN_TOKEN
) -> LiveServer:
    """Serve a fresh app on a free port (and its dashboard on another) in this process."""
    import uvicorn
    from pydantic import SecretStr

    from server.app import create_app
    from server.config import Settings
    from server.serve import bind_port
    from web.dashboard import Dashboard

    settings = Settings(db=db, admin_token=SecretStr(admin_token), dashboard_port=None)
    app = create_app(settings)
    sock = bind_port("127.0.0.1", 0)
    port = sock.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", access_log=False))
    thread = threading.Thread(
        target=server.run, kwargs={"sockets": [sock]}, name="uvicorn", daemon=True
    )
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        if time.monotonic() > deadline or not thread.is_alive():
            raise RuntimeError("the API server did not start")
        time.sleep(0.02)
    live = LiveServer(f"http://127.0.0.1:{port}", app.state.services, server, thread)
    if dashboard:
        live.dashboard = Dashboard(live.services, port=0)
        live.dashboard.start()
    return live


def register(url: str, robot: str, *, admin_token: str = ADMIN_TOKEN) -> str:
    """A new robot's bearer token."""
    from robot_client.client import TeachRepeatClient

    with TeachRepeatClient(url, admin_token) as admin:
        return admin.register_robot(robot).token


def teach_corridor(client: TeachRepeatClient, data: Path, *, tour: str = "corridor") -> int:
    """Teach the corridor reference frames (4 places, 3 paths); returns the tour id."""
    from robot_client.teach import teach_folder

    report = teach_folder(
        client, tour=tour, frames=data / "corridor" / "ref", marks=corridor_marks(), progress=False
    )
    return report.tour.id


def query_frames(data: Path) -> list[bytes]:
    """The JPEG bytes of the corridor query frames, in order."""
    folder = data / "corridor" / "query"
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in (".jpg", ".jpeg"))
    if not files:
        raise FileNotFoundError(f"no query frames in {folder}")
    return [p.read_bytes() for p in files]


@dataclass
class FrameStreamer:
    """Streams frames as a navigating robot would, in a thread; re-sends one of ``goals``
    when a task ends so the robot keeps navigating (none: never). ``round_trips_ms`` grows as
    frames are answered."""

    client: TeachRepeatClient
    robot: str
    frames: list[bytes]
    fps: float = 10.0
    goals: tuple[str, ...] = field(default_factory=lambda: _ends(corridor_marks()))
    record: bool | None = None  # the gotos ask for recording (None: the server decides)
    round_trips_ms: list[float] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    sent: int = 0
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None
    _clock: float = 0.0

    def send(self, n: int) -> list[float]:
        """Send ``n`` frames at ``fps`` from the calling thread; their round trips (ms)."""
        from robot_client.client import ApiError
        from server import schemas

        out: list[float] = []
        period = 1.0 / self.fps
        next_at = time.perf_counter()
        for _ in range(n):
            if self._stop.is_set():
                break
            jpeg = self.frames[self.sent % len(self.frames)]
            self._clock += period
            started = time.perf_counter()
            try:
                result = self.client.upload_frame(self.robot, jpeg, timestamp=self._clock, v=0.3)
            except ApiError as exc:
                self.errors.append(str(exc))
                continue
            out.append((time.perf_counter() - started) * 1000.0)
            self.sent += 1
            task = getattr(result, "task", None)
            if (
                self.goals
                and isinstance(result, schemas.NavigationFrameResult)
                and (task is None or task.state != "underway")
            ):
                goal = self.goals[self.sent % len(self.goals)]
                self.client.goto(self.robot, goal, record=self.record)
            next_at += period
            delay = next_at - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            else:
                next_at = time.perf_counter()
        self.round_trips_ms.extend(out)
        return out

    def start(self) -> None:
        """Stream until :meth:`stop`, in a background thread."""

        def loop() -> None:
            while not self._stop.is_set():
                self.send(10)

        self._thread = threading.Thread(target=loop, name="frame-streamer", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)


@contextlib.contextmanager
def headless_browser(url: str, *, executable: str = CHROMIUM) -> Iterator[Any]:
    """A headless Chromium page showing ``url`` (fresh temporary profile)."""
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as profile, sync_playwright() as pw:
        context = pw.chromium.launch_persistent_context(
            profile,
            executable_path=executable,
            headless=True,
            args=CHROMIUM_ARGS,
            viewport={"width": 1600, "height": 900},
        )
        try:
            page = context.pages[0] if context.pages else context.new_page()
            page.goto(url)
            yield page
        finally:
            context.close()


def descendants() -> set[int]:
    """Process ids of every descendant of this process (the browser and its helpers). Linux
    only (reads /proc); empty elsewhere."""
    if not Path("/proc").is_dir():
        return set()
    parents: dict[int, int] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError, ValueError, IndexError):
            fields = stat.read_text().rsplit(")", 1)[1].split()
            parents[int(stat.parent.name)] = int(fields[1])
    mine = {os.getpid()}
    changed = True
    while changed:
        kids = {pid for pid, ppid in parents.items() if ppid in mine and pid not in mine}
        changed = bool(kids)
        mine |= kids
    mine.discard(os.getpid())
    return mine


def renice_descendants(niceness: int) -> int:
    """Set the niceness of every descendant process of this one (the browser); returns how
    many were changed. A no-op for ``niceness`` 0."""
    if niceness == 0:
        return 0
    done = 0
    for pid in descendants():
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, pid, niceness)
            done += 1
    return done


def pin_descendants(cpus: set[int] | None) -> int:
    """Restrict every thread of every descendant process to ``cpus``; returns how many threads
    were pinned (affinity is per thread on Linux). A no-op for ``None``."""
    if not cpus:
        return 0
    done = 0
    for pid in descendants():
        tasks = Path(f"/proc/{pid}/task")
        tids = [int(t.name) for t in tasks.iterdir()] if tasks.is_dir() else [pid]
        for tid in tids:
            with contextlib.suppress(OSError):
                os.sched_setaffinity(tid, cpus)
                done += 1
    return done


def step_times(services: Services, robot: str, since: float) -> list[float]:
    """Server step latencies (ms) of ``robot`` for frames with robot time > ``since``."""
    session = services.navigation.sessions().get(robot)
    if session is None:
        return []
    return [r.step_ms for r in list(session.history) if r.timestamp > since]


# --- the benchmark ---------------------------------------------------------------------------


def run(args: argparse.Namespace) -> int:
    from robot_client.client import TeachRepeatClient

    data = args.data or default_data_dir()
    if not (data / "corridor" / "ref").is_dir():
        print(f"no corridor frames under {data}; pass --data DIR")
        return 2
    if not Path(args.chromium).exists():
        print(f"no Chromium at {args.chromium}; pass --chromium PATH")
        return 2
    server_cpus = _cpus(args.server_cpus)
    if server_cpus:
        os.sched_setaffinity(0, server_cpus)  # threads started from now on inherit it
    recording = args.compare == "recording"
    with tempfile.TemporaryDirectory() as tmp:
        live = start_live_server(Path(tmp) / "bench.sqlite", dashboard=not recording)
        try:
            print(
                f"API {live.url}" + (f", dashboard {live.dashboard.url}" if live.dashboard else "")
            )
            token = register(live.url, "bench")
            with TeachRepeatClient(live.url, token) as client:
                teach_corridor(client, data)
                client.goto("bench", _ends(corridor_marks())[0])
                streamer = FrameStreamer(client, "bench", query_frames(data), fps=args.fps)
                streamer.send(30)  # warm-up: runtime built, caches hot
                if recording:
                    result = _alternate_recording(live, client, streamer, args)
                else:
                    result = _alternate(live, streamer, args)
        finally:
            live.stop()
    write_json(args.json, result)
    return 0


def _alternate(
    live: LiveServer, streamer: FrameStreamer, args: argparse.Namespace
) -> dict[str, Any]:
    assert live.dashboard is not None
    steps: dict[str, list[float]] = {"without": [], "with": []}
    trips: dict[str, list[float]] = {"without": [], "with": []}
    for block in range(args.blocks):
        mode = "without" if block % 2 == 0 else "with"
        since = streamer._clock
        if mode == "with":
            with headless_browser(live.dashboard.url, executable=args.chromium) as page:
                page.wait_for_selector("canvas", timeout=30_000)
                renice_descendants(args.browser_nice)
                browser_cpus = _cpus(args.browser_cpus)
                pin_descendants(browser_cpus)
                page.wait_for_timeout(1000)  # the scene and images have arrived
                pin_descendants(browser_cpus)  # threads started since
                clients = len(live.dashboard.server.get_clients()) if live.dashboard.server else 0
                trips[mode] += streamer.send(args.frames)
        else:
            clients = 0
            trips[mode] += streamer.send(args.frames)
        block_steps = step_times(live.services, streamer.robot, since)
        steps[mode] += block_steps
        s = stats(block_steps)
        print(
            f"block {block + 1}/{args.blocks} {mode:>7} browser ({clients} clients): "
            f"step median {s['p50']:.1f} ms, p95 {s['p95']:.1f} ms"
        )
    a, b = stats(steps["without"]), stats(steps["with"])
    publish = stats(list(live.dashboard.publisher.publish_ms))
    ta, tb = stats(trips["without"]), stats(trips["with"])
    ratio = b["p50"] / a["p50"]
    print(
        f"server step without browser: median {a['p50']:.1f} ms, p95 {a['p95']:.1f} ms "
        f"(n={a['n']})\n"
        f"server step with browser:    median {b['p50']:.1f} ms, p95 {b['p95']:.1f} ms "
        f"(n={b['n']})\n"
        f"ratio of medians {ratio:.3f} ({(ratio - 1) * 100:+.1f}%; target within 5%)\n"
        f"client round trip: median {ta['p50']:.1f} ms without, {tb['p50']:.1f} ms with\n"
        f"dashboard snapshot + render: median {publish['p50']:.1f} ms, p95 "
        f"{publish['p95']:.1f} ms, at most {1 / live.dashboard.publisher.period_s:.0f} per s"
    )
    return {
        "what": "server step latency (StepRecord.step_ms) of a navigating robot streaming the "
        "corridor query frames, without / with a headless Chromium showing the dashboard",
        "fps": args.fps,
        "browser_nice": args.browser_nice,
        "server_cpus": args.server_cpus,
        "browser_cpus": args.browser_cpus,
        "blocks": args.blocks,
        "frames_per_block": args.frames,
        "step_ms_without_browser": a,
        "step_ms_with_browser": b,
        "round_trip_ms_without_browser": ta,
        "round_trip_ms_with_browser": tb,
        "publish_ms": publish,
        "ratio_median": ratio,
        "ratio_p95": b["p95"] / a["p95"],
        "within_5_percent": abs(ratio - 1.0) < 0.05,
        "cpus": os.cpu_count(),
        "errors": streamer.errors[:10],
    }


def _alternate_recording(
    live: LiveServer, client: TeachRepeatClient, streamer: FrameStreamer, args: argparse.Namespace
) -> dict[str, Any]:
    """Blocks off / on: each starts a task to the corridor's far end, recorded or not, and
    streams the same frames (the first ``--frames`` query frames)."""
    recorder = live.services.recordings
    hook_ms: list[float] = []
    stepped = recorder.stepped

    def timed(*a: Any, **kw: Any) -> None:  # the recorder's work in the request thread
        started = time.perf_counter()
        stepped(*a, **kw)
        hook_ms.append((time.perf_counter() - started) * 1000.0)

    recorder.stepped = timed  # type: ignore[method-assign]
    modes = ("off", "on")
    steps: dict[str, list[float]] = {m: [] for m in modes}
    trips: dict[str, list[float]] = {m: [] for m in modes}
    cpu: dict[str, list[float]] = {m: [] for m in modes}
    for block in range(args.blocks):
        mode = modes[block % 2]
        recorder.wait_idle()  # the last block's file finished before this block is timed
        streamer.record = mode == "on"
        client.goto(streamer.robot, _ends(corridor_marks())[0], record=streamer.record)
        streamer.sent = 0  # every block streams the same frames from a fresh task
        since = streamer._clock
        cpu0 = time.process_time()
        sent = streamer.send(args.frames)
        cpu[mode].append((time.process_time() - cpu0) * 1000.0 / max(1, len(sent)))
        trips[mode] += sent
        block_steps = step_times(live.services, streamer.robot, since)
        steps[mode] += block_steps
        s = stats(sent)
        print(
            f"block {block + 1}/{args.blocks} recording {mode:>3}: round trip median "
            f"{s['p50']:.1f} ms, p95 {s['p95']:.1f} ms"
        )
    client.stop(streamer.robot)
    recorder.wait_idle()
    writer_ms = recorder.writer_cpu_s * 1000.0 / max(1, len(trips["on"]))
    files = recorder.store.files()
    written = sum(f.size_bytes for f in files)
    frames_on = len(trips["on"])
    a, b = stats(trips["off"]), stats(trips["on"])
    sa, sb = stats(steps["off"]), stats(steps["on"])
    hook = stats(hook_ms)
    cpu_off, cpu_on = float(np.median(cpu["off"])), float(np.median(cpu["on"]))
    ratio = b["p50"] / a["p50"]
    print(
        f"round trip, recording off: median {a['p50']:.2f} ms, p95 {a['p95']:.2f} ms (n={a['n']})\n"
        f"round trip, recording on:  median {b['p50']:.2f} ms, p95 {b['p95']:.2f} ms (n={b['n']})\n"
        f"ratio of medians {ratio:.3f} ({(ratio - 1) * 100:+.1f}%; target at most +10%)\n"
        f"server step (StepRecord.step_ms): median {sa['p50']:.2f} ms off, {sb['p50']:.2f} ms on\n"
        f"recorder in the request thread: median {hook['p50']:.3f} ms, p95 {hook['p95']:.3f} ms "
        f"per frame ({hook['p50'] / sa['p50'] * 100:.1f}% of the step's median)\n"
        f"recorder's writer thread: {writer_ms:.3f} ms of CPU per recorded frame\n"
        f"process CPU per frame (clients, server, writer): median of blocks {cpu_off:.2f} ms off, "
        f"{cpu_on:.2f} ms on (x{cpu_on / cpu_off:.3f})\n"
        f"written: {len(files)} files, {written / 1e6:.1f} MB, "
        f"{written / max(1, frames_on) / 1e3:.1f} kB per recorded frame"
    )
    return {
        "what": "client round trip and server step of a navigating robot streaming the corridor "
        "query frames, blocks whose task is recorded (MCAP) alternating with blocks whose is not",
        "fps": args.fps,
        "blocks": args.blocks,
        "frames_per_block": args.frames,
        "round_trip_ms_off": a,
        "round_trip_ms_on": b,
        "step_ms_off": sa,
        "step_ms_on": sb,
        "recorder_request_thread_ms": hook,
        "recorder_writer_cpu_ms_per_frame": writer_ms,
        "cpu_ms_per_frame_off": cpu_off,
        "cpu_ms_per_frame_on": cpu_on,
        "ratio_median": ratio,
        "ratio_p95": b["p95"] / a["p95"],
        "within_10_percent": ratio <= 1.10,
        "bytes_per_recorded_frame": written / max(1, frames_on),
        "files": len(files),
        "cpus": os.cpu_count(),
        "errors": streamer.errors[:10],
    }
