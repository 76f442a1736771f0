"""Shared fixtures: where the real image data lives.

The data folder comes from ``TEACHREPEAT_DATA`` (default: ``../shared/data`` beside the project).
In CI (``CI=true``) a missing data folder is an error, not a skip.
"""

from __future__ import annotations

import os
import sqlite3
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest
from fastapi.testclient import TestClient
from pydantic import SecretStr

if TYPE_CHECKING:
    from server.process import ServerProcess
    from server.storage.pgserver import ThrowawayPostgres

PROJECT_ROOT = Path(__file__).resolve().parent.parent


def pytest_configure(config: pytest.Config) -> None:
    """One thread for BLAS and OpenCV, as in every process of the server (server/threads.py):
    the tests' own computations and the servers they start sum in the same order. Hypothesis
    without its per-example deadline (200 ms): a property holds or not however loaded the
    machine is, and an example that took 338 ms on a busy 2-core machine failed a test that
    passes alone (speed is measured by benchmarks, never by tests)."""
    from hypothesis import settings

    from server.threads import pin_threads

    pin_threads()
    settings.register_profile("teachrepeat", deadline=None)
    settings.load_profile("teachrepeat")


def data_root() -> Path:
    return Path(os.environ.get("TEACHREPEAT_DATA", PROJECT_ROOT.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The read-only folder of real images (``corridor/``, ``nordland/``, ...)."""
    root = data_root()
    if not (root / "corridor").is_dir():
        message = f"real image data not found at {root}; set TEACHREPEAT_DATA"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(message)
        pytest.skip(message)
    return root


# --- API fixtures ---------------------------------------------------------------------------

ADMIN_TOKEN = "admin-secret-for-tests"


def make_jpeg(seed: int = 0, width: int = 64, height: int = 48) -> bytes:
    """A small real JPEG with random content."""
    from server.imaging import encode_jpeg

    rng = np.random.default_rng(seed)
    return encode_jpeg(rng.integers(0, 255, (height, width, 3), dtype=np.uint8))


def db_dump(path: Path) -> str:
    """Every row of every table but the audit log, as SQL text: equal dumps mean unchanged
    data. (A refused call is still audited: the log is meant to grow.)"""
    with sqlite3.connect(path) as conn:
        return "\n".join(
            line for line in conn.iterdump() if not line.startswith('INSERT INTO "audit"')
        )


@dataclass
class Api:
    client: TestClient
    db_path: Path
    admin: dict[str, str]

    def register(self, name: str = "rover") -> dict[str, str]:
        r = self.client.post("/robots", json={"name": name}, headers=self.admin)
        assert r.status_code == 201, r.text
        return {"Authorization": f"Bearer {r.json()['token']}"}

    def dump(self) -> str:
        return db_dump(self.db_path)


@pytest.fixture()
def api(tmp_path: Path) -> Iterator[Api]:
    """The app on a fresh SQLite file, driven in-process."""
    from server.app import create_app
    from server.config import Settings

    db_path = tmp_path / "api.sqlite"
    settings = Settings(db=db_path, admin_token=SecretStr(ADMIN_TOKEN), dashboard_port=None)
    with TestClient(create_app(settings)) as client:
        yield Api(client, db_path, {"Authorization": f"Bearer {ADMIN_TOKEN}"})


def serve_exits_2(
    db: Path, *args: str, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    """Run ``teachrepeat serve --port 0 --db db *args`` with no ``TEACHREPEAT_*`` setting but
    the admin token (and ``env``); assert it exits 2 with a message, not a traceback, and
    without printing the admin token; the finished process (its stdout and stderr)."""
    from server.process import ADMIN

    environment = {k: v for k, v in os.environ.items() if not k.startswith("TEACHREPEAT_")}
    environment.update({"TEACHREPEAT_ADMIN_TOKEN": ADMIN, **(env or {})})
    done = subprocess.run(
        [sys.executable, "-m", "server.cli", "serve", "--port", "0", "--db", str(db), *args],
        capture_output=True,
        text=True,
        env=environment,
        cwd=PROJECT_ROOT,
        timeout=60,
    )
    assert done.returncode == 2, done.stdout + done.stderr
    assert "Traceback" not in done.stderr, done.stderr
    assert ADMIN not in done.stderr + done.stdout
    return done


# --- PostgreSQL (docs/scale.md) -------------------------------------------------------------


@pytest.fixture(scope="session")
def postgres_server() -> Iterator[ThrowawayPostgres]:
    """One throw-away PostgreSQL server for the whole session (server.storage.pgserver); the
    tests that need it skip, saying why, where none can be started."""
    from server.storage.pgserver import PostgresUnavailable, ThrowawayPostgres

    try:
        import psycopg  # noqa: F401

        server = ThrowawayPostgres().start()
    except (PostgresUnavailable, ImportError) as exc:
        pytest.skip(f"PostgreSQL tests skipped: no PostgreSQL server could be started: {exc}")
    yield server
    server.stop()


@pytest.fixture()
def postgres_url(postgres_server: ThrowawayPostgres) -> str:
    """The URL of a new empty database on the session's PostgreSQL server."""
    return postgres_server.create_database()


@pytest.fixture(params=["sqlite", "postgresql"])
def store(request: pytest.FixtureRequest, tmp_path: Path) -> Path | str:
    """Where a storage test's database lives: a new SQLite file, then a new PostgreSQL
    database (the same test runs on both)."""
    if request.param == "sqlite":
        return tmp_path / "t.sqlite"
    return str(request.getfixturevalue("postgres_url"))


def assert_stored_in(server: ServerProcess, tour: int, counts: tuple[int, int]) -> None:
    """The tour's places and paths (``counts``) are in the database the real server was given
    (and, on PostgreSQL, no SQLite file was made instead)."""
    from server.storage.repo import Repo

    repo = Repo(server.database())
    try:
        assert repo.tour_counts(tour) == counts
    finally:
        repo.close()
    assert server.db.exists() == (server.database_url is None)
