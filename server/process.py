"""Start the real server (``teachrepeat serve``) as a child process on a free port.

Used by the integration tests and by the benchmarks that need a real HTTP server.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import httpx

ADMIN = "process-admin-token"
"""Admin token the child server is started with (a local, throw-away server)."""


@dataclass
class ServerProcess:
    proc: subprocess.Popen[str]
    url: str
    db: Path
    dashboard_url: str | None = None
    admin_token: str = ADMIN

    def register_robot(self, name: str) -> str:
        """Register robot ``name`` with the admin token; its bearer token."""
        from robot_client.client import TeachRepeatClient

        with TeachRepeatClient(self.url, self.admin_token) as admin:
            return admin.register_robot(name).token

    def kill(self) -> None:
        """SIGKILL: no clean shutdown, as in a power cut."""
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(timeout=10)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.kill()


def start_server(
    db: Path,
    *,
    admin_token: str = ADMIN,
    dashboard: bool = False,
    extra_env: dict[str, str] | None = None,
) -> ServerProcess:
    """Run ``teachrepeat serve --db DB --port 0`` and wait until it answers ``/health``.

    ``dashboard``: also start the dashboard on a free port (``dashboard_url``)."""
    env = {**os.environ, "TEACHREPEAT_ADMIN_TOKEN": admin_token, **(extra_env or {})}
    env.pop("TEACHREPEAT_DB", None)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "server.cli",
            "serve",
            "--db",
            str(db),
            "--port",
            "0",
            "--dashboard-port",
            "0" if dashboard else "-1",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )
    if proc.stdout is None:
        raise RuntimeError("no stdout pipe")
    deadline = time.monotonic() + 30
    url = None
    dashboard_url = None
    lines = []
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        found = re.search(r"teachrepeat API\s+(http://\S+)", line)
        if found:
            url = found.group(1)
        found = re.search(r"dashboard\s+(http://\S+)", line)
        if found:
            dashboard_url = found.group(1)
        if url and (dashboard_url or not dashboard):
            break
    if url is None:
        proc.kill()
        raise RuntimeError("server did not start:\n" + "".join(lines))
    # keep draining the pipe so the server never blocks on a full stdout
    stdout = proc.stdout
    threading.Thread(target=lambda: [None for _ in stdout], daemon=True).start()
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"{url}/health", timeout=1).status_code == 200:
                return ServerProcess(proc, url, db, dashboard_url, admin_token)
        except httpx.TransportError:
            time.sleep(0.05)
    proc.kill()
    raise RuntimeError("server never answered /health")


@contextmanager
def scratch_server(
    name: str = "scratch.sqlite", *, extra_env: dict[str, str] | None = None
) -> Iterator[ServerProcess]:
    """A real server on a fresh database in a temporary folder, stopped and removed on exit
    (for benchmarks that measure a clean server)."""
    with tempfile.TemporaryDirectory() as tmp:
        server = start_server(Path(tmp) / name, extra_env=extra_env)
        try:
            yield server
        finally:
            server.stop()
