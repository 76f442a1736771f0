"""Cameras: a real device or video file through OpenCV, and a folder of recorded images."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from robot_client.drivers.base import Image
from server.imaging import encode_jpeg

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp")


class OpenCVCamera:
    """A V4L2/USB camera by device index, or a video file by path, through ``cv2.VideoCapture``.

    ``width``/``height`` ask the device for a capture size (ignored by video files).
    """

    def __init__(self, source: int | str, *, width: int | None = None, height: int | None = None):
        self._cap = cv2.VideoCapture(source)
        if not self._cap.isOpened():
            raise OSError(f"cannot open camera {source!r}: check the device index or file path")
        if width:
            self._cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
        if height:
            self._cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)

    def read(self) -> Image | None:
        ok, frame = self._cap.read()
        return np.asarray(frame, dtype=np.uint8) if ok else None

    def close(self) -> None:
        self._cap.release()


class FolderCamera:
    """Replays the images of a folder in file-name order (a recorded traversal)."""

    def __init__(self, folder: Path | str) -> None:
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise FileNotFoundError(f"no such folder of frames: {self.folder}")
        self.paths = sorted(p for p in self.folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self.paths:
            raise FileNotFoundError(f"no images ({', '.join(IMAGE_SUFFIXES)}) in {self.folder}")
        self._next = 0

    def __len__(self) -> int:
        return len(self.paths)

    def read(self) -> Image | None:
        path = self._advance()
        if path is None:
            return None
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            raise OSError(f"cannot decode image {path}")
        return np.asarray(image, dtype=np.uint8)

    def read_jpeg(self) -> bytes | None:
        """The next frame as JPEG bytes: the file itself when it is a JPEG, else re-encoded."""
        path = self._advance()
        if path is None:
            return None
        if path.suffix.lower() in (".jpg", ".jpeg"):
            return path.read_bytes()
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            raise OSError(f"cannot decode image {path}")
        return encode_jpeg(np.asarray(image, np.uint8), 95)

    def _advance(self) -> Path | None:
        if self._next >= len(self.paths):
            return None
        self._next += 1
        return self.paths[self._next - 1]

    def close(self) -> None:
        self._next = len(self.paths)
