"""Run many closed-loop navigation trials, in one process or several, with the same outcomes.

A trial depends only on the code, the plan, the seed, the condition and its own number:

* its start pose, goal and noise are drawn from ``(seed, trial)`` alone
  (:func:`robot_client.trial.draw_trial`), the same for every condition of a plan;
* it runs with a robot registered for it alone (a fresh session on the server) and a simulated
  robot created for it (its clock starts at 0), so nothing of an earlier trial reaches it;
* the simulated robot waits for every answer and its clock stands still meanwhile, and the
  benchmark server's only wall-clock rule that could end a task (the silence watchdog,
  ``frame_timeout_s``) is turned off, so neither the machine's load nor the number of workers
  changes what happens.

The tour of each plan is walked once per plan and seed and kept as a recording
(:class:`robot_client.tour_recording.TourRecording`) in a cache folder, keyed by the plan's
SHA-256, the seed and a hash of the code that renders and walks it; every worker teaches its own
server from that recording through the REST API.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import multiprocessing as mp
import os
import queue
import signal
import tempfile
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

BENCH_SERVER_SETTINGS: dict[str, Any] = {"frame_timeout_s": 1e9, "history": 1}
"""Navigation settings every benchmark server runs with, beside ``--set`` ones: no silence
watchdog (wall clock; the simulated robot's clock stands still while it waits) and a history of
one step per robot (the dashboard's; each trial has its own robot). Neither changes a command."""

PREPARE_S = 1800.0
"""How long a worker waits for its server to prepare a freshly taught tour (its first goto)."""

ANSWER_WAIT_S = 600.0
"""How long a benchmark's simulated robot waits for the server's answer to one request (s of
wall clock). The simulated world stands still while it waits, so a slow answer (a loaded
machine) changes nothing in the trial, where giving up would: the robot's client resends the
frame, which makes the trial depend on the machine's load, and a 10 s wait (the client's
default, right for a real robot) ended whole runs when several ran at once. This long only
catches a server that hangs."""

_RECORDING_CODE = (
    "robot_client/guide.py",
    "robot_client/tour_recording.py",
    "robot_client/sim/floorplan.py",
    "robot_client/sim/paths.py",
    "robot_client/sim/robot.py",
    "robot_client/sim/route.py",
    "robot_client/sim/textures.py",
    "robot_client/sim/world.py",
    "server/imaging.py",
)
"""The code a tour recording depends on: a change to any of these files makes a new one."""


@dataclass(frozen=True)
class TrialSpec:
    """Which trial: plan (index into the sweep's plans), condition and trial number."""

    plan: int
    condition: str
    trial: int


@dataclass(frozen=True)
class TrialError:
    """A trial that raised instead of finishing: which one, and the traceback (or what
    became of its worker)."""

    spec: TrialSpec
    traceback: str

    def row(self) -> dict[str, Any]:
        """As the JSON's ``errors`` list holds it."""
        return {
            "plan_index": self.spec.plan,
            "condition": self.spec.condition,
            "trial": self.spec.trial,
            "traceback": self.traceback,
        }


@dataclass(frozen=True)
class SweepConfig:
    """What every worker needs (plain data: it crosses process boundaries)."""

    plans: tuple[str, ...]  # plan files
    recordings: tuple[str, ...]  # the tour recording of each plan
    seed: int
    max_steps: int
    env: tuple[tuple[str, str], ...]  # the benchmark server's environment
    trace: str | None  # folder for per-step traces
    record: str | None = None  # folder for the recordings kept (--record)
    record_all: bool = False  # keep every trial's recording, not only the failures'
    no_depth: bool = False  # a robot without a depth sensor: taught and navigating (--no-depth)


def recording_key(plan_sha256: str, seed: int) -> str:
    """File name of the recording of a plan's tour for a seed, with a hash of the code."""
    from importlib.metadata import version

    root = Path(__file__).resolve().parents[2]
    h = hashlib.sha256(f"mujoco {version('mujoco')}\n".encode())  # not imported: see SimWorld
    for name in _RECORDING_CODE:
        h.update((root / name).read_bytes())
    return f"{plan_sha256[:16]}-seed{seed}-{h.hexdigest()[:12]}.npz"


def record(plan_file: str, seed: int, out: str) -> float:
    """Walk the plan's teaching route in the home as taught and save it to ``out``; seconds
    taken."""
    from robot_client.guide import record_tour
    from robot_client.sim import SimulatedRobot, SimWorld, load_plan
    from robot_client.sim.world import Pose

    t0 = time.perf_counter()
    plan = load_plan(plan_file)
    first = plan.places[0]
    with SimWorld(plan, condition="same", seed=seed) as world:
        robot = SimulatedRobot(world, Pose(first.x, first.y, first.yaw), seed=seed)
        record_tour(robot, plan).save(Path(out))
    return time.perf_counter() - t0


class Worker:
    """One benchmark server and the simulated homes; runs trials one at a time."""

    def __init__(self, config: SweepConfig) -> None:
        from robot_client.sim import load_plan
        from server.process import scratch_server

        self.config = config
        self._stack = contextlib.ExitStack()
        env = dict(config.env)
        if config.record is not None:  # the server records each trial's task where asked
            env["TEACHREPEAT_RECORD_DIR"] = self._stack.enter_context(
                tempfile.TemporaryDirectory(prefix="teachrepeat-recordings-")
            )
        self.server = self._stack.enter_context(scratch_server("bench.sqlite", extra_env=env))
        self.plans = [load_plan(p) for p in config.plans]
        self._tours: dict[int, Any] = {}
        self._truth: dict[int, Any] = {}  # where each plan's taught paths really are (judge)
        self._worlds: dict[tuple[int, str], Any] = {}
        self.teach_s = 0.0

    def close(self) -> None:
        self._stack.close()

    def __enter__(self) -> Worker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def client(self, robot: str) -> Any:
        """A client of this worker's server for ``robot``, registered afresh (the admin's
        request too waiting up to :data:`ANSWER_WAIT_S`), that waits for every answer as
        long."""
        from robot_client.client import TeachRepeatClient

        token = self.server.register_robot(robot, timeout_s=ANSWER_WAIT_S)
        return TeachRepeatClient(self.server.url, token, timeout_s=ANSWER_WAIT_S)

    def tour(self, plan: int) -> Any:
        """The taught graph of ``plan`` on this worker's server (taught on first use)."""
        if plan not in self._tours:
            from robot_client.guide import upload_tour
            from robot_client.tour_recording import TourRecording

            t0 = time.perf_counter()
            recording = TourRecording.load(Path(self.config.recordings[plan]))
            name = f"teacher-{plan}"
            with self.client(name) as client:
                steps = recording.steps
                if self.config.no_depth:  # a one-webcam robot taught it: no depth profiles
                    steps = tuple(replace(step, depth=None) for step in steps)
                graph = upload_tour(
                    client, name, steps, tour=f"home {plan}: {self.plans[plan].name}"
                )
                # the server prepares the tour (features, weights, distinctiveness) for the
                # first goto: here, with time to spare on a loaded machine, not in a trial's
                client.goto(name, graph.locations[0].name, tour=graph.id, timeout_s=PREPARE_S)
                client.stop(name)
                self._tours[plan] = graph
                from robot_client.trial import TaughtTruth

                self._truth[plan] = TaughtTruth.of(graph, recording.steps)
            self.teach_s += time.perf_counter() - t0
            if self.config.record is not None:
                keep_database(self.server.db, self._tour_database(plan))
        return self._tours[plan]

    def _tour_database(self, plan: int) -> Path:
        """Where the database a plan's recordings replay against is kept (--record)."""
        assert self.config.record is not None
        return Path(self.config.record) / f"{slug(self.plans[plan].name)}.sqlite"

    def world(self, plan: int, condition: str) -> Any:
        key = (plan, condition)
        if key not in self._worlds:
            from robot_client.sim import SimWorld

            self._worlds[key] = self._stack.enter_context(
                SimWorld(self.plans[plan], condition=condition, seed=self.config.seed)
            )
        return self._worlds[key]

    def run(self, spec: TrialSpec) -> dict[str, Any]:
        """One trial; its row (``TrialResult.row()`` plus which trial and its wall seconds)."""
        from robot_client.sim import SimulatedRobot
        from robot_client.trial import draw_trial, run_trial

        plan = self.plans[spec.plan]
        graph = self.tour(spec.plan)
        world = self.world(spec.plan, spec.condition)
        start, goal, noise = draw_trial(plan, self.config.seed, spec.trial)
        name = f"trial-{spec.plan}-{spec.condition}-{spec.trial}"
        t0 = time.perf_counter()
        trace: list[dict[str, Any]] = []
        with self.client(name) as client:
            robot = SimulatedRobot(world, start, seed=noise)
            result = run_trial(
                client,
                name,
                robot,
                plan,
                goal,
                tour=graph,
                max_steps=self.config.max_steps,
                on_step=None
                if self.config.trace is None
                else tracer(robot, trace, self._truth.get(spec.plan)),
                record=True if self.config.record is not None else None,
                truth=self._truth.get(spec.plan),
                depth_sensor=not self.config.no_depth,
            )
            evidence = self._keep_recording(client, name, spec, result.success)
        if self.config.trace is not None:
            folder = Path(self.config.trace) / slug(plan.name) / spec.condition
            write_trace(folder / f"trial_{spec.trial:03d}.jsonl", trace)
        return {
            "plan_index": spec.plan,
            "plan": plan.name,
            "condition": spec.condition,
            "trial": spec.trial,
            **result.row(),
            **evidence,
            "wall_s": time.perf_counter() - t0,
        }

    def _keep_recording(
        self, client: Any, robot: str, spec: TrialSpec, success: bool
    ) -> dict[str, Any]:
        """Download the trial's recording into the --record folder when it failed (every
        one with --record-all); the row's ``recording`` (its path) and ``recording_db`` (the
        database to replay it against)."""
        config = self.config
        if config.record is None or (success and not config.record_all):
            return {}
        deadline = time.monotonic() + 30
        while True:  # the server finishes the file in its writer thread
            listed = [r for r in client.recordings(robot) if r.kind == "navigate"]
            if (listed and not listed[0].recording) or time.monotonic() > deadline:
                break
            time.sleep(0.05)
        if not listed:
            return {"recording": None, "recording_db": None}
        folder = Path(config.record) / slug(self.plans[spec.plan].name) / spec.condition
        out = folder / f"trial_{spec.trial:03d}.mcap"
        folder.mkdir(parents=True, exist_ok=True)
        out.write_bytes(client.recording(robot, listed[0].name))
        return {"recording": str(out), "recording_db": str(self._tour_database(spec.plan))}


def keep_database(db: Path, out: Path) -> None:
    """A consistent copy of the server's database at ``out`` (SQLite's online backup, safe
    while the server writes it), unless one is there: the tour a recording replays against
    has the same fingerprint in every worker's database."""
    import sqlite3

    if out.exists():
        return
    out.parent.mkdir(parents=True, exist_ok=True)
    part = out.with_name(f"{out.name}.{os.getpid()}.part")
    source, target = sqlite3.connect(str(db)), sqlite3.connect(str(part))
    try:
        source.backup(target)
    finally:
        target.close()
        source.close()
    part.replace(out)


def slug(name: str) -> str:
    """A plan's name as a file or folder name (every character not a letter or digit: _)."""
    return "".join(c if c.isalnum() else "_" for c in name)


def write_trace(path: Path, rows: list[dict[str, Any]]) -> None:
    """Write a trial's trace (the rows of :func:`tracer`) to ``path``, one JSON line per step,
    making its folder."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))


def tracer(robot: Any, out: list[dict[str, Any]], taught: Any = None) -> Callable[[int, Any], None]:
    """A step hook that records the true pose, the command, the top beliefs, the belief over
    appearance models, the change evidence and the path tracker's estimate (edge id, along,
    lateral, heading error, their standard deviations, locked, the true distance to that
    edge's taught path and how far the robot truly is from where the estimate puts it, from
    ``taught``: ``TaughtTruth.locate``; null when it tracks none)."""

    def hook(step: int, result: Any) -> None:
        pose, c = robot.pose, result.command
        path = result.path
        tracked = None
        if path is not None:
            error = None if taught is None else taught.error(path.edge, pose.x, pose.y)
            put = None if taught is None else taught.locate(path.edge, path.along_m, path.lateral_m)
            missed = None if put is None else math.hypot(put[0] - pose.x, put[1] - pose.y)
            tracked = {
                "edge": path.edge,
                "along": round(path.along_m, 3),
                "lateral": round(path.lateral_m, 3),
                "heading": round(path.heading_error, 3),
                "sd": [
                    round(path.sigma_along_m, 3),
                    round(path.sigma_lateral_m, 3),
                    round(path.sigma_heading, 3),
                ],
                "locked": path.locked,
                "true_error": None if error is None else round(error, 3),
                "estimate_error": None if missed is None else round(missed, 3),
            }
        out.append(
            {
                "step": step,
                "t": round(robot.now(), 2),
                "pose": [round(pose.x, 3), round(pose.y, 3), round(pose.theta, 3)],
                "action": c.action,
                "behaviour": c.behaviour,
                "reason": c.reason,
                "edge": c.edge,
                "target_image": c.target_image_id,
                "v": round(c.v, 3),
                "w": round(c.w, 3),
                "top": [[b.name, round(b.probability, 3)] for b in result.belief.top[:3]],
                "appearance": [round(x, 3) for x in result.belief.appearance],
                "light_change": round(result.belief.light_change, 3),
                "path": tracked,
            }
        )

    return hook


def _exit_on_sigterm(signum: int, frame: object) -> None:
    raise SystemExit(128 + signum)  # so that the worker's scratch server is stopped


def _serve(config: SweepConfig, tasks: Any, results: Any) -> None:
    """A worker process: run the trials it is given until it gets ``None``; its last word
    (the seconds spent teaching) comes once its server and homes are closed, so the sweep
    that waits for it never stops a worker midway through closing (a SIGTERM then left
    its scratch server running, with no parent)."""
    signal.signal(signal.SIGTERM, _exit_on_sigterm)
    with Worker(config) as worker:
        while True:
            spec = tasks.get()
            if spec is None:
                break
            try:
                results.put(("row", spec, worker.run(spec)))
            except Exception:  # reported; the next trial is run (its server may be fine)
                results.put(("error", spec, traceback.format_exc()))
        teach_s = worker.teach_s
    results.put(("teach_s", None, teach_s))


def run_trials(
    config: SweepConfig,
    specs: Sequence[TrialSpec],
    *,
    workers: int = 1,
    on_row: Callable[[dict[str, Any]], None] | None = None,
    on_error: Callable[[TrialError], None] | None = None,
) -> tuple[list[dict[str, Any]], float, list[TrialError]]:
    """Run every trial of ``specs`` on ``workers`` processes (1: in this process): the rows of
    the trials that finished, in the order of ``specs``, the seconds spent teaching the
    workers' servers, and the trials that raised (or whose worker died), in the order of
    ``specs``. A trial that raises is reported (``on_error``) and the sweep goes on: an hour
    of finished trials is not lost to one."""
    failed: dict[TrialSpec, TrialError] = {}

    def fail(spec: TrialSpec, text: str) -> None:
        failed[spec] = TrialError(spec, text)
        if on_error:
            on_error(failed[spec])

    if workers <= 1:
        rows = []
        with Worker(config) as worker:
            for spec in specs:
                try:
                    rows.append(worker.run(spec))
                except Exception:
                    fail(spec, traceback.format_exc())
                    continue
                if on_row:
                    on_row(rows[-1])
            return rows, worker.teach_s, list(failed.values())
    ctx = mp.get_context("spawn")  # MuJoCo's OpenGL context and threads do not survive fork
    tasks: Any = ctx.Queue()
    results: Any = ctx.Queue()
    for spec in specs:
        tasks.put(spec)
    n = min(workers, len(specs))
    for _ in range(n):
        tasks.put(None)
    procs = [ctx.Process(target=_serve, args=(config, tasks, results)) for _ in range(n)]
    for p in procs:
        p.start()
    got: dict[TrialSpec, dict[str, Any]] = {}
    teach_s, finished = 0.0, 0
    try:
        while finished < n:
            try:
                kind, spec, payload = results.get(timeout=5.0)
            except queue.Empty:
                if not any(p.is_alive() for p in procs):
                    for s in specs:  # left in the queue, or being run by a worker that died
                        if s not in got and s not in failed:
                            fail(s, "not run: its worker died (see above)")
                    break
                continue
            if kind == "error":
                fail(spec, payload)
                continue
            if kind == "teach_s":
                teach_s += payload
                finished += 1
                continue
            got[spec] = payload
            if on_row:
                on_row(payload)
    finally:
        for p in procs:  # done: each has closed and is on its way out; else stop them now
            p.join(timeout=30 if finished == n else 0)
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join(timeout=30)
    rows = [got[s] for s in specs if s in got]
    return rows, teach_s, [failed[s] for s in specs if s in failed]


def prepare_recordings(
    plan_files: Sequence[str],
    plan_sha256: Sequence[str],
    seed: int,
    cache: Path | None,
    scratch: Path,
    *,
    workers: int = 1,
    log: Callable[[str], None] = print,
) -> list[str]:
    """The tour recording of every plan: from ``cache`` when there, walked (in parallel on
    ``workers`` processes) and stored there otherwise. ``cache=None``: always walked, into
    ``scratch``."""
    folder = scratch if cache is None else cache
    paths = [str(folder / recording_key(sha, seed)) for sha in plan_sha256]
    missing = [(f, p) for f, p in zip(plan_files, paths, strict=True) if not Path(p).exists()]
    for f, p in zip(plan_files, paths, strict=True):
        if (f, p) not in missing:
            log(f"tour of {f}: from the cache ({p})")
    if not missing:
        return paths
    log(f"walking the tour of {len(missing)} plan(s) (cached afterwards)")
    if workers <= 1 or len(missing) == 1:
        for f, p in missing:
            log(f"tour of {f}: walked in {record(f, seed, p):.0f} s -> {p}")
        return paths
    from concurrent.futures import ProcessPoolExecutor

    ctx = mp.get_context("spawn")
    with ProcessPoolExecutor(max_workers=min(workers, len(missing)), mp_context=ctx) as pool:
        futures = [(f, p, pool.submit(record, f, seed, p)) for f, p in missing]
        for f, p, fut in futures:
            log(f"tour of {f}: walked in {fut.result():.0f} s -> {p}")
    return paths


def group_rows(
    rows: Sequence[dict[str, Any]], keys: Sequence[str]
) -> Iterator[tuple[tuple[Any, ...], list[dict[str, Any]]]]:
    """Rows grouped by the values of ``keys``, groups in first-seen order."""
    groups: dict[tuple[Any, ...], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in keys), []).append(r)
    yield from groups.items()
