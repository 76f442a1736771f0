"""Versioned schema migrations, each a decorated function run in its own transaction.

``migrate(db)`` applies every migration newer than the database's version, in order. A failed
migration rolls back whole and leaves the database at the previous version.

Migrations are written once, for SQLite and PostgreSQL alike: portable SQL through
``db.execute`` with ``?`` placeholders and SQLite's type names (``INTEGER PRIMARY KEY``,
``INTEGER``, ``TEXT``, ``REAL``, ``BLOB``), which :func:`server.storage.database.to_postgres`
translates on PostgreSQL. The version is kept the same way on both, in ``schema_migrations``.
Only a rebuild of a referenced table (migration 3) needs a PostgreSQL branch: there a table
others reference cannot be dropped, and ``ALTER TABLE`` changes it in place instead.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, TypeVar

Migration = Callable[[Any], None]
"""A function of a :class:`server.storage.database.Database` (or a plain sqlite-utils
``Database``) that changes the schema with ``db.execute``."""
M = TypeVar("M", bound=Migration)
MIGRATIONS: list[tuple[int, str, Migration, bool]] = []


def on_postgres(db: Any) -> bool:
    """Whether ``db`` is a PostgreSQL database (a migration's own branch)."""
    return getattr(db, "dialect", "sqlite") == "postgresql"


def migration(version: int, *, rebuilds: bool = False) -> Callable[[M], M]:
    """Register ``fn`` as the migration to schema ``version`` (strictly increasing).

    ``rebuilds``: the migration rebuilds tables that others reference (SQLite's way to change a
    constraint: create the new table, copy, drop, rename). It then runs with foreign keys off,
    as SQLite's documentation prescribes, so dropping the old table cascades nothing, and every
    reference is checked (``PRAGMA foreign_key_check``) before it commits. On PostgreSQL a
    rebuilding migration has its own branch (:func:`on_postgres`; module docstring)."""

    def register(fn: M) -> M:
        if MIGRATIONS and version <= MIGRATIONS[-1][0]:
            raise RuntimeError(f"migration {version} registered out of order")
        MIGRATIONS.append((version, fn.__name__, fn, rebuilds))
        return fn

    return register


@migration(1)
def initial_schema(db: Any) -> None:
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
def navigation_tasks(db: Any) -> None:
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


@migration(3, rebuilds=True)
def households(db: Any) -> None:
    """Households own robots and tours (and, through the tours, every image, location, edge and
    task). Everything that existed moves into household 1, ``default``, which has no password
    until the admin sets one. Tour names become unique per household; a robot token can be
    revoked (``token_hash`` NULL). Adds the household logins and the audit log."""
    now = time.time()
    db.execute(
        """
        CREATE TABLE households (
            id INTEGER PRIMARY KEY,
            name TEXT NOT NULL UNIQUE,
            password_hash TEXT,                -- argon2id; NULL = no login yet
            created_at REAL NOT NULL
        )"""
    )
    db.execute(
        "INSERT INTO households (id, name, password_hash, created_at) "
        "VALUES (1, 'default', NULL, ?)",
        (now,),
    )
    if on_postgres(db):
        _households_in_place(db)
    else:
        db.execute(
            """
            CREATE TABLE robots_new (
                name TEXT PRIMARY KEY,
                household_id INTEGER NOT NULL REFERENCES households(id),
                token_hash TEXT UNIQUE,        -- sha256 of the bearer token, hex; NULL = revoked
                token_issued_at REAL,
                created_at REAL NOT NULL
            )"""
        )
        db.execute(
            "INSERT INTO robots_new (name, household_id, token_hash, token_issued_at, created_at) "
            "SELECT name, 1, token_hash, created_at, created_at FROM robots"
        )
        db.execute("DROP TABLE robots")
        db.execute("ALTER TABLE robots_new RENAME TO robots")
        db.execute(
            """
            CREATE TABLE tours_new (
                id INTEGER PRIMARY KEY,
                household_id INTEGER NOT NULL REFERENCES households(id),
                name TEXT NOT NULL,
                created_at REAL NOT NULL,
                weights BLOB,                      -- learned signature weights (engine), float32
                weights_images INTEGER,            -- images the weights were learned from
                UNIQUE (household_id, name)
            )"""
        )
        db.execute(
            "INSERT INTO tours_new (id, household_id, name, created_at, weights, weights_images) "
            "SELECT id, 1, name, created_at, weights, weights_images FROM tours"
        )
        db.execute("DROP TABLE tours")
        db.execute("ALTER TABLE tours_new RENAME TO tours")
    db.execute(
        """
        CREATE TABLE logins (
            token_hash TEXT PRIMARY KEY,       -- sha256 of the session token, hex
            household_id INTEGER NOT NULL REFERENCES households(id) ON DELETE CASCADE,
            created_at REAL NOT NULL,
            expires_at REAL NOT NULL
        )"""
    )
    db.execute(
        """
        CREATE TABLE audit (
            id INTEGER PRIMARY KEY,
            at REAL NOT NULL,                  -- unix time, s
            actor TEXT NOT NULL,               -- admin, robot:<name>, household:<name>, ...
            action TEXT NOT NULL,              -- e.g. "POST /robots/{robot}/goto"
            target TEXT NOT NULL,              -- the path called (never a secret)
            status INTEGER NOT NULL,
            address TEXT
        )"""
    )
    db.execute("CREATE INDEX audit_at ON audit(at)")


def _households_in_place(db: Any) -> None:
    """Migration 3's table changes on PostgreSQL, where ``robots`` and ``tours`` cannot be
    dropped and renamed while other tables reference them: the same columns and constraints,
    made with ``ALTER TABLE`` (new columns come last; every query names its columns)."""
    for table in ("robots", "tours"):
        db.execute(
            f"ALTER TABLE {table} ADD COLUMN household_id INTEGER NOT NULL DEFAULT 1 "
            "REFERENCES households(id)"
        )
        db.execute(f"ALTER TABLE {table} ALTER COLUMN household_id DROP DEFAULT")
    db.execute("ALTER TABLE robots ALTER COLUMN token_hash DROP NOT NULL")
    db.execute("ALTER TABLE robots ADD COLUMN token_issued_at REAL")
    db.execute("UPDATE robots SET token_issued_at = created_at")
    db.execute("ALTER TABLE tours DROP CONSTRAINT tours_name_key")
    db.execute("ALTER TABLE tours ADD UNIQUE (household_id, name)")


@migration(4)
def image_poses_and_distinctiveness(db: Any) -> None:
    """Each image may carry the pose it was taken at (``pose_x``, ``pose_y`` metres,
    ``pose_theta`` radians, in the teaching robot's odometry frame; NULL when the robot sent
    none) and its distinctiveness (``entropy``: the entropy of its retrieval scores against the
    whole tour, nats, seed 000; NULL until computed). ``tours.entropy_images`` is the number of
    images the entropies were computed over. Columns are only added: nothing is lost."""
    for column in ("pose_x", "pose_y", "pose_theta", "entropy"):
        db.execute(f"ALTER TABLE images ADD COLUMN {column} REAL")
    db.execute("ALTER TABLE tours ADD COLUMN entropy_images INTEGER")


@migration(5)
def learned_changes(db: Any) -> None:
    """What the robot learned from its repeat runs, per tour, each change undoable
    (docs/learning.md). ``learned_changes``: one row per change, its ``kind`` ('transitions':
    ``counts`` holds the run's expected motion counts, ``(3, n_edges)`` float64; 'experience':
    its images are in ``experiences``), when and from which run (``source``, e.g. the robot and
    the task's start). ``experiences``: an image of a run kept as another appearance of a taught
    image (``image_id``), with its engine features. Tables are only added: nothing is lost."""
    db.execute(
        """
        CREATE TABLE learned_changes (
            id INTEGER PRIMARY KEY,
            tour_id INTEGER NOT NULL REFERENCES tours(id) ON DELETE CASCADE,
            kind TEXT NOT NULL CHECK (kind IN ('transitions', 'experience')),
            created_at REAL NOT NULL,
            source TEXT NOT NULL,              -- the run it came from
            summary TEXT NOT NULL,             -- one line for people
            counts BLOB                        -- 'transitions': float64 (3, n_edges)
        )"""
    )
    db.execute("CREATE INDEX learned_changes_tour ON learned_changes(tour_id)")
    db.execute(
        """
        CREATE TABLE experiences (
            id INTEGER PRIMARY KEY,
            change_id INTEGER NOT NULL REFERENCES learned_changes(id) ON DELETE CASCADE,
            image_id INTEGER NOT NULL REFERENCES images(id) ON DELETE CASCADE,
            features BLOB NOT NULL,            -- ImageFeatures.to_bytes()
            created_at REAL NOT NULL
        )"""
    )
    db.execute("CREATE INDEX experiences_image ON experiences(image_id)")


@migration(6)
def questions(db: Any) -> None:
    """Questions the robot asks a person (issue 25 parts 1 and 5, docs/learning.md), and the
    learned changes their answers make.

    ``questions``: one row per question of a robot on a tour, its ``kind`` ('same_place':
    "are we at the kitchen?" while teaching; 'new_path': "keep the way I just found from the
    hall to the kitchen?"), the place asked about (``location_id``; for a new path its end)
    and where the robot came from (``source_location_id``), the frame asked at and the
    place's image it matched (``image_id``, ``match_image_id``), when it was asked and when it
    expires (unix seconds), its ``state`` ('open', 'yes', 'no', 'expired', 'withdrawn') and
    the change its answer made (``change_id``). ``question_frames``: the frames of a proposed
    new path until it is answered. ``look_alikes``: a 'no' answer's pair of images that looked
    like the same place but are not.

    ``learned_changes`` is rebuilt (portable SQL: create, copy, drop, rename, with
    ``experiences`` that references it) to drop the CHECK on ``kind`` (the kinds are listed in
    :data:`server.storage.repo.LEARNED_KINDS`; a CHECK would need a rebuild for every new
    kind) and to add ``edge_id``: the edge a loop closure or a new path added, removed with
    the change. Every row is kept."""
    db.execute(
        """
        CREATE TABLE learned_changes_v6 (
            id INTEGER PRIMARY KEY,
            tour_id INTEGER NOT NULL REFERENCES tours(id) ON DELETE CASCADE,
            kind TEXT NOT NULL,                -- repo.LEARNED_KINDS
            created_at REAL NOT NULL,
            source TEXT NOT NULL,              -- the run or question it came from
            summary TEXT NOT NULL,             -- one line for people
            counts BLOB,                       -- 'transitions': float64 (3, n_edges)
            edge_id INTEGER REFERENCES edges(id)  -- 'loop_closure', 'new_path': the edge added
        )"""
    )
    db.execute(
        "INSERT INTO learned_changes_v6 (id, tour_id, kind, created_at, source, summary, counts) "
        "SELECT id, tour_id, kind, created_at, source, summary, counts FROM learned_changes"
    )
    db.execute(
        """
        CREATE TABLE experiences_v6 (
            id INTEGER PRIMARY KEY,
            change_id INTEGER NOT NULL REFERENCES learned_changes_v6(id) ON DELETE CASCADE,
            image_id INTEGER NOT NULL REFERENCES images(id) ON DELETE CASCADE,
            features BLOB NOT NULL,            -- ImageFeatures.to_bytes()
            created_at REAL NOT NULL
        )"""
    )
    db.execute(
        "INSERT INTO experiences_v6 (id, change_id, image_id, features, created_at) "
        "SELECT id, change_id, image_id, features, created_at FROM experiences"
    )
    db.execute("DROP TABLE experiences")
    db.execute("DROP TABLE learned_changes")
    db.execute("ALTER TABLE learned_changes_v6 RENAME TO learned_changes")
    db.execute("ALTER TABLE experiences_v6 RENAME TO experiences")
    db.execute("CREATE INDEX learned_changes_tour ON learned_changes(tour_id)")
    db.execute("CREATE INDEX experiences_image ON experiences(image_id)")
    db.execute(
        """
        CREATE TABLE questions (
            id INTEGER PRIMARY KEY,
            robot TEXT NOT NULL REFERENCES robots(name) ON DELETE CASCADE,
            tour_id INTEGER NOT NULL REFERENCES tours(id) ON DELETE CASCADE,
            kind TEXT NOT NULL,                -- 'same_place' | 'new_path'
            text TEXT NOT NULL,                -- the question as a person reads it
            location_id INTEGER NOT NULL REFERENCES locations(id) ON DELETE CASCADE,
            source_location_id INTEGER REFERENCES locations(id) ON DELETE CASCADE,
            image_id INTEGER REFERENCES images(id) ON DELETE SET NULL,
            match_image_id INTEGER REFERENCES images(id) ON DELETE SET NULL,
            confidence REAL NOT NULL,          -- the belief's mass at the place, 0..1
            created_at REAL NOT NULL,          -- unix time, s
            expires_at REAL NOT NULL,          -- unix time, s
            state TEXT NOT NULL,               -- open | yes | no | expired | withdrawn
            answered_at REAL,
            change_id INTEGER REFERENCES learned_changes(id) ON DELETE SET NULL
        )"""
    )
    db.execute("CREATE INDEX questions_robot ON questions(robot, state)")
    db.execute(
        """
        CREATE TABLE question_frames (
            id INTEGER PRIMARY KEY,
            question_id INTEGER NOT NULL REFERENCES questions(id) ON DELETE CASCADE,
            seq INTEGER NOT NULL,
            timestamp REAL NOT NULL,           -- capture time, s
            v REAL NOT NULL,                   -- m/s
            w REAL NOT NULL,                   -- rad/s
            width INTEGER NOT NULL,
            height INTEGER NOT NULL,
            jpeg BLOB NOT NULL,
            features BLOB                      -- engine features
        )"""
    )
    db.execute("CREATE INDEX question_frames_question ON question_frames(question_id, seq)")
    db.execute(
        """
        CREATE TABLE look_alikes (
            id INTEGER PRIMARY KEY,
            change_id INTEGER NOT NULL REFERENCES learned_changes(id) ON DELETE CASCADE,
            location_id INTEGER NOT NULL REFERENCES locations(id) ON DELETE CASCADE,
            image_id INTEGER REFERENCES images(id) ON DELETE SET NULL,  -- the frame
            match_image_id INTEGER NOT NULL REFERENCES images(id) ON DELETE CASCADE
        )"""
    )
    db.execute("CREATE INDEX look_alikes_location ON look_alikes(location_id)")


@migration(7)
def junctions(db: Any) -> None:
    """Junctions learned from shared path prefixes (issue 25 part 2, docs/learning.md): a
    learned change of kind 'junction' refines the tour's graph when its runtime is built; the
    taught places, edges and images stay as they are. ``junctions``: one row per change, the
    edges it splits named by their first image (``keep_image_id``: the edge whose shared images
    are kept, ``other_image_id``: the edge whose shared images are mapped onto them), how many
    images of each are shared and ``mapping`` (int32 ``(other_shared,)``: the index among the
    kept shared images each mapped image stands for). The kind needs no change of
    ``learned_changes``: migration 6 took the CHECK on ``kind`` away."""
    db.execute(
        """
        CREATE TABLE junctions (
            id INTEGER PRIMARY KEY,
            change_id INTEGER NOT NULL REFERENCES learned_changes(id) ON DELETE CASCADE,
            keep_image_id INTEGER NOT NULL REFERENCES images(id) ON DELETE CASCADE,
            other_image_id INTEGER NOT NULL REFERENCES images(id) ON DELETE CASCADE,
            keep_shared INTEGER NOT NULL,      -- images of the kept edge before the junction
            other_shared INTEGER NOT NULL,     -- images of the other edge before the junction
            mapping BLOB NOT NULL              -- int32 (other_shared,)
        )"""
    )
    db.execute("CREATE INDEX junctions_change ON junctions(change_id)")


@migration(8)
def belief_memory(db: Any) -> None:
    """What the tracker remembers besides the belief (``navigation.belief_memory``, JSON of
    :class:`server.belief.tracker.TrackerMemory`: the belief over appearance models, the
    running familiarity, the evidence EMAs), saved with each belief snapshot so a restarted
    server resumes the whole filter, not only its belief. NULL in older rows: the tracker
    then starts its memory afresh, as before. A column is only added: nothing is lost."""
    db.execute("ALTER TABLE navigation ADD COLUMN belief_memory TEXT")


@migration(9)
def image_depth(db: Any) -> None:
    """The depth profile a robot sent with a taught image (``images.depth``: float32
    little-endian ranges in metres, left to right; NULL when it sent none, as in older rows).
    Topometric repeat matches a frame's profile against the taught image's to tell how far
    beside the taught path the robot stands. A column is only added: nothing is lost."""
    db.execute("ALTER TABLE images ADD COLUMN depth BLOB")


@migration(10)
def removed_learned_kinds(db: Any) -> None:
    """Learned transitions, experiences and junctions were removed (issue 41 part 8,
    docs/learning.md, "Removed"): each was measured on top of the tracker with no gain, and
    the server no longer reads or makes them. Their learned changes (kinds 'transitions',
    'experience' and 'junction') are deleted, with their rows in ``experiences`` and
    ``junctions`` (the references cascade), and both tables are dropped. The changes that
    answers to questions make ('loop_closure', 'look_alike', 'new_path') are kept as they were,
    with their ids; nothing else changes. ``learned_changes.counts`` (only 'transitions' used
    it) stays, NULL in every row: dropping a column needs SQLite 3.35, which older systems'
    Python does not have."""
    db.execute(
        "DELETE FROM learned_changes WHERE kind IN ('transitions', 'experience', 'junction')"
    )
    db.execute("DROP TABLE junctions")
    db.execute("DROP TABLE experiences")


def current_version(db: Any) -> int:
    if "schema_migrations" not in db.table_names():
        return 0
    row = db.execute("SELECT MAX(version) FROM schema_migrations").fetchone()
    return int(row[0] or 0)


SCHEMA_MIGRATIONS = (
    "CREATE TABLE IF NOT EXISTS schema_migrations "
    "(version INTEGER PRIMARY KEY, name TEXT NOT NULL, applied_at REAL NOT NULL)"
)


def migrate(db: Any, upto: int | None = None) -> int:
    """Bring ``db`` (SQLite or PostgreSQL, :mod:`server.storage.database`) to the newest schema
    (or to version ``upto``: tests build old databases with it); returns the version it ends
    at. Several processes may start together: one migrates, the others wait and see it done."""
    if on_postgres(db):
        return _migrate_postgres(db, upto)
    conn = db.conn
    conn.execute(SCHEMA_MIGRATIONS)
    version = current_version(db)
    for number, name, fn, rebuilds in _pending(version, upto):
        keys_on = bool(conn.execute("PRAGMA foreign_keys").fetchone()[0])
        if rebuilds:
            conn.execute("PRAGMA foreign_keys = OFF")  # a no-op inside a transaction
        conn.execute("BEGIN IMMEDIATE")
        if current_version(db) >= number:  # another process applied it while we waited
            conn.execute("ROLLBACK")
            if rebuilds and keys_on:
                conn.execute("PRAGMA foreign_keys = ON")
            version = number
            continue
        try:
            fn(db)
            broken = conn.execute("PRAGMA foreign_key_check").fetchall() if rebuilds else []
            if broken:
                raise RuntimeError(f"migration {number} broke references: {broken[:5]}")
            _record(db, number, name)
        except BaseException:
            conn.execute("ROLLBACK")
            raise
        else:
            conn.execute("COMMIT")
        finally:
            if rebuilds and keys_on:
                conn.execute("PRAGMA foreign_keys = ON")
        version = number
    return version


def _migrate_postgres(db: Any, upto: int | None) -> int:
    """:func:`migrate` on PostgreSQL: DDL is transactional there, so each migration commits
    whole or not at all; the write lock (``begin_write``) makes concurrent starts wait."""
    db.begin_write()
    try:
        db.execute(SCHEMA_MIGRATIONS)
    except BaseException:
        db.rollback()
        raise
    db.commit()
    version = current_version(db)
    for number, name, fn, _ in _pending(version, upto):
        db.begin_write()
        try:
            if current_version(db) < number:  # else another process applied it meanwhile
                fn(db)
                db.sync_identities()  # rows inserted with their id (migration 3's household)
                _record(db, number, name)
        except BaseException:
            db.rollback()
            raise
        db.commit()
        version = number
    return version


def _pending(version: int, upto: int | None) -> list[tuple[int, str, Migration, bool]]:
    return [m for m in MIGRATIONS if m[0] > version and (upto is None or m[0] <= upto)]


def _record(db: Any, number: int, name: str) -> None:
    db.execute(
        "INSERT INTO schema_migrations (version, name, applied_at) VALUES (?, ?, ?)",
        (number, name, time.time()),
    )
