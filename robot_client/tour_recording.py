"""A guided tour as the server receives it, kept in one file so it can be taught again.

Walking and rendering a tour is the slow part of teaching a simulated home; a benchmark that
starts several servers (one per worker) records the tour once and uploads the recording to
each of them through the same REST calls. The file is a NumPy ``.npz`` archive (no pickles):
the JPEG bytes of every image end to end, their offsets, the step kinds, times and motions, the
simulator's true pose of every image (format 2; NaN where there is none), the depth profile sent
with it (format 3; a row of NaN where none), and a JSON header (format version, the plan's
SHA-256, the route, the place names).
"""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

FORMAT = 3
"""Version of the file layout written; :data:`READABLE` ones are read, others refused."""
READABLE = (1, 2, 3)
"""Format 1 has no poses (its steps read with ``pose`` None), formats 1 and 2 no depth
profiles (``depth`` None)."""

KINDS = ("frame", "spin", "mark")


@dataclass(frozen=True)
class RecordedStep:
    """One moment of a tour: ``kind`` ``"frame"`` (an image of the path to ``place``),
    ``"spin"`` (an image of the spin at ``place``) or ``"mark"`` ("this is ``place``": no
    image). ``t`` robot seconds, ``v`` m/s and ``w`` rad/s executed while the image was taken;
    ``pose`` ``(x, y, theta)`` (m, m, rad) where the camera was (the simulator's truth, for
    the judge: never uploaded), or ``None``; ``depth`` the depth profile sent with the image
    (metres, left to right), or ``None``."""

    kind: str
    place: str
    t: float
    v: float
    w: float
    jpeg: bytes | None
    pose: tuple[float, float, float] | None = None
    depth: tuple[float, ...] | None = None


class RecordingError(ValueError):
    """The file is not a tour recording this version can read; teach the tour again."""


@dataclass(frozen=True)
class TourRecording:
    """Every step of a guided tour with its image. ``plan_sha256`` names the plan walked."""

    plan_sha256: str
    route: tuple[str, ...]
    steps: tuple[RecordedStep, ...]

    @property
    def images(self) -> int:
        """Number of images (frames and spin images)."""
        return sum(s.jpeg is not None for s in self.steps)

    def save(self, path: Path) -> None:
        """Write the recording to ``path`` (``.npz``), atomically (a temporary file of its
        own renamed: two benchmarks walking the same tour into one cache at once each write
        a whole file, and the last one renamed wins)."""
        names = sorted({s.place for s in self.steps})
        blobs = [s.jpeg or b"" for s in self.steps]
        offsets = np.cumsum([0, *(len(b) for b in blobs)], dtype=np.int64)
        header = {
            "format": FORMAT,
            "plan_sha256": self.plan_sha256,
            "route": list(self.route),
            "places": names,
        }
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=path.name + ".", suffix=".part", dir=path.parent)
        tmp = Path(name)
        try:
            with os.fdopen(fd, "wb") as fh:
                np.savez(
                    fh,
                    header=np.frombuffer(json.dumps(header).encode(), dtype=np.uint8),
                    kind=np.array([KINDS.index(s.kind) for s in self.steps], dtype=np.uint8),
                    place=np.array([names.index(s.place) for s in self.steps], dtype=np.int32),
                    tvw=np.array([(s.t, s.v, s.w) for s in self.steps], dtype=np.float64).reshape(
                        -1, 3
                    ),
                    offsets=offsets,
                    jpeg=np.frombuffer(b"".join(blobs), dtype=np.uint8),
                    pose=np.array(
                        [s.pose if s.pose is not None else (np.nan,) * 3 for s in self.steps],
                        dtype=np.float64,
                    ).reshape(-1, 3),
                    depth=_depth_rows(self.steps),
                )
            tmp.replace(path)
        except BaseException:
            tmp.unlink(missing_ok=True)  # a failed save leaves nothing in the cache
            raise

    @classmethod
    def load(cls, path: Path) -> TourRecording:
        """Read a recording written by :meth:`save`.

        Raises:
            RecordingError: missing, truncated, of another format version, or not a recording.
        """
        try:
            with np.load(path, allow_pickle=False) as z:
                header = json.loads(bytes(z["header"]).decode())
                if header.get("format") not in READABLE:
                    raise RecordingError(
                        f"{path} is a tour recording of format {header.get('format')}, this "
                        f"version reads {READABLE}; delete it and teach again"
                    )
                names = header["places"]
                kind, place, tvw = z["kind"], z["place"], z["tvw"]
                offsets, jpeg = z["offsets"], z["jpeg"].tobytes()
                poses = z["pose"] if "pose" in z.files else np.full((len(kind), 3), np.nan)
                depth = z["depth"] if "depth" in z.files else np.full((len(kind), 0), np.nan)
        except (OSError, ValueError, KeyError, json.JSONDecodeError) as exc:
            if isinstance(exc, RecordingError):
                raise
            raise RecordingError(f"{path} is not a readable tour recording: {exc}") from None
        steps = []
        for k in range(len(kind)):
            blob = jpeg[offsets[k] : offsets[k + 1]]
            steps.append(
                RecordedStep(
                    KINDS[int(kind[k])],
                    names[int(place[k])],
                    float(tvw[k, 0]),
                    float(tvw[k, 1]),
                    float(tvw[k, 2]),
                    blob if KINDS[int(kind[k])] != "mark" else None,
                    _pose(poses[k]),
                    _depth(depth[k]),
                )
            )
        return cls(
            plan_sha256=str(header["plan_sha256"]), route=tuple(header["route"]), steps=tuple(steps)
        )


def _pose(row: np.ndarray) -> tuple[float, float, float] | None:
    """A stored pose row, or ``None`` when it holds NaN (no pose)."""
    if not np.all(np.isfinite(row)):
        return None
    return (float(row[0]), float(row[1]), float(row[2]))


def _depth_rows(steps: tuple[RecordedStep, ...]) -> np.ndarray:
    """``(n_steps, n_rays)`` float64 depth profiles, a row of NaN where a step has none (all
    profiles of one tour have the same number of rays)."""
    n = max((len(s.depth) for s in steps if s.depth is not None), default=0)
    rows = np.full((len(steps), n), np.nan, dtype=np.float64)
    for k, s in enumerate(steps):
        if s.depth is not None:
            if len(s.depth) != n:
                raise ValueError("every depth profile of a tour recording has the same rays")
            rows[k] = s.depth
    return rows


def _depth(row: np.ndarray) -> tuple[float, ...] | None:
    """A stored depth row, or ``None`` when it holds NaN (none was sent)."""
    if len(row) == 0 or not np.all(np.isfinite(row)):
        return None
    return tuple(float(r) for r in row)
