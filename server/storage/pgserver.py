"""A throw-away PostgreSQL server for tests and benchmarks (never for a deployment).

:class:`ThrowawayPostgres` runs the Debian package's own ``initdb`` and ``pg_ctl``
(``/usr/lib/postgresql/<version>/bin``) on a new temporary folder: the server listens on
127.0.0.1 on a free port and on a unix socket in that folder, a role ``teachrepeat`` with a
random password (scram-sha-256) owns it, and :meth:`stop` stops it and deletes the folder.
PostgreSQL refuses to run as root: when this process is root (CI), the folder is given to the
``postgres`` user the package creates and the programs run as that user (``runuser``).

:class:`PostgresUnavailable` says why no server could be started (not installed, no
unprivileged user); tests then skip with that message. ``python -m server.storage.pgserver``
starts one, prints its URL and runs until Ctrl-C (for ``bench load --database-url``).
"""

from __future__ import annotations

import contextlib
import glob
import os
import pwd
import re
import secrets
import shutil
import signal
import socket
import subprocess
import tempfile
import threading
from dataclasses import dataclass, field
from pathlib import Path

BIN_GLOB = "/usr/lib/postgresql/*/bin"
"""Where Debian's ``postgresql`` package puts the server programs (not on PATH)."""

ROLE = "teachrepeat"
"""The superuser role of a throw-away server."""

FAST_OPTIONS = ("fsync=off", "synchronous_commit=off", "full_page_writes=off")
"""Server options for tests (``durable=False``): nothing waits for the disk. Benchmarks keep
PostgreSQL's durable defaults."""


class PostgresUnavailable(RuntimeError):
    """No throw-away server can be started here; the message says why and what to install."""


def server_bin() -> Path:
    """The newest ``/usr/lib/postgresql/<version>/bin`` that has ``initdb`` and ``pg_ctl``;
    :class:`PostgresUnavailable` when none has."""
    found = [
        Path(d)
        for d in glob.glob(BIN_GLOB)
        if (Path(d) / "initdb").exists() and (Path(d) / "pg_ctl").exists()
    ]
    if not found:
        raise PostgresUnavailable(
            f"no PostgreSQL server programs under {BIN_GLOB}: install the Debian package "
            "postgresql (scripts/setup-system.sh)"
        )
    return max(found, key=lambda p: [int(x) for x in re.findall(r"\d+", p.parent.name)] or [0])


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@dataclass
class ThrowawayPostgres:
    """One PostgreSQL server in a temporary folder: :meth:`start`, :meth:`create_database`,
    :meth:`stop` (also a context manager). ``durable``: keep fsync on (benchmarks)."""

    durable: bool = False
    folder: Path | None = None
    port: int = 0
    password: str = field(default_factory=lambda: secrets.token_urlsafe(16), repr=False)
    _as_user: list[str] = field(default_factory=list)
    _counter: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def url(self, database: str = "postgres") -> str:
        """``postgresql://teachrepeat:PASSWORD@127.0.0.1:PORT/DATABASE`` (holds the password:
        print :func:`server.storage.database.masked` of it, never the URL itself)."""
        return f"postgresql://{ROLE}:{self.password}@127.0.0.1:{self.port}/{database}"

    def _run(self, *command: str) -> None:
        done = subprocess.run(
            [*self._as_user, *command], capture_output=True, text=True, timeout=120
        )
        if done.returncode != 0:
            said = (done.stderr or done.stdout).strip()[-800:]
            raise PostgresUnavailable(f"{Path(command[0]).name} failed: {said}")

    def start(self) -> ThrowawayPostgres:
        """initdb, then pg_ctl start (waits until it accepts connections)."""
        bin_dir = server_bin()
        folder = Path(tempfile.mkdtemp(prefix="teachrepeat-pg-"))
        self.folder = folder
        try:
            if os.geteuid() == 0:
                try:
                    user = pwd.getpwnam("postgres")
                except KeyError as exc:
                    raise PostgresUnavailable(
                        "running as root, and PostgreSQL refuses to run as root: the user "
                        "'postgres' (made by the Debian package postgresql) does not exist"
                    ) from exc
                if shutil.which("runuser") is None:
                    raise PostgresUnavailable("running as root and runuser is missing")
                os.chown(folder, user.pw_uid, user.pw_gid)
                self._as_user = ["runuser", "-u", "postgres", "--"]
            secret = folder / "pw"
            secret.write_text(self.password + "\n")
            if self._as_user:
                user = pwd.getpwnam("postgres")
                os.chown(secret, user.pw_uid, user.pw_gid)
            secret.chmod(0o600)
            data = folder / "data"
            self._run(
                str(bin_dir / "initdb"),
                "-D",
                str(data),
                "-U",
                ROLE,
                "--pwfile",
                str(secret),
                "-A",
                "scram-sha-256",
                "-E",
                "UTF8",
                "--locale=C",
                "--no-sync",
            )
            secret.unlink()
            self.port = _free_port()
            options = [
                "-c listen_addresses=127.0.0.1",
                f"-c port={self.port}",
                f"-c unix_socket_directories={folder}",
                "-c max_connections=200",
            ]
            if not self.durable:
                options += [f"-c {o}" for o in FAST_OPTIONS]
            self._run(
                str(bin_dir / "pg_ctl"),
                "-D",
                str(data),
                "-l",
                str(folder / "server.log"),
                "-w",
                "-t",
                "60",
                "-o",
                " ".join(options),
                "start",
            )
        except BaseException:
            shutil.rmtree(folder, ignore_errors=True)
            self.folder = None
            raise
        return self

    def create_database(self, prefix: str = "t") -> str:
        """A new empty database; returns its URL."""
        import psycopg

        with self._lock:
            self._counter += 1
            name = f"{prefix}_{os.getpid()}_{self._counter}"
        with psycopg.connect(self.url(), autocommit=True) as conn:
            conn.execute(f'CREATE DATABASE "{name}"')
        return self.url(name)

    def stop(self) -> None:
        """Stop the server (immediately: its data is thrown away) and delete the folder."""
        if self.folder is None:
            return
        with contextlib.suppress(PostgresUnavailable, subprocess.TimeoutExpired):
            self._run(
                str(server_bin() / "pg_ctl"), "-D", str(self.folder / "data"), "-m", "immediate",
                "stop",
            )  # fmt: skip
        shutil.rmtree(self.folder, ignore_errors=True)
        self.folder = None

    def __enter__(self) -> ThrowawayPostgres:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def main() -> int:
    """Start a durable throw-away server, print its URL, run until Ctrl-C or SIGTERM."""
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        server = ThrowawayPostgres(durable=True).start()
    except PostgresUnavailable as exc:
        print(f"no PostgreSQL server: {exc}", flush=True)
        return 1
    try:
        print(server.url(), flush=True)
        print("(throw-away: stopped and deleted on Ctrl-C)", flush=True)
        with contextlib.suppress(KeyboardInterrupt):
            while not stop.wait(1.0):
                pass
    finally:
        server.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
