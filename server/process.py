"""Start the real server (``teachrepeat serve``) as a child process on a free port.

Used by the integration tests and by the benchmarks that need a real HTTP server.
"""

from __future__ import annotations

import os
import re
import signal
import ssl
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
    ca_cert: Path | None = None
    """The certificate the server presents, when it serves over HTTPS."""
    database_url: str | None = None
    """The PostgreSQL database it serves from (``db``'s folder then holds only the admin
    token file and recordings)."""

    def database(self) -> Path | str:
        """What :class:`server.storage.repo.Repo` opens to read what the server stored."""
        return self.database_url if self.database_url is not None else self.db

    def register_robot(self, name: str, *, timeout_s: float = 10.0) -> str:
        """Register robot ``name`` with the admin token, waiting up to ``timeout_s`` for the
        answer; its bearer token."""
        from robot_client.client import TeachRepeatClient

        with TeachRepeatClient(
            self.url, self.admin_token, ca_cert=self.ca_cert, timeout_s=timeout_s
        ) as admin:
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
    tls: tuple[Path, Path] | None = None,
    workers: int = 0,
    database_url: str | None = None,
) -> ServerProcess:
    """Run ``teachrepeat serve --db DB --port 0`` and wait until it answers ``/health``.

    ``database_url``: serve from this PostgreSQL database instead of the file ``db``
    (``TEACHREPEAT_DATABASE_URL``, never on the command line).

    ``workers``: that many server processes behind HAProxy (``--workers``, docs/scale.md);
    ``url`` is then HAProxy's address and ``proc`` the launcher.

    ``dashboard``: also start the dashboard on a free port (``dashboard_url``). ``tls``:
    ``(cert, key)`` to serve over HTTPS with (``--tls-cert``, ``--tls-key``); ``/health`` is
    then asked trusting that certificate only."""
    env = {**os.environ, "TEACHREPEAT_ADMIN_TOKEN": admin_token, **(extra_env or {})}
    env.pop("TEACHREPEAT_DB", None)
    env.pop("TEACHREPEAT_DATABASE_URL", None)
    if database_url is not None:
        env["TEACHREPEAT_DATABASE_URL"] = database_url
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
            *(["--tls-cert", str(tls[0]), "--tls-key", str(tls[1])] if tls else []),
            *(["--workers", str(workers)] if workers else []),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )
    try:
        server = _wait_until_up(proc, db, admin_token, dashboard, tls, 90.0 if workers else 30.0)
        server.database_url = database_url
        return server
    except BaseException:
        # not up (or the caller was interrupted, e.g. SIGTERM or Ctrl-C while the server was
        # still importing): nobody else holds the process, so stop it here
        proc.kill()
        proc.wait()
        raise


def _wait_until_up(
    proc: subprocess.Popen[str],
    db: Path,
    admin_token: str,
    dashboard: bool,
    tls: tuple[Path, Path] | None,
    timeout_s: float = 30.0,
) -> ServerProcess:
    """Read the server's address from its output and wait until ``/health`` answers,
    ``timeout_s`` at most; ``RuntimeError`` if it does not start."""
    if proc.stdout is None:
        raise RuntimeError("no stdout pipe")
    deadline = time.monotonic() + timeout_s
    url = None
    dashboard_url = None
    lines = []
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        found = re.search(r"teachrepeat API\s+(https?://\S+)", line)
        if found:
            url = found.group(1)
        found = re.search(r"dashboard\s+(https?://\S+)", line)
        if found:
            dashboard_url = found.group(1)
        if url and (dashboard_url or not dashboard):
            break
    if url is None:
        raise RuntimeError("server did not start:\n" + "".join(lines))
    # keep draining the pipe so the server never blocks on a full stdout
    stdout = proc.stdout
    threading.Thread(target=lambda: [None for _ in stdout], daemon=True).start()
    ca_cert = tls[0] if tls else None
    verify = ssl.create_default_context(cafile=str(ca_cert)) if ca_cert else True
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"{url}/health", timeout=1, verify=verify).status_code == 200:
                return ServerProcess(proc, url, db, dashboard_url, admin_token, ca_cert)
        except httpx.TransportError:
            time.sleep(0.05)
    raise RuntimeError("server never answered /health")


@contextmanager
def scratch_server(
    name: str = "scratch.sqlite",
    *,
    extra_env: dict[str, str] | None = None,
    workers: int = 0,
    database_url: str | None = None,
) -> Iterator[ServerProcess]:
    """A real server on a fresh database in a temporary folder, stopped and removed on exit
    (for benchmarks that measure a clean server); ``workers`` and ``database_url`` (an empty
    PostgreSQL database instead of the file) as in :func:`start_server`."""
    with tempfile.TemporaryDirectory() as tmp:
        server = start_server(
            Path(tmp) / name, extra_env=extra_env, workers=workers, database_url=database_url
        )
        try:
            yield server
        finally:
            server.stop()
