"""Where recordings live on disk, what they are called, and which ones are kept.

One folder per household under the recordings folder (``household<ID>/``), one file per
teaching tour or navigation task, named by robot, tour and time::

    household1/rover.tour3.20261126-101502.task17.mcap
    household1/rover.tour3.20261126-093011.teach.mcap

Robot names hold no dot, so a file belongs to exactly one robot; a household's robots never
see another household's folder. The file name is the index: nothing about recordings is kept in
the database. Retention (:class:`Retention`) deletes the oldest finished recordings, over all
households, once there are too many or they take too much space.
"""

from __future__ import annotations

import calendar
import contextlib
import re
import time
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path

from server import schemas
from server.errors import NotFound

NAME = re.compile(
    r"^(?P<robot>[a-z0-9][a-z0-9_-]{0,63})\.tour(?P<tour>[0-9]{1,16})\."
    r"(?P<date>[0-9]{8}-[0-9]{6})(?:-(?P<n>[0-9]{1,3}))?\."
    r"(?P<kind>teach|task(?P<task>[0-9]{1,16}))\.mcap$"
)
"""A recording's file name (the same pattern as :data:`server.schemas.RecordingName`)."""
SUFFIX = ".mcap"


@dataclass(frozen=True)
class Retention:
    """How much is kept. ``keep_files`` (200) recordings and ``keep_bytes`` (2 GB) over all
    households: when a recording ends, the oldest finished ones are deleted until both hold.
    ``file_bytes`` (500 MB): a recording takes no more frames past this size."""

    keep_files: int = 200
    keep_bytes: int = 2_000_000_000
    file_bytes: int = 500_000_000

    def __post_init__(self) -> None:
        if self.keep_files < 1 or self.keep_bytes <= 0 or self.file_bytes <= 0:
            raise ValueError(f"retention limits must be positive, got {self}")


@dataclass(frozen=True)
class RecordingFile:
    """A recording on disk, as its name and folder describe it."""

    path: Path
    household: int
    robot: str
    tour: int
    task: int | None  # the navigation task's id; None for a teaching tour
    started_at: float  # Unix time, s (whole seconds, UTC, from the name)
    size_bytes: int
    modified_at: float  # Unix time, s

    @property
    def name(self) -> str:
        return self.path.name

    @property
    def kind(self) -> str:
        return "teach" if self.task is None else "navigate"

    def public(self, *, open_now: bool) -> schemas.RecordingPublic:
        return schemas.RecordingPublic(
            name=self.name,
            kind="teach" if self.task is None else "navigate",
            tour=self.tour,
            task=self.task,
            started_at=self.started_at,
            size_bytes=self.size_bytes,
            recording=open_now,
        )


def parse(path: Path, household: int) -> RecordingFile | None:
    """The recording ``path`` names, or ``None`` for a file that is not one."""
    found = NAME.match(path.name)
    if found is None:
        return None
    try:
        st = path.stat()
    except OSError:  # deleted meanwhile
        return None
    started = calendar.timegm(time.strptime(found["date"], "%Y%m%d-%H%M%S"))
    task = found["task"]
    return RecordingFile(
        path=path,
        household=household,
        robot=found["robot"],
        tour=int(found["tour"]),
        task=None if task is None else int(task),
        started_at=float(started),
        size_bytes=st.st_size,
        modified_at=st.st_mtime,
    )


class RecordingStore:
    """The recordings folder: new file names, listings per household and robot, retention."""

    def __init__(self, root: Path, retention: Retention | None = None) -> None:
        self.root = Path(root)
        self.retention = retention or Retention()

    def folder(self, household: int) -> Path:
        return self.root / f"household{int(household)}"

    def new_path(
        self, household: int, robot: str, tour: int, task: int | None, started_at: float
    ) -> Path:
        """A fresh file name for a recording starting at ``started_at`` (Unix time, s); the
        household's folder is created. Never an existing file (a suffix -1, -2 ... is added)."""
        folder = self.folder(household)
        folder.mkdir(parents=True, exist_ok=True)
        stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime(started_at))
        kind = "teach" if task is None else f"task{int(task)}"
        for n in range(1000):
            suffix = "" if n == 0 else f"-{n}"
            path = folder / f"{robot}.tour{int(tour)}.{stamp}{suffix}.{kind}{SUFFIX}"
            if not NAME.match(path.name):
                raise ValueError(f"not a recording name: {path.name}")
            with contextlib.suppress(FileExistsError):
                path.touch(exist_ok=False)
                return path
        raise FileExistsError(f"no free recording name for {robot} at {stamp} in {folder}")

    def files(self, household: int | None = None, robot: str | None = None) -> list[RecordingFile]:
        """The recordings of ``household`` (every household's with ``None``), of ``robot`` only
        when given; newest first."""
        if household is None:
            folders = sorted(self.root.glob("household*")) if self.root.is_dir() else []
        else:
            folders = [self.folder(household)]
        out: list[RecordingFile] = []
        for folder in folders:
            found = re.fullmatch(r"household([0-9]+)", folder.name)
            if found is None or not folder.is_dir():
                continue
            pattern = f"{robot}.tour*{SUFFIX}" if robot is not None else f"*{SUFFIX}"
            for path in folder.glob(pattern):
                rec = parse(path, int(found[1]))
                if rec is not None and (robot is None or rec.robot == robot):
                    out.append(rec)
        out.sort(key=lambda r: (r.started_at, r.modified_at, r.name), reverse=True)
        return out

    def find(self, household: int, robot: str, name: str) -> RecordingFile:
        """Robot ``robot``'s recording ``name`` in ``household``'s folder; :class:`NotFound`
        otherwise (another robot's or household's recording is answered the same way)."""
        found = NAME.match(name)
        if found is None or found["robot"] != robot:
            raise NotFound(
                f"robot {robot!r} has no recording {name!r}; GET /robots/{robot}/recordings "
                "lists them"
            )
        rec = parse(self.folder(household) / name, household)
        if rec is None:
            raise NotFound(
                f"robot {robot!r} has no recording {name!r} (it may have been deleted to keep "
                f"within the retention limits); GET /robots/{robot}/recordings lists them"
            )
        return rec

    def enforce(self, open_paths: Collection[Path] = ()) -> list[Path]:
        """Delete the oldest finished recordings until at most ``keep_files`` are left and
        they take at most ``keep_bytes``; recordings being written are never deleted. Returns
        the deleted paths."""
        everything = sorted(self.files(), key=lambda r: (r.modified_at, r.name))
        keep = self.retention
        count = len(everything)
        total = sum(r.size_bytes for r in everything)
        opened = {Path(p) for p in open_paths}
        deleted: list[Path] = []
        for rec in everything:
            if count <= keep.keep_files and total <= keep.keep_bytes:
                break
            if rec.path in opened:
                continue
            with contextlib.suppress(FileNotFoundError):
                rec.path.unlink()
            deleted.append(rec.path)
            count -= 1
            total -= rec.size_bytes
        return deleted
