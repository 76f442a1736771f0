"""All SQL lives here: typed functions over one database, nothing else does I/O.

The database is a SQLite file (the embedded default: WAL mode, foreign keys on) or a
PostgreSQL server shared by several processes or machines (``postgresql://...``); the same
SQL runs on both through :mod:`server.storage.database`. One connection is shared by the
threads of the server behind a re-entrant lock; :meth:`Repo.transaction` wraps a service call
so that every teaching step that changes the graph commits whole or not at all.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from server.domain import Edge, Location, TourGraph
from server.errors import NotFound
from server.storage.database import open_database
from server.storage.migrations import migrate

DEFAULT_HOUSEHOLD = 1
"""The household that data from before households moved into (migration 3)."""


@dataclass(frozen=True)
class TourRow:
    id: int
    name: str
    created_at: float
    household_id: int = DEFAULT_HOUSEHOLD


Pose = tuple[float, float, float]
"""``(x, y, theta)``: metres, metres, radians, in the teaching robot's odometry frame."""


@dataclass(frozen=True)
class LocationRow:
    id: int
    tour_id: int
    name: str
    image_ids: tuple[int, ...]
    poses: tuple[Pose | None, ...] = ()  # aligned with image_ids (when read with them)
    entropy: tuple[float | None, ...] = ()  # distinctiveness per image, nats


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
    poses: tuple[Pose | None, ...] = ()  # aligned with image_ids
    entropy: tuple[float | None, ...] = ()  # distinctiveness per image, nats

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
    household_id: int = DEFAULT_HOUSEHOLD
    token_active: bool = True
    token_issued_at: float | None = None


@dataclass(frozen=True)
class HouseholdRow:
    id: int
    name: str
    created_at: float
    password_hash: str | None

    @property
    def has_login(self) -> bool:
        return self.password_hash is not None


@dataclass(frozen=True)
class AuditRow:
    id: int
    at: float
    actor: str
    action: str
    target: str
    status: int
    address: str | None


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
    belief_memory: str | None = None


@dataclass(frozen=True)
class LearnedChangeRow:
    """One learned change of a tour (migrations 5, 6 and 10): ``kind`` one of
    :data:`LEARNED_KINDS`; ``images``: the images of the edge a loop closure or a new path
    added (0 otherwise); ``edge_id``: that edge."""

    id: int
    tour_id: int
    kind: str
    created_at: float
    source: str
    summary: str
    images: int
    edge_id: int | None = None


LEARNED_KINDS = ("loop_closure", "look_alike", "new_path")
"""What a learned change can be: a loop closure or a look-alike pair (a 'same_place' question
answered yes or no), a new path (a 'new_path' question answered yes). Learned transitions,
experiences and junctions were removed (migration 10)."""

QUESTION_STATES = ("open", "yes", "no", "expired", "withdrawn")
"""A question is open until answered (yes/no), past its expiry (expired), or made moot
(withdrawn: its robot marked a place, finished or aborted teaching meanwhile)."""


@dataclass(frozen=True)
class QuestionRow:
    """One question (migration 6); times are unix seconds."""

    id: int
    robot: str
    tour_id: int
    kind: str
    text: str
    location_id: int
    source_location_id: int | None
    image_id: int | None
    match_image_id: int | None
    confidence: float
    created_at: float
    expires_at: float
    state: str
    answered_at: float | None
    change_id: int | None


@dataclass(frozen=True)
class FrameRow:
    """A frame kept for a proposed new path: capture time (s), odometry (m/s, rad/s), size,
    the JPEG as sent and the engine features."""

    timestamp: float
    v: float
    w: float
    width: int
    height: int
    jpeg: bytes
    features: bytes | None


class Repo:
    """Typed access to one teachrepeat database: a SQLite file (a path, ``sqlite:///path`` or
    ``":memory:"``) or a ``postgresql://`` URL (:func:`server.storage.database.open_database`).
    A constraint the database enforces raises :class:`~server.errors.IntegrityViolation`."""

    def __init__(self, path: Path | str) -> None:
        self.db = open_database(path)
        self._lock = threading.RLock()
        self._depth = 0
        self._reading = False  # the open outer transaction is a read snapshot
        self.schema_version = migrate(self.db)

    def close(self) -> None:
        with self._lock:
            self.db.close()

    # --- transactions ---------------------------------------------------------------------

    @contextmanager
    def transaction(self) -> Iterator[None]:
        """All statements inside commit together or not at all; nesting joins the outer one."""
        with self._lock:
            if self._reading:
                raise RuntimeError("a write transaction cannot be nested in a read snapshot")
            outer = self._depth == 0
            if outer:
                self.db.begin_write()
            self._depth += 1
            try:
                yield
            except BaseException:
                self._depth -= 1
                if outer:
                    self.db.rollback()
                raise
            self._depth -= 1
            if outer:
                self._commit()

    @contextmanager
    def snapshot(self) -> Iterator[None]:
        """Reads inside see one consistent state of the file and write nothing.

        A deferred transaction (PostgreSQL: repeatable read, read only): unlike
        :meth:`transaction` it takes no write lock, so it keeps working on a read-only file.
        Inside a transaction it joins it; a transaction inside a snapshot is a programming
        error (``RuntimeError``).
        """
        with self._lock:
            outer = self._depth == 0
            if outer:
                self.db.begin_read()
                self._reading = True
            self._depth += 1
            try:
                yield
            finally:
                self._depth -= 1
                if outer:
                    self._reading = False
                    if self.db.in_transaction:
                        self.db.commit()  # ends the read; nothing was written

    def _commit(self) -> None:
        try:
            self.db.commit()
        except BaseException:
            self.db.rollback()
            raise

    def _q(self, sql: str, params: Sequence[object] = ()) -> list[tuple]:
        with self._lock:
            return list(self.db.execute(sql, params).fetchall())

    def _writing(self) -> None:
        if self._reading:
            raise RuntimeError("a write inside a read snapshot; use Repo.transaction()")

    def _x(self, sql: str, params: Sequence[object] = ()) -> int:
        """Execute a write; returns the number of rows it changed. Call inside
        :meth:`transaction`."""
        with self._lock:
            self._writing()
            return int(self.db.execute(sql, params).rowcount)

    def _insert(self, sql: str, params: Sequence[object] = ()) -> int:
        """Execute an ``INSERT`` into a table with an ``id``; returns the new row's id."""
        with self._lock:
            self._writing()
            return self.db.insert(sql, params)

    def _many(self, sql: str, rows: Sequence[Sequence[object]]) -> None:
        with self._lock:
            self._writing()
            self.db.executemany(sql, rows)

    def integrity_ok(self) -> bool:
        """SQLite: the file passes ``PRAGMA integrity_check``; PostgreSQL: the server answers."""
        with self._lock:
            return self.db.integrity_ok()

    # --- households -----------------------------------------------------------------------

    def add_household(self, name: str, password_hash: str | None) -> HouseholdRow:
        now = time.time()
        hid = self._insert(
            "INSERT INTO households (name, password_hash, created_at) VALUES (?, ?, ?)",
            (name, password_hash, now),
        )
        return HouseholdRow(hid, name, now, password_hash)

    def household(self, household_id: int) -> HouseholdRow:
        rows = self._q(_HOUSEHOLD_SQL + " WHERE id = ?", (household_id,))
        if not rows:
            raise NotFound(f"no household with id {household_id}; GET /households lists them")
        return HouseholdRow(*rows[0])

    def household_by_name(self, name: str) -> HouseholdRow | None:
        rows = self._q(_HOUSEHOLD_SQL + " WHERE name = ?", (name,))
        return HouseholdRow(*rows[0]) if rows else None

    def households(self) -> list[HouseholdRow]:
        return [HouseholdRow(*r) for r in self._q(_HOUSEHOLD_SQL + " ORDER BY id")]

    def set_password_hash(self, household_id: int, password_hash: str) -> None:
        self._x(
            "UPDATE households SET password_hash = ? WHERE id = ?", (password_hash, household_id)
        )

    def any_login(self) -> bool:
        """Whether some household has a password (someone can log in to the dashboard)."""
        return bool(self._q("SELECT 1 FROM households WHERE password_hash IS NOT NULL LIMIT 1"))

    # --- household logins (sessions) -------------------------------------------------------

    def add_login(self, token_hash: str, household_id: int, expires_at: float) -> None:
        self._x(
            "INSERT INTO logins (token_hash, household_id, created_at, expires_at) "
            "VALUES (?, ?, ?, ?)",
            (token_hash, household_id, time.time(), expires_at),
        )

    def login(self, token_hash: str) -> tuple[int, str, float] | None:
        """``(household id, household name, expires at)`` of a login token's hash, or ``None``."""
        rows = self._q(
            "SELECT l.household_id, h.name, l.expires_at FROM logins l "
            "JOIN households h ON h.id = l.household_id WHERE l.token_hash = ?",
            (token_hash,),
        )
        return (int(rows[0][0]), rows[0][1], float(rows[0][2])) if rows else None

    def end_login(self, token_hash: str) -> None:
        self._x("DELETE FROM logins WHERE token_hash = ?", (token_hash,))

    # --- robots ---------------------------------------------------------------------------

    def add_robot(
        self, name: str, token_hash: str, household_id: int = DEFAULT_HOUSEHOLD
    ) -> RobotRow:
        now = time.time()
        self._x(
            "INSERT INTO robots (name, household_id, token_hash, token_issued_at, created_at) "
            "VALUES (?, ?, ?, ?, ?)",
            (name, household_id, token_hash, now, now),
        )
        return RobotRow(name, now, household_id, True, now)

    def robot(self, name: str) -> RobotRow:
        rows = self._q(_ROBOT_SQL + " WHERE name = ?", (name,))
        if not rows:
            raise NotFound(f"no robot named {name!r}; register it with POST /robots")
        return _robot_row(rows[0])

    def robot_exists(self, name: str) -> bool:
        return bool(self._q("SELECT 1 FROM robots WHERE name = ?", (name,)))

    def robot_household(self, name: str) -> int | None:
        rows = self._q("SELECT household_id FROM robots WHERE name = ?", (name,))
        return int(rows[0][0]) if rows else None

    def robot_by_token_hash(self, token_hash: str) -> tuple[str, int, str] | None:
        """``(robot name, household id, household name)`` of a live token's hash, or ``None``."""
        rows = self._q(
            "SELECT r.name, r.household_id, h.name FROM robots r "
            "JOIN households h ON h.id = r.household_id WHERE r.token_hash = ?",
            (token_hash,),
        )
        return (rows[0][0], int(rows[0][1]), rows[0][2]) if rows else None

    def set_robot_token(self, name: str, token_hash: str | None) -> None:
        """Replace (rotate) or, with ``None``, revoke the robot's token."""
        self._x(
            "UPDATE robots SET token_hash = ?, token_issued_at = ? WHERE name = ?",
            (token_hash, None if token_hash is None else time.time(), name),
        )

    def robots(self, household_id: int | None = None) -> list[RobotRow]:
        """The robots of one household, or of all with ``None``, by name."""
        where, params = _owned_by(household_id)
        return [_robot_row(r) for r in self._q(_ROBOT_SQL + where + " ORDER BY name", params)]

    # --- tours ----------------------------------------------------------------------------

    def add_tour(self, name: str, household_id: int = DEFAULT_HOUSEHOLD) -> TourRow:
        now = time.time()
        tid = self._insert(
            "INSERT INTO tours (name, household_id, created_at) VALUES (?, ?, ?)",
            (name, household_id, now),
        )
        return TourRow(tid, name, now, household_id)

    def tour(self, tour_id: int, household_id: int | None = None) -> TourRow:
        """The tour ``tour_id``; with ``household_id``, only when that household owns it (a
        tour of another household is answered as one that does not exist)."""
        rows = self._q(
            "SELECT id, name, created_at, household_id FROM tours WHERE id = ?", (tour_id,)
        )
        if not rows or (household_id is not None and rows[0][3] != household_id):
            raise NotFound(f"no tour with id {tour_id}; GET /tours lists the tours")
        return TourRow(*rows[0])

    def tour_by_name(self, name: str, household_id: int = DEFAULT_HOUSEHOLD) -> TourRow | None:
        rows = self._q(
            "SELECT id, name, created_at, household_id FROM tours "
            "WHERE name = ? AND household_id = ?",
            (name, household_id),
        )
        return TourRow(*rows[0]) if rows else None

    def tours(self, household_id: int | None = None) -> list[tuple[TourRow, int, int, int]]:
        """The tours of one household (all with ``None``), each with its numbers of locations,
        edges and stored (non-pending) images."""
        where, params = _owned_by(household_id, "t.")
        rows = self._q(
            f"""
            SELECT t.id, t.name, t.created_at, t.household_id,
                   (SELECT COUNT(*) FROM locations l WHERE l.tour_id = t.id),
                   (SELECT COUNT(*) FROM edges e WHERE e.tour_id = t.id),
                   (SELECT COUNT(*) FROM images i WHERE i.tour_id = t.id
                                                   AND i.pending_robot IS NULL)
            FROM tours t{where} ORDER BY t.id""",
            params,
        )
        return [(TourRow(r[0], r[1], r[2], r[3]), r[4], r[5], r[6]) for r in rows]

    def tour_counts(self, tour_id: int) -> tuple[int, int]:
        """Numbers of locations and of edges of one tour."""
        row = self._q(
            "SELECT (SELECT COUNT(*) FROM locations WHERE tour_id = ?), "
            "(SELECT COUNT(*) FROM edges WHERE tour_id = ?)",
            (tour_id, tour_id),
        )[0]
        return int(row[0]), int(row[1])

    def tour_stamp(self, tour_id: int) -> tuple[int, ...]:
        """What changes whenever teaching changes the tour's graph: the count and largest id
        of its places, paths and stored images (not those on a robot's open path). Another
        server process on the same file compares it with the stamp its runtime was built
        from (docs/scale.md)."""
        row = self._q(
            "SELECT (SELECT count(*) FROM locations WHERE tour_id = ?),"
            " (SELECT coalesce(max(id), 0) FROM locations WHERE tour_id = ?),"
            " (SELECT count(*) FROM edges WHERE tour_id = ?),"
            " (SELECT coalesce(max(id), 0) FROM edges WHERE tour_id = ?),"
            " (SELECT count(*) FROM images WHERE tour_id = ? AND pending_robot IS NULL),"
            " (SELECT coalesce(max(id), 0) FROM images"
            "  WHERE tour_id = ? AND pending_robot IS NULL)",
            (tour_id,) * 6,
        )[0]
        return tuple(int(x) for x in row)

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

    # --- audit ----------------------------------------------------------------------------

    def add_audit(
        self, *, actor: str, action: str, target: str, status: int, address: str | None
    ) -> None:
        with self.transaction():
            self._x(
                "INSERT INTO audit (at, actor, action, target, status, address) "
                "VALUES (?, ?, ?, ?, ?, ?)",
                (time.time(), actor, action, target, status, address),
            )

    def forget_before(self, audit_before: float, now: float) -> tuple[int, int]:
        """Delete audit entries written before ``audit_before`` and logins expired by ``now``
        (unix times, s); returns how many of each."""
        with self.transaction():
            audit = self._x("DELETE FROM audit WHERE at < ?", (audit_before,))
            return audit, self._x("DELETE FROM logins WHERE expires_at < ?", (now,))

    def audit(self, *, limit: int = 100, before_id: int | None = None) -> list[AuditRow]:
        """The newest ``limit`` audit rows (older than ``before_id`` when given), newest first."""
        rows = self._q(
            "SELECT id, at, actor, action, target, status, address FROM audit "
            "WHERE id < ? ORDER BY id DESC LIMIT ?",
            (before_id if before_id is not None else 2**63 - 1, limit),
        )
        return [AuditRow(*r) for r in rows]

    # --- locations and edges --------------------------------------------------------------

    def locations(self, tour_id: int) -> list[LocationRow]:
        locs = self._q("SELECT id, name FROM locations WHERE tour_id = ? ORDER BY id", (tour_id,))
        images = self._q(
            f"SELECT location_id, id, {_IMAGE_EXTRAS} FROM images "
            "WHERE tour_id = ? AND location_id IS NOT NULL ORDER BY location_id, seq",
            (tour_id,),
        )
        by_loc: dict[int, list[tuple]] = {}
        for loc_id, *rest in images:
            by_loc.setdefault(loc_id, []).append(tuple(rest))
        out = []
        for i, n in locs:
            rows = by_loc.get(i, [])
            out.append(
                LocationRow(
                    i,
                    tour_id,
                    n,
                    tuple(r[0] for r in rows),
                    tuple(_pose(r[1:4]) for r in rows),
                    tuple(r[4] for r in rows),
                )
            )
        return out

    def location_by_name(self, tour_id: int, name: str) -> int | None:
        rows = self._q("SELECT id FROM locations WHERE tour_id = ? AND name = ?", (tour_id, name))
        return rows[0][0] if rows else None

    def location_name(self, location_id: int) -> str:
        rows = self._q("SELECT name FROM locations WHERE id = ?", (location_id,))
        if not rows:
            raise NotFound(f"no location with id {location_id}")
        return str(rows[0][0])

    def add_location(self, tour_id: int, name: str) -> int:
        return self._insert(
            "INSERT INTO locations (tour_id, name, created_at) VALUES (?, ?, ?)",
            (tour_id, name, time.time()),
        )

    def edges(self, tour_id: int) -> list[EdgeRow]:
        heads = self._q(
            "SELECT id, source_id, target_id FROM edges WHERE tour_id = ? ORDER BY id", (tour_id,)
        )
        images = self._q(
            f"SELECT edge_id, id, timestamp, v, w, {_IMAGE_EXTRAS} FROM images "
            "WHERE tour_id = ? AND edge_id IS NOT NULL ORDER BY edge_id, seq",
            (tour_id,),
        )
        by_edge: dict[int, list[tuple]] = {}
        for edge_id, *rest in images:
            by_edge.setdefault(edge_id, []).append(tuple(rest))
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
                    tuple(_pose(r[4:7]) for r in rows),
                    tuple(r[7] for r in rows),
                )
            )
        return out

    def add_edge(self, tour_id: int, source_id: int, target_id: int) -> int:
        return self._insert(
            "INSERT INTO edges (tour_id, source_id, target_id, created_at) VALUES (?, ?, ?, ?)",
            (tour_id, source_id, target_id, time.time()),
        )

    def graph(self, tour_id: int) -> TourGraph:
        """The tour as the pure core sees it (locations and edges in id order), with the
        images' taught poses and distinctiveness where known."""
        locs = self.locations(tour_id)
        edges = self.edges(tour_id)
        index = {loc.id: k for k, loc in enumerate(locs)}
        poses = [p for loc in locs for p in loc.poses] + [p for e in edges for p in e.poses]
        entropy = [h for loc in locs for h in loc.entropy] + [h for e in edges for h in e.entropy]
        return TourGraph(
            image_pose=None
            if all(p is None for p in poses)
            else np.array([p if p is not None else (np.nan,) * 3 for p in poses]).reshape(-1, 3),
            image_entropy=None
            if all(h is None for h in entropy)
            else np.array([np.nan if h is None else h for h in entropy], dtype=np.float64),
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
                for e in edges
            ),
        )

    def set_entropies(self, tour_id: int, items: Sequence[tuple[int, float]]) -> None:
        """Store the distinctiveness (nats) of the tour's images, all at once: ``items`` is
        ``(image id, entropy)`` for every image of the tour; the count is kept with the tour
        (:meth:`entropy_images`)."""
        with self.transaction():
            self._many(
                "UPDATE images SET entropy = ? WHERE id = ? AND tour_id = ?",
                [(float(h), int(i), tour_id) for i, h in items],
            )
            self._x("UPDATE tours SET entropy_images = ? WHERE id = ?", (len(items), tour_id))

    def entropy_images(self, tour_id: int) -> int | None:
        """How many images the stored entropies were computed over (``None``: never)."""
        rows = self._q("SELECT entropy_images FROM tours WHERE id = ?", (tour_id,))
        if not rows:
            raise NotFound(f"no tour with id {tour_id}")
        return None if rows[0][0] is None else int(rows[0][0])

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
        pose: Pose | None = None,
        depth: Sequence[float] | None = None,
    ) -> int:
        """Store one image, owned by a location (spin image) or a robot's open path, with the
        pose it was taken at and its depth profile (metres, left to right) when the robot sent
        them."""
        owner: str
        value: int | str | None
        if location_id is not None:
            owner, value = "location_id", location_id
        else:
            owner, value = "pending_robot", pending_robot
        seq = self._q(f"SELECT COALESCE(MAX(seq), -1) + 1 FROM images WHERE {owner} = ?", (value,))
        x, y, theta = pose if pose is not None else (None, None, None)
        ranges = None if depth is None else np.asarray(depth, dtype="<f4").tobytes()
        return self._insert(
            f"INSERT INTO images (tour_id, {owner}, seq, timestamp, v, w, width, height, jpeg, "
            "pose_x, pose_y, pose_theta, depth) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (tour_id, value, seq[0][0], timestamp, v, w, width, height, jpeg, x, y, theta, ranges),
        )

    def image_jpeg(self, image_id: int) -> bytes:
        rows = self._q("SELECT jpeg FROM images WHERE id = ?", (image_id,))
        if not rows:
            raise NotFound(f"no image with id {image_id}")
        return bytes(rows[0][0])

    def image_household(self, image_id: int) -> int | None:
        """The household that owns the image (through its tour), or ``None`` when unknown."""
        rows = self._q(
            "SELECT t.household_id FROM images i JOIN tours t ON t.id = i.tour_id WHERE i.id = ?",
            (image_id,),
        )
        return int(rows[0][0]) if rows else None

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
        return self._x(
            "UPDATE images SET edge_id = ?, pending_robot = NULL WHERE pending_robot = ?",
            (edge_id, robot),
        )

    def discard_pending(self, robot: str) -> int:
        return self._x("DELETE FROM images WHERE pending_robot = ?", (robot,))

    def copy_last_pending_to_location(self, robot: str, location_id: int) -> int | None:
        """Give ``location_id`` a copy of the last image of the robot's open path, marked as
        taken from the path by ``seq`` -1 (:meth:`drop_path_copies` removes it when a spin
        image arrives). Returns the copy's id; ``None`` when the open path is empty."""
        last = self._q(
            "SELECT id FROM images WHERE pending_robot = ? ORDER BY seq DESC LIMIT 1", (robot,)
        )
        if not last:
            return None
        return self._insert(
            "INSERT INTO images (tour_id, location_id, seq, timestamp, v, w, width, height, "
            "jpeg, features, pose_x, pose_y, pose_theta) SELECT tour_id, ?, -1, timestamp, v, "
            "w, width, height, jpeg, features, pose_x, pose_y, pose_theta FROM images WHERE id = ?",
            (location_id, last[0][0]),
        )

    def drop_path_copies(self, location_id: int) -> int:
        """Remove the images :meth:`copy_last_pending_to_location` gave ``location_id``."""
        return self._x("DELETE FROM images WHERE location_id = ? AND seq < 0", (location_id,))

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

    def depths(self, image_ids: Sequence[int]) -> dict[int, npt.NDArray[np.float32]]:
        """The depth profiles the robot sent with the given images (metres, left to right;
        images without one are left out)."""
        out: dict[int, npt.NDArray[np.float32]] = {}
        ids = list(image_ids)
        for start in range(0, len(ids), 500):
            chunk = ids[start : start + 500]
            marks = ",".join("?" * len(chunk))
            for image_id, blob in self._q(
                f"SELECT id, depth FROM images WHERE id IN ({marks}) AND depth IS NOT NULL", chunk
            ):
                out[int(image_id)] = np.frombuffer(bytes(blob), dtype="<f4").astype(np.float32)
        return out

    def set_features(self, items: Sequence[tuple[int, bytes]]) -> None:
        with self.transaction():
            self._many("UPDATE images SET features = ? WHERE id = ?", [(b, i) for i, b in items])

    # --- learned changes (migrations 5, 6 and 10) -----------------------------------------

    def add_learned_change(
        self,
        tour_id: int,
        kind: str,
        *,
        source: str,
        summary: str,
        now: float,
        edge_id: int | None = None,
    ) -> int:
        """Store one change; ``edge_id``: the edge the change added (removed with it).
        Returns the change's id."""
        if kind not in LEARNED_KINDS:
            raise ValueError(f"unknown learned change kind {kind!r}")
        with self.transaction():
            return self._insert(
                "INSERT INTO learned_changes (tour_id, kind, created_at, source, summary, edge_id) "
                "VALUES (?, ?, ?, ?, ?, ?)",
                (tour_id, kind, now, source, summary, edge_id),
            )

    def learned_changes(self, tour_id: int) -> list[LearnedChangeRow]:
        """The tour's learned changes, oldest first, each with its number of images."""
        rows = self._q(
            "SELECT c.id, c.tour_id, c.kind, c.created_at, c.source, c.summary, "
            "(SELECT COUNT(*) FROM images i WHERE c.edge_id IS NOT NULL "
            "AND i.edge_id = c.edge_id), "
            "c.edge_id FROM learned_changes c WHERE c.tour_id = ? ORDER BY c.id",
            (tour_id,),
        )
        return [LearnedChangeRow(*r) for r in rows]

    def remove_learned_change(self, tour_id: int, change_id: int) -> None:
        """Delete the change and what it added: its look-alike pairs, the edge it added with
        that edge's images; NotFound when the tour has no such change."""
        with self.transaction():
            rows = self._q(
                "SELECT edge_id FROM learned_changes WHERE id = ? AND tour_id = ?",
                (change_id, tour_id),
            )
            if not rows:
                raise NotFound(
                    f"tour {tour_id} has no learned change {change_id}; "
                    f"GET /tours/{tour_id}/learned lists them"
                )
            self._x("DELETE FROM learned_changes WHERE id = ?", (change_id,))
            edge_id = rows[0][0]
            if edge_id is not None:
                self._x("DELETE FROM images WHERE edge_id = ?", (edge_id,))
                self._x("DELETE FROM edges WHERE id = ?", (edge_id,))

    # --- questions (migration 6) ----------------------------------------------------------

    def add_question(
        self,
        *,
        robot: str,
        tour_id: int,
        kind: str,
        text: str,
        location_id: int,
        source_location_id: int | None,
        image_id: int | None,
        match_image_id: int | None,
        confidence: float,
        now: float,
        expires_at: float,
        frames: Sequence[FrameRow] = (),
    ) -> int:
        """Store an open question (with the frames of a proposed new path); its id."""
        with self.transaction():
            question = self._insert(
                "INSERT INTO questions (robot, tour_id, kind, text, location_id, "
                "source_location_id, image_id, match_image_id, confidence, created_at, "
                "expires_at, state) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, 'open')",
                (
                    robot,
                    tour_id,
                    kind,
                    text,
                    location_id,
                    source_location_id,
                    image_id,
                    match_image_id,
                    float(confidence),
                    now,
                    expires_at,
                ),
            )
            for seq, f in enumerate(frames):
                self._x(
                    "INSERT INTO question_frames (question_id, seq, timestamp, v, w, width, "
                    "height, jpeg, features) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                    (question, seq, f.timestamp, f.v, f.w, f.width, f.height, f.jpeg, f.features),
                )
        return question

    _QUESTION_COLUMNS = (
        "id, robot, tour_id, kind, text, location_id, source_location_id, image_id, "
        "match_image_id, confidence, created_at, expires_at, state, answered_at, change_id"
    )

    def question(self, question_id: int) -> QuestionRow | None:
        rows = self._q(
            f"SELECT {self._QUESTION_COLUMNS} FROM questions WHERE id = ?", (question_id,)
        )
        return QuestionRow(*rows[0]) if rows else None

    def questions(self, robot: str, state: str | None = "open") -> list[QuestionRow]:
        """The robot's questions in ``state`` (``None``: all), oldest first."""
        where, params = "robot = ?", [robot]
        if state is not None:
            where, params = "robot = ? AND state = ?", [robot, state]
        rows = self._q(
            f"SELECT {self._QUESTION_COLUMNS} FROM questions WHERE {where} ORDER BY id", params
        )
        return [QuestionRow(*r) for r in rows]

    def close_question(
        self, question_id: int, state: str, *, now: float, change_id: int | None = None
    ) -> None:
        """Give an open question its final ``state``; its frames are no longer needed."""
        if state not in QUESTION_STATES or state == "open":
            raise ValueError(f"cannot close a question as {state!r}")
        with self.transaction():
            self._x(
                "UPDATE questions SET state = ?, answered_at = ?, change_id = ? "
                "WHERE id = ? AND state = 'open'",
                (state, now, change_id, question_id),
            )
            self._x("DELETE FROM question_frames WHERE question_id = ?", (question_id,))

    def expire_questions(self, robot: str, now: float) -> int:
        """Close the robot's open questions whose time is up; how many."""
        due = self._q(
            "SELECT id FROM questions WHERE robot = ? AND state = 'open' AND expires_at <= ?",
            (robot, now),
        )
        if due:  # no write (no transaction) when nothing is due
            with self.transaction():
                for (question_id,) in due:
                    self.close_question(question_id, "expired", now=now)
        return len(due)

    def withdraw_questions(self, robot: str, kind: str, now: float) -> int:
        """Close the robot's open questions of ``kind`` as withdrawn; how many."""
        due = self._q(
            "SELECT id FROM questions WHERE robot = ? AND state = 'open' AND kind = ?",
            (robot, kind),
        )
        if due:
            with self.transaction():
                for (question_id,) in due:
                    self.close_question(question_id, "withdrawn", now=now)
        return len(due)

    def set_question_change(self, question_id: int, change_id: int) -> None:
        self._x("UPDATE questions SET change_id = ? WHERE id = ?", (change_id, question_id))

    def question_frame_count(self, question_id: int) -> int:
        rows = self._q("SELECT COUNT(*) FROM question_frames WHERE question_id = ?", (question_id,))
        return int(rows[0][0])

    def question_frames(self, question_id: int) -> list[FrameRow]:
        rows = self._q(
            "SELECT timestamp, v, w, width, height, jpeg, features FROM question_frames "
            "WHERE question_id = ? ORDER BY seq",
            (question_id,),
        )
        return [
            FrameRow(t, v, w, wd, ht, bytes(j), None if f is None else bytes(f))
            for t, v, w, wd, ht, j, f in rows
        ]

    def add_edge_with_images(
        self, tour_id: int, source_id: int, target_id: int, frames: Sequence[FrameRow]
    ) -> int:
        """A new edge holding ``frames`` in order (a path found by exploration); its id."""
        with self.transaction():
            edge = self.add_edge(tour_id, source_id, target_id)
            for seq, f in enumerate(frames):
                self._x(
                    "INSERT INTO images (tour_id, edge_id, seq, timestamp, v, w, width, height, "
                    "jpeg, features) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                    (
                        tour_id,
                        edge,
                        seq,
                        f.timestamp,
                        f.v,
                        f.w,
                        f.width,
                        f.height,
                        f.jpeg,
                        f.features,
                    ),
                )
        return edge

    def add_look_alike(
        self, change_id: int, location_id: int, image_id: int | None, match_image_id: int
    ) -> None:
        self._x(
            "INSERT INTO look_alikes (change_id, location_id, image_id, match_image_id) "
            "VALUES (?, ?, ?, ?)",
            (change_id, location_id, image_id, match_image_id),
        )

    def look_alike_images(self, location_id: int) -> set[int]:
        """The images of ``location_id`` a person said a frame elsewhere only looked like."""
        rows = self._q(
            "SELECT match_image_id FROM look_alikes WHERE location_id = ?", (location_id,)
        )
        return {int(r[0]) for r in rows}

    def declined_locations(self, robot: str) -> set[int]:
        """Places the robot asked about on its open path and was told 'no' (while that
        answer's look-alike change exists: undoing it lets the question be asked again)."""
        rows = self._q(
            "SELECT q.location_id FROM questions q JOIN images i ON i.id = q.image_id "
            "WHERE q.robot = ? AND q.kind = 'same_place' AND q.state = 'no' "
            "AND q.change_id IS NOT NULL AND i.pending_robot = ?",
            (robot, robot),
        )
        return {int(r[0]) for r in rows}

    def last_pending_image(self, robot: str) -> int | None:
        """The id of the newest image on the robot's open path."""
        rows = self._q(
            "SELECT id FROM images WHERE pending_robot = ? ORDER BY seq DESC LIMIT 1", (robot,)
        )
        return int(rows[0][0]) if rows else None

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
            "ended_at, steps, belief, belief_images, belief_memory FROM navigation WHERE robot = ?",
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
            belief_memory=r[11],
        )

    def next_task_id(self) -> int:
        return int(self._q("SELECT COALESCE(MAX(task_id), 0) + 1 FROM navigation")[0][0])

    def save_navigation(self, row: NavigationRow) -> None:
        """Insert or replace the robot's navigation row (one transaction)."""
        with self.transaction():
            self._x(
                f"INSERT INTO navigation ({_NAVIGATION}) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT (robot) DO UPDATE SET "
                + ", ".join(f"{c} = excluded.{c}" for c in _NAVIGATION.split(", ")[1:]),
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
                    row.belief_memory,
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


_NAVIGATION = (
    "robot, tour_id, task_id, goal_location_id, state, reason, started_at, ended_at, steps, "
    "belief, belief_images, belief_memory, belief_at"
)
"""The columns of a navigation row, the key (``robot``) first."""

_IMAGE_EXTRAS = "pose_x, pose_y, pose_theta, entropy"
"""The per-image columns of migration 4, in this order."""


def _pose(row: Sequence[float | None]) -> Pose | None:
    """``(x, y, theta)`` from the three pose columns, ``None`` unless all three are set."""
    if any(v is None for v in row):
        return None
    return (float(row[0]), float(row[1]), float(row[2]))  # type: ignore[arg-type]


_HOUSEHOLD_SQL = "SELECT id, name, created_at, password_hash FROM households"
_ROBOT_SQL = (
    "SELECT name, created_at, household_id, token_hash IS NOT NULL, token_issued_at FROM robots"
)


def _robot_row(r: tuple) -> RobotRow:
    return RobotRow(r[0], r[1], int(r[2]), bool(r[3]), r[4])


def _owned_by(household_id: int | None, prefix: str = "") -> tuple[str, tuple[object, ...]]:
    """A WHERE clause restricting rows to one household (nothing with ``None``)."""
    if household_id is None:
        return "", ()
    return f" WHERE {prefix}household_id = ?", (household_id,)
