"""All SQL lives here: typed functions over one SQLite file (sqlite-utils), nothing else does I/O.

The database runs in WAL mode with foreign keys on. One connection is shared by the threads of
the server behind a re-entrant lock; :meth:`Repo.transaction` wraps a service call so that
every teaching step that changes the graph commits whole or not at all.
"""

from __future__ import annotations

import sqlite3
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import sqlite_utils

from server.domain import Edge, Location, TourGraph
from server.errors import NotFound, Unavailable
from server.storage.migrations import migrate


@dataclass(frozen=True)
class TourRow:
    id: int
    name: str
    created_at: float


@dataclass(frozen=True)
class LocationRow:
    id: int
    tour_id: int
    name: str
    image_ids: tuple[int, ...]


@dataclass(frozen=True)
class EdgeRow:
    id: int
    tour_id: int
    source_id: int
    target_id: int
    image_ids: tuple[int, ...]
    timestamps: tuple[float, ...]
    v: tuple[float, ...]
    w: tuple[float, ...]

    @property
    def duration(self) -> float:
        return self.timestamps[-1] - self.timestamps[0] if len(self.timestamps) > 1 else 0.0

    @property
    def length(self) -> float:
        """Metres driven while taught: ``sum |v_k| (t_{k+1} - t_k)``."""
        t = self.timestamps
        return float(sum(abs(self.v[k]) * (t[k + 1] - t[k]) for k in range(len(t) - 1)))


@dataclass(frozen=True)
class ImageMeta:
    id: int
    tour_id: int
    width: int
    height: int
    timestamp: float


@dataclass(frozen=True)
class RobotRow:
    name: str
    created_at: float


@dataclass(frozen=True)
class TeachingRow:
    robot: str
    tour_id: int
    current_location_id: int | None
    last_timestamp: float | None
    started_at: float


@dataclass(frozen=True)
class NavigationRow:
    robot: str
    tour_id: int
    task_id: int
    goal_location_id: int
    state: str
    reason: str | None
    started_at: float
    ended_at: float | None
    steps: int
    belief: bytes | None = None
    belief_images: int | None = None


class Repo:
    """Typed access to one teachrepeat database file (or ``":memory:"``)."""

    def __init__(self, path: Path | str) -> None:
        if str(path) != ":memory:":
            Path(path).parent.mkdir(parents=True, exist_ok=True)
        conn = sqlite3.connect(str(path), check_same_thread=False, isolation_level=None)
        conn.execute("PRAGMA foreign_keys = ON")
        conn.execute("PRAGMA busy_timeout = 5000")
        self.db = sqlite_utils.Database(conn)
        if str(path) != ":memory:":
            self.db.enable_wal()
            conn.execute("PRAGMA synchronous = NORMAL")
        self._lock = threading.RLock()
        self._depth = 0
        self._reading = False  # the open outer transaction is a read snapshot
        self.schema_version = migrate(self.db)

    def close(self) -> None:
        with self._lock:
            self.db.conn.close()

    # --- transactions ---------------------------------------------------------------------

    @contextmanager
    def transaction(self) -> Iterator[None]:
        """All statements inside commit together or not at all; nesting joins the outer one."""
        with self._lock:
            if self._reading:
                raise RuntimeError("a write transaction cannot be nested in a read snapshot")
            outer = self._depth == 0
            if outer:
                self._execute_guarded("BEGIN IMMEDIATE")
            self._depth += 1
            try:
                yield
            except BaseException:
                self._depth -= 1
                if outer and self.db.conn.in_transaction:  # SQLITE_FULL already rolled back
                    self.db.conn.execute("ROLLBACK")
                raise
            self._depth -= 1
            if outer:
                self._execute_guarded("COMMIT")

    @contextmanager
    def snapshot(self) -> Iterator[None]:
        """Reads inside see one consistent state of the file and write nothing.

        A deferred transaction: unlike :meth:`transaction` it takes no write lock, so it keeps
        working on a read-only file. Inside a transaction it joins it; a transaction inside a
        snapshot is a programming error (``RuntimeError``).
        """
        with self._lock:
            outer = self._depth == 0
            if outer:
                self._execute_guarded("BEGIN DEFERRED")
                self._reading = True
            self._depth += 1
            try:
                yield
            finally:
                self._depth -= 1
                if outer:
                    self._reading = False
                    if self.db.conn.in_transaction:
                        self.db.conn.execute("COMMIT")  # ends the read; nothing was written

    def _execute_guarded(self, sql: str) -> None:
        try:
            with _guard():
                self.db.conn.execute(sql)
        except BaseException:
            if sql == "COMMIT" and self.db.conn.in_transaction:
                self.db.conn.execute("ROLLBACK")
            raise

    def _q(self, sql: str, params: Sequence[object] = ()) -> list[tuple]:
        with self._lock, _guard():
            return self.db.conn.execute(sql, params).fetchall()

    def _x(self, sql: str, params: Sequence[object] = ()) -> int:
        """Execute a write; returns lastrowid. Call inside :meth:`transaction`."""
        with self._lock, _guard():
            if self._reading:
                raise RuntimeError("a write inside a read snapshot; use Repo.transaction()")
            return int(self.db.conn.execute(sql, params).lastrowid or 0)

    def integrity_ok(self) -> bool:
        return self._q("PRAGMA integrity_check")[0][0] == "ok"

    # --- robots ---------------------------------------------------------------------------

    def add_robot(self, name: str, token_hash: str) -> RobotRow:
        now = time.time()
        self._x(
            "INSERT INTO robots (name, token_hash, created_at) VALUES (?, ?, ?)",
            (name, token_hash, now),
        )
        return RobotRow(name, now)

    def robot(self, name: str) -> RobotRow:
        rows = self._q("SELECT name, created_at FROM robots WHERE name = ?", (name,))
        if not rows:
            raise NotFound(f"no robot named {name!r}; register it with POST /robots (admin)")
        return RobotRow(*rows[0])

    def robot_exists(self, name: str) -> bool:
        return bool(self._q("SELECT 1 FROM robots WHERE name = ?", (name,)))

    def robot_by_token_hash(self, token_hash: str) -> str | None:
        rows = self._q("SELECT name FROM robots WHERE token_hash = ?", (token_hash,))
        return rows[0][0] if rows else None

    def robots(self) -> list[RobotRow]:
        return [RobotRow(*r) for r in self._q("SELECT name, created_at FROM robots ORDER BY name")]

    # --- tours ----------------------------------------------------------------------------

    def add_tour(self, name: str) -> TourRow:
        now = time.time()
        tid = self._x("INSERT INTO tours (name, created_at) VALUES (?, ?)", (name, now))
        return TourRow(tid, name, now)

    def tour(self, tour_id: int) -> TourRow:
        rows = self._q("SELECT id, name, created_at FROM tours WHERE id = ?", (tour_id,))
        if not rows:
            raise NotFound(f"no tour with id {tour_id}; GET /tours lists the tours")
        return TourRow(*rows[0])

    def tour_by_name(self, name: str) -> TourRow | None:
        rows = self._q("SELECT id, name, created_at FROM tours WHERE name = ?", (name,))
        return TourRow(*rows[0]) if rows else None

    def tours(self) -> list[tuple[TourRow, int, int, int]]:
        """Every tour with its numbers of locations, edges and stored (non-pending) images."""
        rows = self._q(
            """
            SELECT t.id, t.name, t.created_at,
                   (SELECT COUNT(*) FROM locations l WHERE l.tour_id = t.id),
                   (SELECT COUNT(*) FROM edges e WHERE e.tour_id = t.id),
                   (SELECT COUNT(*) FROM images i WHERE i.tour_id = t.id
                                                   AND i.pending_robot IS NULL)
            FROM tours t ORDER BY t.id"""
        )
        return [(TourRow(r[0], r[1], r[2]), r[3], r[4], r[5]) for r in rows]

    def tour_counts(self, tour_id: int) -> tuple[int, int]:
        """Numbers of locations and of edges of one tour."""
        row = self._q(
            "SELECT (SELECT COUNT(*) FROM locations WHERE tour_id = ?), "
            "(SELECT COUNT(*) FROM edges WHERE tour_id = ?)",
            (tour_id, tour_id),
        )[0]
        return int(row[0]), int(row[1])

    def tour_weights(self, tour_id: int) -> tuple[bytes | None, int | None]:
        rows = self._q("SELECT weights, weights_images FROM tours WHERE id = ?", (tour_id,))
        if not rows:
            raise NotFound(f"no tour with id {tour_id}")
        return rows[0][0], rows[0][1]

    def set_tour_weights(self, tour_id: int, weights: bytes, n_images: int) -> None:
        with self.transaction():
            self._x(
                "UPDATE tours SET weights = ?, weights_images = ? WHERE id = ?",
                (weights, n_images, tour_id),
            )

    # --- locations and edges --------------------------------------------------------------

    def locations(self, tour_id: int) -> list[LocationRow]:
        locs = self._q("SELECT id, name FROM locations WHERE tour_id = ? ORDER BY id", (tour_id,))
        images = self._q(
            "SELECT location_id, id FROM images WHERE tour_id = ? AND location_id IS NOT NULL "
            "ORDER BY location_id, seq",
            (tour_id,),
        )
        by_loc: dict[int, list[int]] = {}
        for loc_id, image_id in images:
            by_loc.setdefault(loc_id, []).append(image_id)
        return [LocationRow(i, tour_id, n, tuple(by_loc.get(i, ()))) for i, n in locs]

    def location_by_name(self, tour_id: int, name: str) -> int | None:
        rows = self._q("SELECT id FROM locations WHERE tour_id = ? AND name = ?", (tour_id, name))
        return rows[0][0] if rows else None

    def location_name(self, location_id: int) -> str:
        rows = self._q("SELECT name FROM locations WHERE id = ?", (location_id,))
        if not rows:
            raise NotFound(f"no location with id {location_id}")
        return str(rows[0][0])

    def add_location(self, tour_id: int, name: str) -> int:
        return self._x(
            "INSERT INTO locations (tour_id, name, created_at) VALUES (?, ?, ?)",
            (tour_id, name, time.time()),
        )

    def edges(self, tour_id: int) -> list[EdgeRow]:
        heads = self._q(
            "SELECT id, source_id, target_id FROM edges WHERE tour_id = ? ORDER BY id", (tour_id,)
        )
        images = self._q(
            "SELECT edge_id, id, timestamp, v, w FROM images "
            "WHERE tour_id = ? AND edge_id IS NOT NULL ORDER BY edge_id, seq",
            (tour_id,),
        )
        by_edge: dict[int, list[tuple[int, float, float, float]]] = {}
        for edge_id, image_id, ts, v, w in images:
            by_edge.setdefault(edge_id, []).append((image_id, ts, v, w))
        out = []
        for edge_id, src, dst in heads:
            rows = by_edge.get(edge_id, [])
            out.append(
                EdgeRow(
                    edge_id,
                    tour_id,
                    src,
                    dst,
                    tuple(r[0] for r in rows),
                    tuple(r[1] for r in rows),
                    tuple(r[2] for r in rows),
                    tuple(r[3] for r in rows),
                )
            )
        return out

    def add_edge(self, tour_id: int, source_id: int, target_id: int) -> int:
        return self._x(
            "INSERT INTO edges (tour_id, source_id, target_id, created_at) VALUES (?, ?, ?, ?)",
            (tour_id, source_id, target_id, time.time()),
        )

    def graph(self, tour_id: int) -> TourGraph:
        """The tour as the pure core sees it (locations and edges in id order)."""
        locs = self.locations(tour_id)
        index = {loc.id: k for k, loc in enumerate(locs)}
        return TourGraph(
            locations=tuple(Location(loc.name, loc.image_ids, loc.id) for loc in locs),
            edges=tuple(
                Edge(
                    source=index[e.source_id],
                    target=index[e.target_id],
                    image_ids=e.image_ids,
                    timestamps=np.asarray(e.timestamps, dtype=np.float64),
                    v=np.asarray(e.v, dtype=np.float64),
                    w=np.asarray(e.w, dtype=np.float64),
                    id=e.id,
                )
                for e in self.edges(tour_id)
            ),
        )

    # --- images ---------------------------------------------------------------------------

    def add_image(
        self,
        *,
        tour_id: int,
        jpeg: bytes,
        width: int,
        height: int,
        timestamp: float,
        v: float,
        w: float,
        location_id: int | None = None,
        pending_robot: str | None = None,
    ) -> int:
        """Store one image, owned by a location (spin image) or a robot's open path."""
        owner: str
        value: int | str | None
        if location_id is not None:
            owner, value = "location_id", location_id
        else:
            owner, value = "pending_robot", pending_robot
        seq = self._q(f"SELECT COALESCE(MAX(seq), -1) + 1 FROM images WHERE {owner} = ?", (value,))
        return self._x(
            f"INSERT INTO images (tour_id, {owner}, seq, timestamp, v, w, width, height, jpeg) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (tour_id, value, seq[0][0], timestamp, v, w, width, height, jpeg),
        )

    def image_jpeg(self, image_id: int) -> bytes:
        rows = self._q("SELECT jpeg FROM images WHERE id = ?", (image_id,))
        if not rows:
            raise NotFound(f"no image with id {image_id}")
        return bytes(rows[0][0])

    def image_meta(self, image_id: int) -> ImageMeta:
        rows = self._q(
            "SELECT id, tour_id, width, height, timestamp FROM images WHERE id = ?", (image_id,)
        )
        if not rows:
            raise NotFound(f"no image with id {image_id}")
        return ImageMeta(*rows[0])

    def pending_count(self, robot: str) -> int:
        return int(self._q("SELECT COUNT(*) FROM images WHERE pending_robot = ?", (robot,))[0][0])

    def pending_timestamps(self, robot: str) -> list[float]:
        rows = self._q(
            "SELECT timestamp FROM images WHERE pending_robot = ? ORDER BY seq", (robot,)
        )
        return [r[0] for r in rows]

    def move_pending_to_edge(self, robot: str, edge_id: int) -> int:
        """Hand the robot's open path to ``edge_id``, keeping the order; returns the count."""
        with self._lock, _guard():
            cur = self.db.conn.execute(
                "UPDATE images SET edge_id = ?, pending_robot = NULL WHERE pending_robot = ?",
                (edge_id, robot),
            )
            return int(cur.rowcount)

    def discard_pending(self, robot: str) -> int:
        with self._lock, _guard():
            cur = self.db.conn.execute("DELETE FROM images WHERE pending_robot = ?", (robot,))
            return int(cur.rowcount)

    def features(self, image_ids: Sequence[int]) -> dict[int, bytes | None]:
        """Stored engine features of the given images (``None`` where not extracted yet)."""
        out: dict[int, bytes | None] = {}
        ids = list(image_ids)
        for start in range(0, len(ids), 500):
            chunk = ids[start : start + 500]
            marks = ",".join("?" * len(chunk))
            for image_id, blob in self._q(
                f"SELECT id, features FROM images WHERE id IN ({marks})", chunk
            ):
                out[image_id] = None if blob is None else bytes(blob)
        return out

    def set_features(self, items: Sequence[tuple[int, bytes]]) -> None:
        with self.transaction(), self._lock, _guard():
            self.db.conn.executemany(
                "UPDATE images SET features = ? WHERE id = ?", [(b, i) for i, b in items]
            )

    # --- teaching state -------------------------------------------------------------------

    def teaching(self, robot: str) -> TeachingRow | None:
        rows = self._q(
            "SELECT robot, tour_id, current_location_id, last_timestamp, started_at "
            "FROM teaching WHERE robot = ?",
            (robot,),
        )
        return TeachingRow(*rows[0]) if rows else None

    def start_teaching(self, robot: str, tour_id: int) -> None:
        self._x(
            "INSERT INTO teaching (robot, tour_id, started_at) VALUES (?, ?, ?)",
            (robot, tour_id, time.time()),
        )

    def set_teaching(
        self, robot: str, *, current_location_id: int | None, last_timestamp: float | None
    ) -> None:
        self._x(
            "UPDATE teaching SET current_location_id = ?, last_timestamp = ? WHERE robot = ?",
            (current_location_id, last_timestamp, robot),
        )

    def end_teaching(self, robot: str) -> None:
        self._x("DELETE FROM teaching WHERE robot = ?", (robot,))

    # --- navigation ---------------------------------------------------------------------

    def navigation(self, robot: str) -> NavigationRow | None:
        rows = self._q(
            "SELECT robot, tour_id, task_id, goal_location_id, state, reason, started_at, "
            "ended_at, steps, belief, belief_images FROM navigation WHERE robot = ?",
            (robot,),
        )
        if not rows:
            return None
        r = rows[0]
        return NavigationRow(
            robot=r[0],
            tour_id=r[1],
            task_id=r[2],
            goal_location_id=r[3],
            state=r[4],
            reason=r[5],
            started_at=r[6],
            ended_at=r[7],
            steps=r[8],
            belief=None if r[9] is None else bytes(r[9]),
            belief_images=r[10],
        )

    def next_task_id(self) -> int:
        return int(self._q("SELECT COALESCE(MAX(task_id), 0) + 1 FROM navigation")[0][0])

    def save_navigation(self, row: NavigationRow) -> None:
        """Insert or replace the robot's navigation row (one transaction)."""
        with self.transaction():
            self._x(
                "INSERT OR REPLACE INTO navigation (robot, tour_id, task_id, goal_location_id, "
                "state, reason, started_at, ended_at, steps, belief, belief_images, belief_at) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (
                    row.robot,
                    row.tour_id,
                    row.task_id,
                    row.goal_location_id,
                    row.state,
                    row.reason,
                    row.started_at,
                    row.ended_at,
                    row.steps,
                    row.belief,
                    row.belief_images,
                    time.time(),
                ),
            )

    def short_edges(self) -> list[int]:
        """Ids of edges with fewer than 2 images (must always be empty: used by crash tests)."""
        rows = self._q(
            "SELECT e.id FROM edges e LEFT JOIN images i ON i.edge_id = e.id "
            "GROUP BY e.id HAVING COUNT(i.id) < 2"
        )
        return [r[0] for r in rows]


@contextmanager
def _guard() -> Iterator[None]:
    """Turn storage failures a user can act on (disk full, read-only file) into named errors."""
    try:
        yield
    except sqlite3.OperationalError as exc:
        mapped = _storage_error(exc)
        if mapped is None:
            raise
        raise mapped from exc


def _storage_error(exc: sqlite3.OperationalError) -> Unavailable | None:
    """The named error for a storage failure a user can act on, else ``None``."""
    text = str(exc).lower()
    if "readonly" in text or "read-only" in text:
        return Unavailable("the database is read-only; check the file's permissions and disk")
    if "full" in text:
        return Unavailable("the disk holding the database is full; free space and retry")
    if "locked" in text or "busy" in text:
        return Unavailable("the database is busy; retry in a moment")
    return None
