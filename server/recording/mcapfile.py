"""One recording being written: an MCAP file that survives a crash up to its last whole frame.

Messages are written unchunked (each record goes straight to the file; the camera's JPEG is
compressed already, and the JSON of a frame is ~2 kB) and the file is flushed to the operating
system after every frame, so a server killed mid-task leaves every finished frame readable
(:mod:`server.recording.reader` reads up to the last ``/frame`` message). :meth:`McapFile.close`
writes MCAP's summary and footer (statistics, the channels), which a complete file has.
"""

from __future__ import annotations

import base64
import json
from pathlib import Path
from typing import IO, Any

from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer

from server.recording.topics import SCHEMAS

PROFILE = "teachrepeat"
"""The MCAP profile of a recording (its header says so)."""
FORMAT_VERSION = 1
"""Version of what the channels hold; the reader refuses newer ones."""


def _json_default(value: object) -> object:
    """JSON for what ``json`` cannot write: bytes as base64 (Foxglove's ``contentEncoding``)."""
    if isinstance(value, bytes | bytearray | memoryview):
        return base64.b64encode(bytes(value)).decode("ascii")
    if hasattr(value, "item"):  # a NumPy scalar
        return value.item()
    raise TypeError(f"cannot write {type(value).__name__} into a recording")


def encode(payload: dict[str, Any]) -> bytes:
    """The JSON bytes of one message (compact; bytes as base64; no NaN or infinity)."""
    return json.dumps(
        payload, separators=(",", ":"), default=_json_default, allow_nan=False
    ).encode()


class McapFile:
    """Writes one recording. Not thread-safe: one writer thread owns it.

    ``metadata`` goes into the file's ``teachrepeat`` metadata record (strings only).
    ``max_bytes``: :meth:`full` says when the file has reached it."""

    def __init__(self, path: Path, *, metadata: dict[str, str], max_bytes: int) -> None:
        self.path = Path(path)
        self.max_bytes = max_bytes
        self._fh: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(
            self._fh,
            compression=CompressionType.NONE,
            use_chunking=False,
            use_summary_offsets=True,
        )
        self._writer.start(profile=PROFILE, library=f"teachrepeat recording {FORMAT_VERSION}")
        self._writer.add_metadata("teachrepeat", metadata)
        self._channels: dict[str, int] = {}
        self._sequence = 0
        self.messages = 0
        self.frames = 0
        self.closed = False
        self._fh.flush()

    def _channel(self, topic: str) -> int:
        channel = self._channels.get(topic)
        if channel is None:
            name, schema = SCHEMAS[topic]
            schema_id = self._writer.register_schema(
                name=name, encoding=SchemaEncoding.JSONSchema, data=encode(schema)
            )
            channel = self._writer.register_channel(
                topic=topic, message_encoding=MessageEncoding.JSON, schema_id=schema_id
            )
            self._channels[topic] = channel
        return channel

    def write(self, topic: str, payload: dict[str, Any], log_ns: int) -> None:
        """Write one message on ``topic`` (a channel of :data:`SCHEMAS`) at ``log_ns``
        (wall clock, ns since the Unix epoch)."""
        channel = self._channel(topic)
        self._sequence += 1
        self._writer.add_message(
            channel_id=channel,
            log_time=log_ns,
            publish_time=log_ns,
            data=encode(payload),
            sequence=self._sequence,
        )
        self.messages += 1

    def end_frame(self) -> None:
        """A frame is whole: hand it to the operating system (it survives the process)."""
        self.frames += 1
        self._fh.flush()

    @property
    def size(self) -> int:
        return self._fh.tell()

    def full(self) -> bool:
        return self.size >= self.max_bytes

    def close(self) -> None:
        """Write the summary and the footer; close the file (idempotent)."""
        if self.closed:
            return
        self.closed = True
        try:
            self._writer.finish()
        finally:
            self._fh.close()
