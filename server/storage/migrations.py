"""Versioned schema migrations, each a decorated function run in its own transaction.

``migrate(db)`` applies every migration newer than the database's version, in order. A failed
migration rolls back whole and leaves the database at the previous version.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import sqlite_utils

Migration = Callable[[sqlite_utils.Database], None]
MIGRATIONS: list[tuple[int, str, Migration]] = []


def migration(version: int) -> Callable[[Migration], Migration]:
    """Register ``fn`` as the migration to schema ``version`` (strictly increasing)."""

    def register(fn: Migration) -> Migration:
        if MIGRATIONS and version <= MIGRATIONS[-1][0]:
            raise RuntimeError(f"migration {version} registered out of order")
        MIGRATIONS.append((version, fn.__name__, fn))
        return fn

    return register


@migration(1)
def initial_schema(db: sqlite_utils.Database) -> None:
    """Tours, locations, edges, images, robots and the teaching state of each robot."""
    db.execute(
        """
        CREATE TABLE tours (
            id INTEGER PRIMARY KEY,
            name TEXT NOT NULL UNIQUE,
            created_at REAL NOT NULL,
            weights BLOB,                      -- learned signature weights (engine), float32
            weights_images INTEGER             -- images the weights were learned from
        )"""
    )
    db.execute(
        """
        CREATE TABLE robots (
            name TEXT PRIMARY KEY,
            token_hash TEXT NOT NULL UNIQUE,   -- sha256 of the bearer token, hex
            created_at REAL NOT NULL
        )"""
    )
    db.execute(
        """
        CREATE TABLE locations (
            id INTEGER PRIMARY KEY,
            tour_id INTEGER NOT NULL REFERENCES tours(id) ON DELETE CASCADE,
            name TEXT NOT NULL,
            created_at REAL NOT NULL,
            UNIQUE (tour_id, name)
        )"""
    )
    db.execute(
        """
        CREATE TABLE edges (
            id INTEGER PRIMARY KEY,
            tour_id INTEGER NOT NULL REFERENCES tours(id) ON DELETE CASCADE,
            source_id INTEGER NOT NULL REFERENCES locations(id),
            target_id INTEGER NOT NULL REFERENCES locations(id),
            created_at REAL NOT NULL
        )"""
    )
    db.execute(
        """
        CREATE TABLE images (
            id INTEGER PRIMARY KEY,
            tour_id INTEGER NOT NULL REFERENCES tours(id) ON DELETE CASCADE,
            location_id INTEGER REFERENCES locations(id),
            edge_id INTEGER REFERENCES edges(id),
            pending_robot TEXT REFERENCES robots(name),  -- on the robot's open path
            seq INTEGER NOT NULL,               -- order within its owner
            timestamp REAL NOT NULL,            -- capture time, s
            v REAL NOT NULL,                    -- linear velocity when captured, m/s
            w REAL NOT NULL,                    -- angular velocity when captured, rad/s
            width INTEGER NOT NULL,
            height INTEGER NOT NULL,
            jpeg BLOB NOT NULL,
            features BLOB,                      -- engine features, filled lazily
            CHECK ((location_id IS NOT NULL) + (edge_id IS NOT NULL)
                   + (pending_robot IS NOT NULL) = 1)
        )"""
    )
    db.execute("CREATE INDEX images_location ON images(location_id, seq)")
    db.execute("CREATE INDEX images_edge ON images(edge_id, seq)")
    db.execute("CREATE INDEX images_pending ON images(pending_robot, seq)")
    db.execute("CREATE INDEX images_tour ON images(tour_id)")
    db.execute(
        """
        CREATE TABLE teaching (
            robot TEXT PRIMARY KEY REFERENCES robots(name) ON DELETE CASCADE,
            tour_id INTEGER NOT NULL REFERENCES tours(id) ON DELETE CASCADE,
            current_location_id INTEGER REFERENCES locations(id),
            last_timestamp REAL,
            started_at REAL NOT NULL
        )"""
    )


@migration(2)
def navigation_tasks(db: sqlite_utils.Database) -> None:
    """Each robot's tour, its current or last navigation task and a belief snapshot, so a
    restarted server resumes navigation instead of starting from a uniform belief."""
    db.execute(
        """
        CREATE TABLE navigation (
            robot TEXT PRIMARY KEY REFERENCES robots(name) ON DELETE CASCADE,
            tour_id INTEGER NOT NULL REFERENCES tours(id) ON DELETE CASCADE,
            task_id INTEGER NOT NULL,
            goal_location_id INTEGER NOT NULL REFERENCES locations(id),
            state TEXT NOT NULL CHECK (state IN ('underway', 'arrived', 'failed', 'cancelled')),
            reason TEXT,
            started_at REAL NOT NULL,
            ended_at REAL,
            steps INTEGER NOT NULL DEFAULT 0,
            belief BLOB,                       -- (n_fine,) float32 snapshot
            belief_images INTEGER,             -- tour images when the snapshot was taken
            belief_at REAL
        )"""
    )


def current_version(db: sqlite_utils.Database) -> int:
    if "schema_migrations" not in db.table_names():
        return 0
    row = db.execute("SELECT MAX(version) FROM schema_migrations").fetchone()
    return int(row[0] or 0)


def migrate(db: sqlite_utils.Database) -> int:
    """Bring ``db`` to the newest schema; returns the version it ends at."""
    conn = db.conn
    conn.execute(
        "CREATE TABLE IF NOT EXISTS schema_migrations "
        "(version INTEGER PRIMARY KEY, name TEXT NOT NULL, applied_at REAL NOT NULL)"
    )
    version = current_version(db)
    for number, name, fn in MIGRATIONS:
        if number <= version:
            continue
        conn.execute("BEGIN IMMEDIATE")
        try:
            fn(db)
            conn.execute(
                "INSERT INTO schema_migrations (version, name, applied_at) VALUES (?, ?, ?)",
                (number, name, time.time()),
            )
        except BaseException:
            conn.execute("ROLLBACK")
            raise
        conn.execute("COMMIT")
        version = number
    return version
