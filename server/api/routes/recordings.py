"""A robot's recordings: list them, download one (an MCAP file; docs/recording.md)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated, BinaryIO

from fastapi import APIRouter, Path
from fastapi.responses import StreamingResponse

from server import schemas
from server.api.deps import RobotDep, ServicesDep
from server.errors import NotFound

router = APIRouter(prefix="/robots/{robot}/recordings", tags=["recordings"])
NameParam = Annotated[schemas.RecordingName, Path(description="The recording's file name.")]
CHUNK = 1 << 20


@router.get("", response_model=list[schemas.RecordingPublic])
def list_recordings(robot: RobotDep, services: ServicesDep) -> list[schemas.RecordingPublic]:
    """The robot's recorded teaching tours and navigation tasks, newest first."""
    return services.recordings.recordings(robot)


@router.get(
    "/{name}",
    response_class=StreamingResponse,
    responses={
        200: {
            "content": {"application/octet-stream": {"schema": {"type": "string"}}},
            "description": "The MCAP file (as far as it is written, for one being recorded).",
        }
    },
)
def get_recording(name: NameParam, robot: RobotDep, services: ServicesDep) -> StreamingResponse:
    """One recording of the robot, as an MCAP file: open it in Foxglove, replay it with
    `teachrepeat replay FILE`, or scrub it on the dashboard's Timeline."""
    found = services.recordings.file(robot, name)
    size = found.size_bytes  # a recording still being written is sent as it was now
    try:
        fh = open(found.path, "rb")  # noqa: SIM115 - closed by _read
    except FileNotFoundError:
        raise NotFound(f"recording {name!r} was deleted meanwhile (retention)") from None
    return StreamingResponse(
        _read(fh, size),
        media_type="application/octet-stream",
        headers={
            "Content-Length": str(size),
            "Content-Disposition": f'attachment; filename="{found.name}"',
        },
    )


def _read(fh: BinaryIO, size: int) -> Iterator[bytes]:
    """The first ``size`` bytes of ``fh``, a chunk at a time; closes it."""
    with fh:
        left = size
        while left > 0:
            chunk = fh.read(min(CHUNK, left))
            if not chunk:
                return
            left -= len(chunk)
            yield chunk
