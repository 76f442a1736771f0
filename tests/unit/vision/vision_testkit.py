"""Helpers for the vision tests: synthetic textured scenes and small indexes."""

from __future__ import annotations

import cv2
import numpy as np

from server.vision import EngineParams, ImageFeatures, TourIndex, extract
from server.vision.homing import zoom_image


def scene(seed: int, size: tuple[int, int] = (320, 240)) -> np.ndarray:
    """A random but repeatable textured colour image (rectangles, circles, lines) BGR uint8."""
    rng = np.random.default_rng(seed)
    w, h = size
    img = np.full((h, w, 3), rng.integers(40, 200, size=3), np.uint8)
    for _ in range(25):
        colour = tuple(int(c) for c in rng.integers(0, 256, size=3))
        kind = rng.integers(3)
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        if kind == 0:
            x2, y2 = int(rng.integers(0, w)), int(rng.integers(0, h))
            cv2.rectangle(img, (x, y), (x2, y2), colour, -1)
        elif kind == 1:
            cv2.circle(img, (x, y), int(rng.integers(5, 40)), colour, -1)
        else:
            x2, y2 = int(rng.integers(0, w)), int(rng.integers(0, h))
            cv2.line(img, (x, y), (x2, y2), colour, int(rng.integers(1, 5)))
    return img


def shifted(img: np.ndarray, dx: int) -> np.ndarray:
    """``img`` translated right by ``dx`` px (border replicated)."""
    m = np.array([[1, 0, dx], [0, 1, 0]], dtype=np.float32)
    return cv2.warpAffine(img, m, (img.shape[1], img.shape[0]), borderMode=cv2.BORDER_REPLICATE)


def zoomed(img: np.ndarray, factor: float) -> np.ndarray:
    """``img`` magnified ``factor`` times about its centre (border replicated): what a camera
    a little further forward (> 1) or back (< 1) would see of a flat scene."""
    return zoom_image(img, factor)


def index_of(
    images: list[np.ndarray], states: list[int], params: EngineParams | None = None
) -> tuple[TourIndex, list[ImageFeatures]]:
    params = params or EngineParams()
    feats = [extract(im, params.features) for im in images]
    idx = TourIndex(params)
    idx.add(feats, states)
    return idx, feats
