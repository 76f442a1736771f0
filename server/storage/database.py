"""The two database servers :class:`server.storage.repo.Repo` runs on, behind one interface.

SQLite (the embedded default, a file) and PostgreSQL (``postgresql://...``, shared by several
server processes or machines; docs/scale.md) answer the same calls:

* ``execute(sql, params)`` / ``executemany`` / ``insert`` (the new row's ``id``) with the
  project's SQL: ``?`` placeholders and SQLite's type names. On PostgreSQL, :func:`to_postgres`
  rewrites ``?`` as ``%s``, and in ``CREATE TABLE`` / ``ALTER TABLE`` the types (``INTEGER
  PRIMARY KEY`` an identity, ``INTEGER`` BIGINT, ``REAL`` DOUBLE PRECISION, ``BLOB`` BYTEA), so
  one migration text serves both;
* ``begin_write`` (one writer at a time over every process: SQLite's ``BEGIN IMMEDIATE``, on
  PostgreSQL a transaction holding one advisory lock), ``begin_read`` (a consistent read-only
  snapshot), ``commit``, ``rollback``, ``in_transaction``;
* failures a user can act on become the project's errors: a broken constraint
  :class:`~server.errors.IntegrityViolation`, a full disk, read-only file, busy database or
  unreachable server :class:`~server.errors.Unavailable`.

:func:`open_database` picks the server from a path or URL. A URL's password is never printed:
:func:`masked` is what logs and banners show.
"""

from __future__ import annotations

import functools
import re
import sqlite3
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Protocol
from urllib.parse import urlsplit, urlunsplit

import sqlite_utils

from server.errors import IntegrityViolation, Unavailable

POSTGRES_SCHEMES = ("postgresql://", "postgres://")
SQLITE_SCHEME = "sqlite:///"

WRITE_LOCK = 0x7465616368
"""The PostgreSQL advisory lock every write transaction holds ("teach")."""

LOCK_TIMEOUT_MS = 5000
"""How long a PostgreSQL write waits for the write lock before it is answered as busy (as
SQLite's ``busy_timeout``)."""


class Cursor(Protocol):
    """What ``execute`` answers on both (a DB-API cursor)."""

    @property
    def rowcount(self) -> int: ...
    @property
    def description(self) -> Any: ...
    def fetchall(self) -> list[Any]: ...
    def fetchone(self) -> Any: ...


class Database(Protocol):
    """One connection to SQLite or PostgreSQL with the project's SQL (module docstring)."""

    dialect: str

    def execute(self, sql: str, parameters: Sequence[object] | None = None) -> Any: ...
    def executemany(self, sql: str, rows: Sequence[Sequence[object]]) -> int: ...
    def insert(self, sql: str, parameters: Sequence[object] = ()) -> int: ...
    def begin_write(self) -> None: ...
    def begin_read(self) -> None: ...
    def commit(self) -> None: ...
    def rollback(self) -> None: ...
    @property
    def in_transaction(self) -> bool: ...
    def table_names(self) -> list[str]: ...
    def columns(self, table: str) -> list[str]: ...
    def integrity_ok(self) -> bool: ...
    def close(self) -> None: ...


def is_postgres_url(target: Path | str) -> bool:
    return isinstance(target, str) and target.startswith(POSTGRES_SCHEMES)


def sqlite_path(target: Path | str) -> Path | str:
    """The file of a path or ``sqlite:///path`` URL (``":memory:"`` stays itself)."""
    text = str(target)
    if text.startswith(SQLITE_SCHEME):
        rest = text[len(SQLITE_SCHEME) :]
        return ":memory:" if rest in ("", ":memory:") else Path(rest)
    return text if text == ":memory:" else Path(target)


def masked(target: Path | str) -> str:
    """The path or URL with a password replaced by ``***`` (what may be printed or logged)."""
    text = str(target)
    if not is_postgres_url(text):
        return text
    parts = urlsplit(text)
    if parts.password is None:
        return text
    host = parts.netloc.rsplit("@", 1)[1]
    return urlunsplit(parts._replace(netloc=f"{parts.username or ''}:***@{host}"))


def open_database(target: Path | str) -> SqliteDatabase | PostgresDatabase:
    """A connection to ``target``: a ``postgresql://`` URL, or a SQLite file (a path, a
    ``sqlite:///`` URL or ``":memory:"``; the file and its folder are created when missing)."""
    if is_postgres_url(target):
        return PostgresDatabase(str(target))
    return SqliteDatabase.open(sqlite_path(target))


# --- SQLite ---------------------------------------------------------------------------------


class SqliteDatabase(sqlite_utils.Database):
    """One SQLite file in WAL mode with foreign keys on (sqlite-utils' ``Database``, plus the
    calls of :class:`Database`)."""

    dialect = "sqlite"

    @classmethod
    def open(cls, path: Path | str) -> SqliteDatabase:
        if str(path) != ":memory:":
            Path(path).parent.mkdir(parents=True, exist_ok=True)
        conn = sqlite3.connect(str(path), check_same_thread=False, isolation_level=None)
        conn.execute("PRAGMA foreign_keys = ON")
        conn.execute("PRAGMA busy_timeout = 5000")
        db = cls(conn)
        if str(path) != ":memory:":
            db.enable_wal()
            conn.execute("PRAGMA synchronous = NORMAL")
        return db

    def execute(self, sql: str, parameters: Any = None) -> sqlite3.Cursor:
        with _sqlite_errors():
            return self.conn.execute(sql, parameters if parameters is not None else ())

    def executemany(self, sql: str, rows: Sequence[Sequence[object]]) -> int:
        with _sqlite_errors():
            return int(self.conn.executemany(sql, rows).rowcount)

    def insert(self, sql: str, parameters: Sequence[object] = ()) -> int:
        return int(self.execute(sql, parameters).lastrowid or 0)

    def begin_write(self) -> None:
        self.execute("BEGIN IMMEDIATE")

    def begin_read(self) -> None:
        self.execute("BEGIN DEFERRED")

    def commit(self) -> None:
        self.execute("COMMIT")

    def rollback(self) -> None:
        if self.conn.in_transaction:  # SQLITE_FULL already rolled back
            self.conn.execute("ROLLBACK")

    @property
    def in_transaction(self) -> bool:
        return self.conn.in_transaction

    def columns(self, table: str) -> list[str]:
        return [r[1] for r in self.conn.execute(f"PRAGMA table_info({table})").fetchall()]

    def integrity_ok(self) -> bool:
        return bool(self.execute("PRAGMA integrity_check").fetchone()[0] == "ok")


@contextmanager
def _sqlite_errors() -> Iterator[None]:
    try:
        yield
    except sqlite3.IntegrityError as exc:
        raise IntegrityViolation(str(exc)) from exc
    except sqlite3.OperationalError as exc:
        text = str(exc).lower()
        if "readonly" in text or "read-only" in text:
            raise Unavailable(
                "the database is read-only; check the file's permissions and disk"
            ) from exc
        if "full" in text:
            raise Unavailable(
                "the disk holding the database is full; free space and retry"
            ) from exc
        if "locked" in text or "busy" in text:
            raise Unavailable("the database is busy; retry in a moment") from exc
        raise


# --- PostgreSQL -----------------------------------------------------------------------------


class PostgresDatabase:
    """One psycopg 3 connection (autocommit; transactions are explicit) to a PostgreSQL
    database. A connection that broke (the server restarted) is opened again on the next
    statement outside a transaction; the statement that met the break is answered as
    :class:`~server.errors.Unavailable`."""

    dialect = "postgresql"

    def __init__(self, url: str) -> None:
        self.url = url
        self.conn = self._connect()

    def _connect(self) -> Any:
        import psycopg

        try:
            return psycopg.connect(
                self.url,
                autocommit=True,
                connect_timeout=10,
                options=f"-c lock_timeout={LOCK_TIMEOUT_MS}",
            )
        except psycopg.OperationalError as exc:
            raise Unavailable(
                f"cannot connect to the database server {masked(self.url)}: "
                f"{str(exc).strip().splitlines()[-1] if str(exc).strip() else exc!r}"
            ) from exc

    @contextmanager
    def _errors(self) -> Iterator[None]:
        import psycopg
        from psycopg import errors

        if self.conn.closed:
            self.conn = self._connect()
        try:
            yield
        except psycopg.IntegrityError as exc:
            raise IntegrityViolation(str(exc).strip()) from exc
        except (errors.LockNotAvailable, errors.SerializationFailure) as exc:
            raise Unavailable("the database is busy; retry in a moment") from exc
        except errors.ReadOnlySqlTransaction as exc:
            raise Unavailable(
                "the database is read-only (a standby server?); point the server at the primary"
            ) from exc
        except errors.DiskFull as exc:
            raise Unavailable(
                "the disk of the database server is full; free space and retry"
            ) from exc
        except psycopg.OperationalError as exc:
            if not self.conn.closed:
                raise
            raise Unavailable(
                f"lost the connection to the database server {masked(self.url)}; retry"
            ) from exc

    def execute(self, sql: str, parameters: Sequence[object] | None = None) -> Any:
        with self._errors():
            return self.conn.execute(to_postgres(sql), tuple(parameters or ()))

    def executemany(self, sql: str, rows: Sequence[Sequence[object]]) -> int:
        with self._errors(), self.conn.cursor() as cur:
            cur.executemany(to_postgres(sql), [tuple(r) for r in rows])
            return int(cur.rowcount)

    def insert(self, sql: str, parameters: Sequence[object] = ()) -> int:
        return int(self.execute(sql + " RETURNING id", parameters).fetchone()[0])

    def begin_write(self) -> None:
        self.execute("BEGIN")
        try:
            self.execute("SELECT pg_advisory_xact_lock(?)", (WRITE_LOCK,))
        except BaseException:  # waited longer than lock_timeout: no transaction is left open
            self.rollback()
            raise

    def begin_read(self) -> None:
        self.execute("BEGIN ISOLATION LEVEL REPEATABLE READ, READ ONLY")

    def commit(self) -> None:
        self.execute("COMMIT")

    def rollback(self) -> None:
        if self.in_transaction:
            self.conn.execute("ROLLBACK")

    @property
    def in_transaction(self) -> bool:
        from psycopg.pq import TransactionStatus

        if self.conn.closed:
            return False
        return bool(self.conn.info.transaction_status != TransactionStatus.IDLE)

    def table_names(self) -> list[str]:
        rows = self.execute(
            "SELECT table_name FROM information_schema.tables "
            "WHERE table_schema = current_schema() ORDER BY table_name"
        ).fetchall()
        return [r[0] for r in rows]

    def columns(self, table: str) -> list[str]:
        rows = self.execute(
            "SELECT column_name FROM information_schema.columns "
            "WHERE table_schema = current_schema() AND table_name = ? ORDER BY ordinal_position",
            (table,),
        ).fetchall()
        return [r[0] for r in rows]

    def sync_identities(self) -> None:
        """Move every identity column's sequence past the largest id (rows a migration
        inserted with their id, as SQLite's rowids would count on); never backwards."""
        rows = self.execute(
            "SELECT table_name, column_name FROM information_schema.columns "
            "WHERE table_schema = current_schema() AND is_identity = 'YES'"
        ).fetchall()
        for table, column in rows:
            self.execute(
                f"SELECT setval(pg_get_serial_sequence('{table}', '{column}'), "
                f"GREATEST((SELECT COALESCE(MAX({column}), 0) FROM {table}) + 1, "
                f"nextval(pg_get_serial_sequence('{table}', '{column}'))), false)"
            )

    def integrity_ok(self) -> bool:
        """The server answers (PostgreSQL checks its pages itself; there is no file check)."""
        return bool(self.execute("SELECT 1").fetchone()[0] == 1)

    def close(self) -> None:
        self.conn.close()


_DDL = re.compile(r"^\s*(CREATE\s+TABLE|ALTER\s+TABLE)", re.IGNORECASE)
_TYPES = [
    (
        re.compile(r"\bINTEGER\s+PRIMARY\s+KEY(\s+AUTOINCREMENT)?\b", re.I),
        "BIGINT GENERATED BY DEFAULT AS IDENTITY PRIMARY KEY",
    ),
    (re.compile(r"\bINTEGER\b", re.I), "BIGINT"),
    (re.compile(r"\bREAL\b", re.I), "DOUBLE PRECISION"),
    (re.compile(r"\bBLOB\b", re.I), "BYTEA"),
    # SQLite adds truth values as integers: (a IS NOT NULL) + (b IS NOT NULL) = 1
    (re.compile(r"(\(\s*\w+\s+IS\s+NOT\s+NULL\s*\))(?!::)(?=\s*\+)", re.I), r"\1::int"),
    (re.compile(r"(\+\s*)(\(\s*\w+\s+IS\s+NOT\s+NULL\s*\))(?!::)", re.I), r"\1\2::int"),
]


@functools.lru_cache(maxsize=1024)
def to_postgres(sql: str) -> str:
    """The project's SQL for psycopg: ``?`` outside string literals becomes ``%s``, a ``%``
    ``%%``, comments go; in ``CREATE TABLE`` / ``ALTER TABLE`` SQLite's type names become
    PostgreSQL's (module docstring). ``ValueError`` for numbered ``?NNN`` placeholders."""
    out: list[str] = []
    i, n = 0, len(sql)
    while i < n:
        c = sql[i]
        if c == "'":
            end = sql.index("'", i + 1)
            while end + 1 < n and sql[end + 1] == "'":  # '' inside a literal
                end = sql.index("'", end + 2)
            out.append(sql[i : end + 1].replace("%", "%%"))
            i = end + 1
        elif sql.startswith("--", i):
            end = sql.find("\n", i)
            i = n if end < 0 else end
        elif c == "?":
            if i + 1 < n and sql[i + 1].isdigit():
                raise ValueError(f"numbered placeholders are not portable: {sql!r}")
            out.append("%s")
            i += 1
        elif c == "%":
            out.append("%%")
            i += 1
        else:
            out.append(c)
            i += 1
    text = "".join(out)
    if _DDL.match(text):
        for pattern, replacement in _TYPES:
            text = pattern.sub(replacement, text)
    return text
