"""``teachrepeat serve --workers N``: N server processes behind HAProxy, each robot on one.

The launcher (docs/scale.md):

1. brings the database to the newest schema once, so that N processes starting together do
   not all try to migrate it;
2. starts N ``teachrepeat serve`` processes on 127.0.0.1, each on its own port, named
   ``w0`` ... (``X-Teachrepeat-Worker`` header, ``/health``), without a dashboard;
3. writes the shipped HAProxy configuration (``server/deploy/haproxy.cfg``) with their
   addresses and runs ``haproxy`` in the foreground on ``host``:``port``. HAProxy hashes the
   robot's name in ``/robots/NAME/...`` so that all of a robot's requests reach the process
   that holds its session;
4. restarts a process that dies, on the same port. Its robots' requests wait meanwhile (HAProxy
   tries the process again once a second); everything taught is in the database, and a robot's
   next frame rebuilds its session from the persisted task and belief snapshot.

SIGTERM or Ctrl-C stops HAProxy and every process.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import string
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType

from server.config import Settings, is_loopback
from server.errors import Unavailable

HAPROXY_TEMPLATE = Path(__file__).with_name("deploy") / "haproxy.cfg"
"""The shipped HAProxy configuration, with ``${bind}``, ``${servers}`` and ``${retries}``."""

RETRIES = 15
"""Times HAProxy tries a process that refuses connections (one second apart): longer than a
restart of a process takes on a loaded 2-core machine (about 5 s)."""

START_TIMEOUT_S = 90.0
"""How long a process (or HAProxy) may take to answer ``/health`` at start."""


@dataclass(frozen=True)
class WorkerAddress:
    """One server process behind HAProxy: its name and its port on 127.0.0.1."""

    name: str
    port: int


def haproxy_address(host: str, port: int) -> str:
    """``host:port`` as HAProxy's ``bind`` and ``server`` lines take it (``ipv6@`` for IPv6)."""
    host = host.strip("[]")
    return f"ipv6@{host}:{port}" if ":" in host else f"{host}:{port}"


def haproxy_config(
    *,
    host: str,
    port: int,
    workers: Sequence[WorkerAddress],
    retries: int = RETRIES,
    template: str | None = None,
) -> str:
    """The HAProxy configuration for ``workers`` behind ``host``:``port``: the shipped
    template (``template`` overrides its text) with its placeholders filled in.
    ``ValueError`` for no workers, a port out of range or two workers with one name."""
    if not workers:
        raise ValueError("HAProxy needs at least one server process")
    names = [w.name for w in workers]
    if len(set(names)) != len(names):
        raise ValueError(f"server process names must differ: {names}")
    for p in (port, *(w.port for w in workers)):
        if not 1 <= p <= 65535:
            raise ValueError(f"port {p} is out of range 1-65535")
    servers = "\n".join(
        f"    server {w.name} {haproxy_address('127.0.0.1', w.port)}" for w in workers
    )
    text = template if template is not None else HAPROXY_TEMPLATE.read_text()
    return string.Template(text).substitute(
        bind=haproxy_address(host, port), servers=servers, retries=str(retries)
    )


def free_port(host: str = "127.0.0.1") -> int:
    """A port nobody listens on right now (the system picks it; another program could take it
    before we do, which a start then reports)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as sock:
        sock.bind((host.strip("[]"), 0))
        return int(sock.getsockname()[1])


def worker_command(settings: Settings, worker: WorkerAddress) -> list[str]:
    """The command line of one server process behind HAProxy."""
    command = [
        sys.executable,
        "-m",
        "server.cli",
        "serve",
        "--workers",
        "0",
        "--db",
        str(settings.db),
        "--host",
        "127.0.0.1",
        "--port",
        str(worker.port),
        "--dashboard-port",
        "-1",
    ]
    if settings.record:
        command += ["--record", str(settings.recordings_dir())]
    return command


def cluster_refusal(settings: Settings, *, dashboard_asked: bool) -> str | None:
    """Why ``serve --workers`` cannot run with these settings (a message saying what to do),
    or ``None`` when it can."""
    if settings.tls_cert is not None:
        return (
            "--workers does not serve HTTPS yet: HAProxy would need the certificate "
            "(docs/scale.md, TLS). Serve one process with --tls-cert, or put TLS on HAProxy "
            "yourself with the shipped server/deploy/haproxy.cfg"
        )
    if dashboard_asked:
        return (
            "--workers runs no dashboard: each process would show and drive only the robots "
            "it holds (docs/scale.md). Leave out --dashboard-port, or serve one process"
        )
    if shutil.which("haproxy") is None:
        return (
            "--workers needs HAProxy, which is not installed: run scripts/setup-system.sh "
            "(Debian package haproxy)"
        )
    return None


@dataclass
class Worker:
    """A supervised server process: its address, the running process and its restarts."""

    address: WorkerAddress
    proc: subprocess.Popen[bytes] | None = None
    started_at: float = 0.0
    restarts: int = 0
    quick_deaths: int = 0
    restart_at: float | None = None


@dataclass
class Cluster:
    """N server processes and HAProxy in front of them; :meth:`start`, :meth:`supervise`
    (restart what died) and :meth:`stop`. ``say`` prints a line (the launcher's output)."""

    settings: Settings
    addresses: list[WorkerAddress]
    port: int
    say: Callable[[str], None] = print
    workers: list[Worker] = field(default_factory=list)
    haproxy: subprocess.Popen[bytes] | None = None
    folder: Path | None = None

    def environment(self, worker: WorkerAddress) -> dict[str, str]:
        token = self.settings.admin_token
        if token is None:
            raise ValueError("the cluster needs the admin token resolved before it starts")
        env = {k: v for k, v in os.environ.items() if k != "TEACHREPEAT_WORKERS"}
        env["TEACHREPEAT_ADMIN_TOKEN"] = token.get_secret_value()
        env["TEACHREPEAT_WORKER_NAME"] = worker.name
        if self.settings.database_url is not None:  # never on a command line: ps shows those
            env["TEACHREPEAT_DATABASE_URL"] = self.settings.database_url.get_secret_value()
        return env

    def _spawn(self, worker: Worker) -> None:
        worker.proc = subprocess.Popen(
            worker_command(self.settings, worker.address),
            env=self.environment(worker.address),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,  # its banner would name its own port; errors still show
            preexec_fn=_die_with_parent,
        )
        worker.started_at = time.monotonic()
        worker.restart_at = None

    def start(self) -> None:
        """Start every process, wait for each to answer, then HAProxy; ``RuntimeError`` when
        one does not come up (whatever started is stopped by :meth:`stop`)."""
        from server.storage.repo import Repo

        # migrate once, before N processes open the database
        Repo(self.settings.database()).close()
        self.workers = [Worker(a) for a in self.addresses]
        for worker in self.workers:
            self._spawn(worker)
        for worker in self.workers:
            _wait_healthy(f"http://127.0.0.1:{worker.address.port}", worker.proc)
        self.folder = Path(tempfile.mkdtemp(prefix="teachrepeat-haproxy-"))
        config = self.folder / "haproxy.cfg"
        config.write_text(
            haproxy_config(host=self.settings.host, port=self.port, workers=self.addresses)
        )
        checked = subprocess.run(
            ["haproxy", "-c", "-q", "-f", str(config)], capture_output=True, text=True
        )
        if checked.returncode != 0:
            said = (checked.stderr + checked.stdout).strip()
            raise RuntimeError(f"HAProxy refused its configuration {config}: {said}")
        self.haproxy = subprocess.Popen(
            ["haproxy", "-db", "-f", str(config)],
            stdin=subprocess.DEVNULL,
            preexec_fn=_die_with_parent,
        )
        _wait_healthy(self.url(for_client=True), self.haproxy)

    def url(self, *, for_client: bool = False) -> str:
        """The address robots use (``for_client``: a loopback one when HAProxy listens on
        every interface)."""
        host = self.settings.host
        if for_client and host in ("0.0.0.0", "::", ""):
            host = "127.0.0.1"
        shown = f"[{host}]" if ":" in host else host
        return f"http://{shown}:{self.port}"

    def supervise(self, now: float | None = None) -> str | None:
        """One look at the processes: a process that ended is started again on its port
        (after a pause that grows while it keeps dying within 10 s of starting). Returns why
        the cluster cannot go on (HAProxy ended), else ``None``."""
        now = time.monotonic() if now is None else now
        if self.haproxy is not None and self.haproxy.poll() is not None:
            return f"HAProxy ended with code {self.haproxy.returncode}"
        for worker in self.workers:
            proc = worker.proc
            if proc is None or proc.poll() is None:
                continue
            if worker.restart_at is None:
                quick = now - worker.started_at < 10.0
                worker.quick_deaths = worker.quick_deaths + 1 if quick else 0
                pause = 0.0 if not quick else min(30.0, 2.0 ** (worker.quick_deaths - 1))
                worker.restart_at = now + pause
                self.say(
                    f"worker {worker.address.name} (pid {proc.pid}) ended with code "
                    f"{proc.returncode}; starting it again"
                    + (f" in {pause:.0f} s" if pause else "")
                )
            if now >= worker.restart_at:
                self._spawn(worker)
                worker.restarts += 1
                pid = worker.proc.pid if worker.proc is not None else "?"
                self.say(f"worker {worker.address.name} started again (pid {pid})")
        return None

    def stop(self) -> None:
        """Stop HAProxy and every process (SIGTERM, then SIGKILL after 10 s); idempotent."""
        procs = [p for p in [self.haproxy, *(w.proc for w in self.workers)] if p is not None]
        for proc in procs:
            if proc.poll() is None:
                proc.terminate()
        deadline = time.monotonic() + 10.0
        for proc in procs:
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)
            self.folder = None


PR_SET_PDEATHSIG = 1  # <sys/prctl.h>


def _die_with_parent() -> None:
    """In a child before it runs: SIGTERM it when the launcher dies, even by SIGKILL (Linux),
    so that no server process outlives it."""
    import ctypes

    # not Linux/glibc: the launcher's stop() still stops it
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6").prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def _wait_healthy(url: str, proc: subprocess.Popen[bytes] | None) -> None:
    """Wait until ``url``/health answers 200; ``RuntimeError`` when ``proc`` ends first or
    :data:`START_TIMEOUT_S` passes."""
    import httpx

    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            raise RuntimeError(f"{url} ended with code {proc.returncode} before answering")
        try:
            if httpx.get(f"{url}/health", timeout=2.0).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.1)
    raise RuntimeError(f"{url} did not answer /health within {START_TIMEOUT_S:.0f} s")


def run_cluster(settings: Settings) -> int:
    """``serve --workers N``: start, print the addresses, supervise until SIGTERM or Ctrl-C."""
    port = settings.port or free_port(settings.host if settings.host else "127.0.0.1")
    addresses = [WorkerAddress(f"w{i}", free_port()) for i in range(settings.workers)]
    cluster = Cluster(settings, addresses, port, say=lambda line: print(line, flush=True))
    stopping = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stopping.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        try:
            cluster.start()
        except (RuntimeError, OSError, Unavailable) as exc:
            print(f"teachrepeat serve: the cluster did not start: {exc}", file=sys.stderr)
            return 1
        if not is_loopback(settings.host):
            print(f"HAProxy listens on {settings.host}: robots on the network can reach it")
        print(f"teachrepeat API  {cluster.url()}", flush=True)
        print(f"database         {settings.database_shown()}", flush=True)
        for w in cluster.workers:
            pid = w.proc.pid if w.proc is not None else "?"
            print(f"worker {w.address.name}        http://127.0.0.1:{w.address.port} (pid {pid})")
        print("dashboard        off with --workers (docs/scale.md)", flush=True)
        while not stopping.wait(0.2):
            why = cluster.supervise()
            if why is not None:
                print(f"teachrepeat serve: {why}; stopping", file=sys.stderr, flush=True)
                return 1
        return 0
    finally:
        cluster.stop()
        for s, handler in previous.items():
            signal.signal(s, handler)
