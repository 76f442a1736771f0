"""``teachrepeat robot teach``: replay a recorded folder of images as a teaching tour.

The marks file is CSV, one row per named place: ``frame index, location name``. The frame at a
mark is where the place is reached: it becomes the place's image (its "spin"), and the frames
since the previous mark become the edge between the two places. Frames before the first mark
and after the last one belong to no path and are not uploaded.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from robot_client.client import ApiError, TeachRepeatClient
from robot_client.credentials import add_pinning_arguments, add_token_arguments, read_token
from robot_client.drivers.cameras import FolderCamera
from server import schemas


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--server", required=True, help="server URL, e.g. http://127.0.0.1:8000")
    add_token_arguments(parser)
    add_pinning_arguments(parser)
    _add_teach_arguments(parser)


def _add_teach_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--tour", required=True, help="tour name (created when missing)")
    parser.add_argument("--frames", required=True, type=Path, help="folder of images, in order")
    parser.add_argument("--marks", required=True, type=Path, help="CSV: frame index, place name")
    parser.add_argument("--fps", type=float, default=10.0, help="frame rate of the recording")
    parser.add_argument("--speed", type=float, default=0.3, help="forward speed while taught, m/s")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def read_marks(path: Path) -> dict[int, str]:
    """``{frame index: place name}`` from a CSV file; a clear error for every bad row."""
    marks: dict[int, str] = {}
    with path.open(newline="") as fh:
        for line, row in enumerate(csv.reader(fh), start=1):
            if not row or row[0].strip().startswith("#"):
                continue
            if len(row) != 2:
                raise ValueError(f"{path}:{line}: expected 'frame index, place name', got {row}")
            index_text, name = row[0].strip(), row[1].strip()
            if line == 1 and not index_text.isdigit():
                continue  # header
            if not index_text.isdigit():
                raise ValueError(f"{path}:{line}: frame index {index_text!r} is not a number")
            if not name:
                raise ValueError(f"{path}:{line}: the place name is empty")
            index = int(index_text)
            if index in marks:
                raise ValueError(f"{path}:{line}: frame {index} is marked twice")
            marks[index] = name
    if not marks:
        raise ValueError(f"{path}: no marks; give at least one 'frame index, place name' row")
    return marks


@dataclass(frozen=True)
class TeachReport:
    tour: schemas.TourGraphPublic
    uploaded: int
    skipped: int
    seconds: float

    @property
    def frames_per_second(self) -> float:
        return self.uploaded / self.seconds if self.seconds > 0 else 0.0


def teach_folder(
    client: TeachRepeatClient,
    *,
    tour: str,
    frames: Path,
    marks: dict[int, str],
    fps: float = 10.0,
    speed: float = 0.3,
    progress: bool = True,
) -> TeachReport:
    """Teach ``tour`` from the images in ``frames`` with the places in ``marks``, as a robot
    driving it at ``speed`` m/s and ``fps`` frames a second would."""
    me = client.whoami()
    if me.robot is None:
        raise ApiError(403, "teaching needs a robot token, not the admin token", "forbidden")
    robot = me.robot
    camera = FolderCamera(frames)
    if max(marks) >= len(camera):
        raise ValueError(f"mark at frame {max(marks)} but {frames} holds {len(camera)} frames")
    tour_id = client.tour_named(tour, create=True).id
    client.start_teaching(robot, tour_id)
    first, last = min(marks), max(marks)
    uploaded = skipped = 0
    started = time.perf_counter()
    try:
        with tqdm(total=len(camera), unit="frame", disable=not progress, desc=tour) as bar:
            for index in range(len(camera)):
                jpeg = camera.read_jpeg()
                bar.update(1)
                if jpeg is None:
                    break
                if index < first or index > last:
                    skipped += 1
                    continue
                timestamp = index / fps
                if index in marks:
                    client.mark_location(robot, marks[index])
                    client.upload_spin_image(robot, jpeg, timestamp=timestamp)
                else:
                    client.upload_frame(robot, jpeg, timestamp=timestamp, v=speed)
                uploaded += 1
        ended = client.finish_teaching(robot)
    except BaseException:
        with contextlib.suppress(ApiError, OSError):
            client.abort_teaching(robot)
        raise
    finally:
        camera.close()
    return TeachReport(ended.tour, uploaded, skipped, time.perf_counter() - started)


def run(args: argparse.Namespace) -> int:
    try:
        marks = read_marks(args.marks)
        token = read_token(args)
        with TeachRepeatClient(
            args.server, token, ca_cert=args.ca_cert, fingerprint=args.fingerprint
        ) as client:
            report = teach_folder(
                client,
                tour=args.tour,
                frames=args.frames,
                marks=marks,
                fps=args.fps,
                speed=args.speed,
                progress=not args.quiet,
            )
    except (ApiError, ValueError, OSError) as exc:
        print(f"teaching failed: {exc}", file=sys.stderr)
        return 1
    tour = report.tour
    print(
        f"taught {tour.name!r}: {len(tour.locations)} places, {len(tour.edges)} edges, "
        f"{report.uploaded} images in {report.seconds:.2f} s "
        f"({report.frames_per_second:.0f} frames/s); {report.skipped} frames outside the marks"
    )
    for edge in tour.edges:
        print(
            f"  {edge.source_name} -> {edge.target_name}: {edge.image_count} images, "
            f"{edge.duration_s:.1f} s"
        )
    return 0
