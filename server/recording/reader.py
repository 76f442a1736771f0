"""Reading a recording back: its metadata, tour, frames and log, up to its last whole frame.

Records are read one after the other (MCAP's stream reader), so a file without its summary and
footer (the server was killed mid-task) reads as far as it was written: every frame whose
``/frame`` message is in the file. :class:`Recording` says whether the file was complete.
"""

from __future__ import annotations

import base64
import json
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcap.exceptions import McapError
from mcap.records import Channel, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

from server.recording import topics
from server.recording.mcapfile import FORMAT_VERSION, PROFILE
from server.recording.messages import compared

MAGIC = b"\x89MCAP0\r\n"


class RecordingError(Exception):
    """A file that cannot be read as a recording; the message says what to do."""


@dataclass(frozen=True)
class RecordedFrame:
    """One whole frame: what the robot sent and (navigating) what the server made of it.

    ``timestamp``: robot clock, s; ``wall``: server clock, Unix s; ``v`` m/s, ``w`` rad/s;
    ``depth``: ranges in metres, leftmost first; ``kind``: navigate, path or spin;
    ``messages``: every message of the frame by topic (JSON as written)."""

    index: int
    timestamp: float
    wall: float
    kind: str
    jpeg: bytes
    v: float
    w: float
    depth: tuple[float, ...] | None
    messages: dict[str, dict[str, Any]]

    def compared(self) -> dict[str, Any]:
        """What ``teachrepeat replay`` compares (:func:`server.recording.messages.compared`)."""
        return compared(self.messages)

    @property
    def belief(self) -> dict[str, Any] | None:
        return self.messages.get(topics.BELIEF)

    @property
    def votes(self) -> dict[str, Any] | None:
        return self.messages.get(topics.VOTES)

    @property
    def command(self) -> dict[str, Any] | None:
        return self.messages.get(topics.COMMAND)


@dataclass(frozen=True)
class Recording:
    """A recording as read. ``meta``: the ``teachrepeat`` metadata record (robot, household,
    kind, tour, fingerprint, task, goal, navigation_overrides ...); ``tour``: the first
    ``/tour`` message; ``start``: the ``/start`` message (navigation); ``logs``: ``(wall s,
    text)`` of every ``/log`` line; ``tasks``: every ``/task`` message; ``complete``: the file
    ends with MCAP's footer; ``cut_at``: where a file that is not complete stops being
    readable (bytes), else ``None``."""

    path: Path
    meta: dict[str, str]
    tour: dict[str, Any] | None
    start: dict[str, Any] | None
    frames: tuple[RecordedFrame, ...]
    logs: tuple[tuple[float, str], ...]
    tasks: tuple[dict[str, Any], ...]
    complete: bool
    cut_at: int | None
    size_bytes: int

    @property
    def kind(self) -> str:
        return self.meta.get("kind", "")

    @property
    def start_belief(self) -> bytes | None:
        """The belief the task started from (``(n_fine,)`` float64 little-endian bytes), or
        ``None`` when it started from the prior."""
        encoded = None if self.start is None else self.start.get("belief")
        return None if not encoded else base64.b64decode(encoded)

    @property
    def start_memory(self) -> dict[str, Any] | None:
        """What the tracker remembered besides the belief when the task started
        (:meth:`server.belief.tracker.TrackerMemory.to_dict`), or ``None`` (the prior, or a
        recording made before it was recorded)."""
        memory = None if self.start is None else self.start.get("memory")
        return memory if isinstance(memory, dict) else None

    def realtime_fps(self) -> float:
        """Frames per second of robot time while it was recorded (0 with fewer than 2)."""
        if len(self.frames) < 2:
            return 0.0
        span = self.frames[-1].timestamp - self.frames[0].timestamp
        return (len(self.frames) - 1) / span if span > 0 else 0.0


class _Builder:
    """Collects records into frames as they are read."""

    def __init__(self) -> None:
        self.meta: dict[str, str] = {}
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.pending: dict[str, dict[str, Any]] = {}
        self.frames: list[RecordedFrame] = []
        self.tour: dict[str, Any] | None = None
        self.start: dict[str, Any] | None = None
        self.logs: list[tuple[float, str]] = []
        self.tasks: list[dict[str, Any]] = []
        self.profile = ""

    def add(self, record: object) -> None:
        if isinstance(record, Schema):
            self.schemas[record.id] = record
        elif isinstance(record, Channel):
            self.channels[record.id] = record
        elif isinstance(record, Metadata) and record.name == "teachrepeat":
            self.meta = dict(record.metadata)
        elif isinstance(record, Message):
            channel = self.channels.get(record.channel_id)
            if channel is not None:
                self.message(channel.topic, json.loads(record.data), record.log_time)

    def message(self, topic: str, payload: dict[str, Any], log_ns: int) -> None:
        if topic == topics.TOUR:
            self.tour = self.tour or payload
        elif topic == topics.START:
            self.start = payload
        elif topic == topics.TASK:
            self.tasks.append(payload)
        elif topic == topics.LOG:
            self.logs.append((log_ns / 1e9, str(payload.get("message", ""))))
        elif topic == topics.FRAME:
            self.frame(payload)
        else:
            self.pending[topic] = payload

    def frame(self, closing: dict[str, Any]) -> None:
        messages, self.pending = {**self.pending, topics.FRAME: closing}, {}
        camera = messages.get(topics.CAMERA)
        odometry = messages.get(topics.ODOMETRY) or {}
        depth = messages.get(topics.DEPTH)
        if camera is None:
            return
        self.frames.append(
            RecordedFrame(
                index=int(closing["index"]),
                timestamp=float(closing["timestamp"]),
                wall=float(closing["wall"]),
                kind=str(closing["kind"]),
                jpeg=base64.b64decode(camera["data"]),
                v=float(odometry.get("v", 0.0)),
                w=float(odometry.get("w", 0.0)),
                depth=None if depth is None else tuple(float(r) for r in depth["ranges"]),
                messages=messages,
            )
        )


def read_recording(path: Path | str) -> Recording:
    """Read the recording at ``path`` up to its last whole frame.

    Raises :class:`RecordingError` for a file that is missing, is not MCAP, or is MCAP but not
    a teachrepeat recording (or one written by a newer version)."""
    path = Path(path)
    try:
        fh = open(path, "rb")  # noqa: SIM115 - closed below
    except OSError as exc:
        raise RecordingError(f"cannot open {path}: {exc.strerror}") from None
    with fh:
        head = fh.read(len(MAGIC))
        if head != MAGIC:
            raise RecordingError(
                f"{path} is not an MCAP file (it starts with {head[:8]!r}, not MCAP's magic "
                "bytes); give a recording made by `teachrepeat serve --record DIR` or "
                "`bench navigate --record DIR`"
            )
        fh.seek(0)
        size = path.stat().st_size
        built = _Builder()
        complete = False
        good = 0  # bytes read as whole records
        reader = StreamReader(fh, record_size_limit=size + 1)
        try:
            for record in reader.records:
                built.add(record)
                good = fh.tell()
                if isinstance(record, Footer):
                    complete = True
        except (McapError, ValueError, KeyError, EOFError, struct.error):
            complete = False
    if not built.meta:
        raise RecordingError(
            f"{path} is an MCAP file but not a teachrepeat recording (no 'teachrepeat' "
            "metadata record): it was not written by teachrepeat"
        )
    version = int(built.meta.get("format", "0") or 0)
    if version > FORMAT_VERSION:
        raise RecordingError(
            f"{path} was written by a newer teachrepeat (recording format {version}; this one "
            f"reads {FORMAT_VERSION}): update teachrepeat to read it"
        )
    return Recording(
        path=path,
        meta=built.meta,
        tour=built.tour,
        start=built.start,
        frames=tuple(built.frames),
        logs=tuple(built.logs),
        tasks=tuple(built.tasks),
        complete=complete,
        cut_at=None if complete else good,
        size_bytes=size,
    )


__all__ = ["PROFILE", "RecordedFrame", "Recording", "RecordingError", "read_recording"]
