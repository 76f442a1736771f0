"""``teachrepeat bench load --processes P``: the load bench through HAProxy and P processes.

The same robots as :mod:`server.bench.load` (taught corridor tour, ``R`` client threads at
``--rate`` Hz each, spread along the frames), but the server is ``teachrepeat serve --workers
P`` on a fresh database: HAProxy in front, ``P`` server processes behind it, each robot kept on
one of them (docs/scale.md). So the latency is the whole path a robot sees: client, HAProxy,
server process and back. Measured per run, besides the robots' p50/p95/p99, frames/s and
errors:

* per process (each server process, HAProxy, the launcher, and ``clients``: this process,
  whose threads are the robots): CPU (100 = one core) from ``/proc/<pid>/stat`` over the
  measured window;
* per server process: the robots it held (from each robot's ``X-Teachrepeat-Worker``), RSS
  first after the warm-up and last, and their ratio.

``--processes 1,2`` alternates the counts for each ``R`` (one fresh cluster per run), so that
both see the same machine load; with ``--sweep`` it reports the largest ``R`` within ``--p99-ms``
for each ``P``. The clients run as threads of this process on the same machine as HAProxy and
the servers, and share its cores: on a 2-core machine, 2 processes cannot get 2 cores.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Any

from server.bench.common import corridor_marks, default_data_dir, write_json
from server.bench.load import (
    RssSampler,
    client_figures,
    cpu_seconds,
    databases,
    drive,
    load_frames,
    meets,
    run_options,
)
from server.process import ADMIN, ServerProcess
from server.storage.pgserver import PostgresUnavailable

WORKER_HEADER = "X-Teachrepeat-Worker"


def child_pids(pid: int) -> list[int]:
    """The children of process ``pid`` (Linux ``/proc/<pid>/task/*/children``)."""
    found: list[int] = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        text = (task / "children").read_text()
        found += [int(x) for x in text.split()]
    return found


def cluster_processes(launcher_pid: int) -> dict[str, int]:
    """The processes of a ``serve --workers`` launcher by name: ``haproxy``, and each server
    process by the name it answers ``/health`` with (``w0``, ``w1``, ...)."""
    import httpx

    named: dict[str, int] = {}
    for pid in child_pids(launcher_pid):
        try:
            argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        except OSError:  # ended meanwhile
            continue
        words = [a.decode() for a in argv if a]
        if words and os.path.basename(words[0]) == "haproxy":
            named["haproxy"] = pid
        elif "serve" in words and "--port" in words:
            port = words[words.index("--port") + 1]
            health = httpx.get(f"http://127.0.0.1:{port}/health", timeout=10).json()
            named[str(health.get("worker", f"port {port}"))] = pid
    return named


def worker_of(url: str, token: str, robot: str) -> str:
    """Which server process holds ``robot`` (the header of its state, through HAProxy)."""
    import httpx

    r = httpx.get(
        f"{url}/robots/{robot}/state", headers={"Authorization": f"Bearer {token}"}, timeout=30
    )
    return r.headers.get(WORKER_HEADER, "?")


def _teach(server: ServerProcess, ref: Path, robots: int, goal: str) -> dict[str, str]:
    """Teach the corridor tour through HAProxy, register ``robots`` robots and send each to
    ``goal``; their tokens by name."""
    from robot_client.client import TeachRepeatClient
    from robot_client.teach import teach_folder

    with TeachRepeatClient(server.url, ADMIN) as admin:
        teacher = admin.register_robot("teacher").token
        with TeachRepeatClient(server.url, teacher) as client:
            teach_folder(
                client,
                tour="corridor",
                frames=ref,
                marks=corridor_marks(),
                progress=False,
            )
        tokens = {f"r{i:03d}": admin.register_robot(f"r{i:03d}").token for i in range(robots)}
    for name, token in tokens.items():
        with TeachRepeatClient(server.url, token) as robot:
            robot.goto(name, goal)
    return tokens


def cluster_run(
    robots: int,
    processes: int,
    *,
    ref: Path,
    frames: list[bytes],
    seconds: float,
    warmup_s: float,
    rate_hz: float,
    goal: str,
    rss_every_s: float,
    server_env: dict[str, str] | None = None,
    lockstep: bool = False,
    database_url: str | None = None,
) -> dict[str, Any]:
    """Start ``serve --workers processes`` on a fresh database (``database_url``: a new
    PostgreSQL database), teach, drive ``robots`` clients through HAProxy; the figures of
    this run."""
    from server.process import scratch_server

    with scratch_server(
        "load.sqlite", extra_env=server_env, workers=processes, database_url=database_url
    ) as server:
        tokens = _teach(server, ref, robots, goal)
        pids = cluster_processes(server.proc.pid)
        pids["launcher"] = server.proc.pid
        pids["clients"] = os.getpid()  # this process: the robots' threads
        workers = sorted(k for k in pids if k not in ("haproxy", "launcher", "clients"))
        held = {name: worker_of(server.url, token, name) for name, token in tokens.items()}
        samplers = {w: RssSampler(pids[w], rss_every_s) for w in workers}
        for sampler in samplers.values():
            sampler.start()
        measure_from = time.monotonic() + warmup_s
        until = measure_from + seconds
        logs, threads = drive(
            server, tokens, frames, rate_hz=rate_hz, goal=goal, until=until, lockstep=lockstep
        )
        time.sleep(max(0.0, measure_from - time.monotonic()))
        cpu0, wall0 = {k: cpu_seconds(p) for k, p in pids.items()}, time.monotonic()
        for t in threads:
            t.join(timeout=seconds + warmup_s + 60)
        cpu1, wall1 = {k: cpu_seconds(p) for k, p in pids.items()}, time.monotonic()
        for sampler in samplers.values():
            sampler.stop()
        same = cluster_processes(server.proc.pid)
        restarted = [w for w in workers if same.get(w) != pids[w]]
    per_process: dict[str, dict[str, Any]] = {
        k: {"pid": pids[k], "cpu_pct": 100.0 * (cpu1[k] - cpu0[k]) / max(wall1 - wall0, 1e-9)}
        for k in pids
    }
    for w in workers:
        after = [mb for (t, mb) in samplers[w].samples if t >= warmup_s]
        per_process[w]["robots"] = sum(1 for h in held.values() if h == w)
        per_process[w]["rss_mb_first"] = after[0] if after else float("nan")
        per_process[w]["rss_mb_last"] = after[-1] if after else float("nan")
        per_process[w]["rss_growth"] = after[-1] / after[0] if len(after) >= 2 else float("nan")
    return {
        "robots": robots,
        "processes": processes,
        **client_figures(
            logs,
            measure_from=measure_from,
            robots=robots,
            rate_hz=rate_hz,
            seconds=seconds,
            warmup_s=warmup_s,
            lockstep=lockstep,
        ),
        "per_process": per_process,
        "robot_worker": held,
        "restarted": restarted,
        "rss_growth": max((per_process[w]["rss_growth"] for w in workers), default=float("nan")),
    }


def describe(result: dict[str, Any]) -> str:
    """One line per run: the robots' figures, then each process's."""
    lat = result["latency_ms"]
    procs = result["per_process"]
    parts = []
    for name in sorted(procs):
        p = procs[name]
        text = f"{name} CPU {p['cpu_pct']:.0f} %"
        if "robots" in p:
            text += (
                f" ({p['robots']} robots, RSS {p['rss_mb_first']:.0f} -> "
                f"{p['rss_mb_last']:.0f} MiB x{p['rss_growth']:.3f})"
            )
        parts.append(text)
    return (
        f"P={result['processes']} R={result['robots']:3d}: {result['fps']:6.1f} frames/s of "
        f"{result['offered_fps']:.0f} offered, latency p50 {lat['p50']:.1f} / p95 "
        f"{lat['p95']:.1f} / p99 {lat['p99']:.1f} ms, {result['errors']} errors; "
        + "; ".join(parts)
        + (f"; RESTARTED {result['restarted']}" if result["restarted"] else "")
    )


def parse_counts(text: str, what: str) -> list[int]:
    """``"1,2"`` -> ``[1, 2]``; ``ValueError`` saying what to fix."""
    try:
        counts = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        counts = []
    if not counts or min(counts) < 1:
        raise ValueError(f"{what} must be positive integers separated by commas, e.g. 1,2")
    return counts


def _measured(
    args: argparse.Namespace,
    robots: int,
    processes: int,
    ref: Path,
    frames: list[bytes],
    server_env: dict[str, str],
    database_url: str | None,
) -> dict[str, Any]:
    """One run of :func:`run`, printed as it ends."""
    result = cluster_run(
        robots,
        processes,
        ref=ref,
        frames=frames,
        server_env=server_env,
        database_url=database_url,
        **run_options(args),
    )
    result["meets_target"] = meets(result, args.p99_ms)
    print(describe(result) + ("" if result["meets_target"] else "  [misses target]"))
    for sample in result["error_samples"]:
        print(f"    error: {sample}")
    return result


def run(args: argparse.Namespace) -> int:
    """``bench load --processes P[,P2...]``: runs for every robot count and process count."""
    try:
        processes = parse_counts(str(args.processes), "--processes")
        counts = parse_counts(args.sweep, "--sweep") if args.sweep else [args.robots]
        ref, frames = load_frames(args.data or default_data_dir())
    except (ValueError, FileNotFoundError) as exc:
        print(exc)
        return 2
    server_env = dict(kv.split("=", 1) for kv in args.server_env if "=" in kv)
    print(
        f"load through HAProxy: {len(frames)} query frames at {args.rate:g} Hz per robot, "
        f"{args.warmup:g} s warm-up + {args.seconds:g} s measured per run; processes "
        f"{processes}, alternating; clients, HAProxy and servers share this machine's "
        f"{os.cpu_count()} cores"
        + ("; stored on PostgreSQL (throw-away server, same cores)" if args.postgres else "")
    )
    runs = []
    try:
        with databases(args.postgres) as fresh:
            for robots in counts:
                for p in processes:
                    runs.append(_measured(args, robots, p, ref, frames, server_env, fresh()))
    except PostgresUnavailable as exc:
        print(f"--postgres: {exc}")
        return 2
    largest = {}
    for p in processes:
        ok = [r["robots"] for r in runs if r["processes"] == p and r["meets_target"]]
        largest[p] = max(ok) if ok else None
        if len(counts) > 1:
            print(f"P={p}: largest R with p99 <= {args.p99_ms:g} ms and no errors: {largest[p]}")
    write_json(
        args.json,
        {
            "runs": runs,
            "largest_robots_meeting_target": {str(p): r for p, r in largest.items()},
            "server_env": server_env,
            "store": "postgresql" if args.postgres else "sqlite",
            "target": {"p99_ms": args.p99_ms, "errors": 0},
            "note": "clients run as threads on the same machine and cores as HAProxy and the "
            "server processes",
        },
    )
    return 0
