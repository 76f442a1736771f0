"""Photometric changes of an image: the light of another hour, another bulb or another season.

The engine learns each tour's signature weights (:func:`server.vision.index.learn_weights`)
from the tour alone. Learned on one traversal only, they reward whatever separates places *in
that light* (colour, histograms), which is exactly what changes by evening or by season. So the
learning also sees every sampled tour image under a changed light (:func:`photometric_change`),
and rewards the signature blocks that stay close to the taught image under the change while
still telling places apart.

A change moves pixel values only, never pixels: geometry (corners, edges, the layout of the
scene) is untouched. It composes, each with its own random strength drawn from ``rng``:

* **gain** per colour channel (a dimmer, warmer or cooler light),
* **gamma** (the camera's exposure curve; dark or washed-out images),
* **contrast** around the image mean (haze, a low sun, a flat overcast sky),
* **shading**: a smooth multiplicative field (light from another side, lamps on or off,
  vignetting; the ``lighting`` condition of the simulator changes ambient against direct light),
* **blur** (focus, motion) and **noise** (a dark, amplified sensor).

Pure: NumPy and OpenCV only.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt


@dataclass(frozen=True)
class ChangeParams:
    """Ranges of one photometric change; each strength is drawn uniformly in its range.

    Attributes:
        gain: per-channel multiplicative gain range (1 = unchanged).
        warm_tint: largest extra red-over-blue ratio of a warm (or, mirrored, cool) light.
        gamma: exponent range of ``out = 255 * (in / 255) ** gamma`` (drawn log-uniformly).
        contrast: factor range around the image mean (1 = unchanged).
        shading: largest deviation of the smooth multiplicative field from 1.
        colour_shading: largest deviation of a second smooth field, one per colour channel
            (light of different colours from different sides; foliage, snow or a wall that
            changed colour in one part of the view).
        saturation: factor range of the colour's distance from grey (0 = grey, 1 = unchanged).
        shading_cells: the field is a random ``cells x cells`` grid, smoothly upsampled.
        blur_sigma: Gaussian blur sigma range (px at the image's own size); 0 = none.
        noise_sigma: additive Gaussian noise range (grey levels).
    """

    gain: tuple[float, float] = (0.4, 1.3)
    warm_tint: float = 0.35
    gamma: tuple[float, float] = (0.6, 1.8)
    contrast: tuple[float, float] = (0.5, 1.1)
    shading: float = 0.45
    colour_shading: float = 0.0
    saturation: tuple[float, float] = (1.0, 1.0)
    shading_cells: int = 3
    blur_sigma: tuple[float, float] = (0.0, 1.5)
    noise_sigma: tuple[float, float] = (0.0, 6.0)

    def __post_init__(self) -> None:
        for name in ("gain", "gamma", "contrast", "saturation", "blur_sigma", "noise_sigma"):
            lo, hi = getattr(self, name)
            if not 0.0 <= lo <= hi:
                raise ValueError(f"{name} must be a range 0 <= low <= high, got {(lo, hi)}")
        if self.gain[0] <= 0.0 or self.gamma[0] <= 0.0:
            raise ValueError("gain and gamma must be positive")
        if not all(0.0 <= v < 1.0 for v in (self.shading, self.colour_shading, self.warm_tint)):
            raise ValueError("shading, colour_shading and warm_tint must lie in [0, 1)")
        if self.shading_cells < 2:
            raise ValueError("shading_cells must be at least 2")


def photometric_change(
    image: npt.NDArray[np.uint8],
    rng: np.random.Generator,
    params: ChangeParams = ChangeParams(),
) -> npt.NDArray[np.uint8]:
    """One random photometric change of ``image`` (see the module docstring).

    Args:
        image: ``(H, W, 3)`` BGR or ``(H, W)`` grey ``uint8``.
        rng: source of the change's strengths (deterministic for a seeded generator).
        params: ranges of the strengths.

    Returns:
        An image of the same shape and dtype; pixel positions are unchanged.
    """
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3):
        raise ValueError(f"expected an (H, W[, 3]) uint8 image, got {img.dtype} {img.shape}")
    x = img.astype(np.float32) / 255.0
    h, w = x.shape[:2]
    gamma = float(np.exp(rng.uniform(*np.log(params.gamma))))
    x = np.power(x, gamma, dtype=np.float32)
    if x.ndim == 3:
        gain = rng.uniform(*params.gain)
        tint = rng.uniform(-params.warm_tint, params.warm_tint)  # > 0 warm, < 0 cool
        x *= np.array([gain * (1.0 - tint), gain, gain * (1.0 + tint)], np.float32)  # B, G, R
    else:
        x *= np.float32(rng.uniform(*params.gain))
    contrast = np.float32(rng.uniform(*params.contrast))
    mean = np.float32(x.mean())
    x = (x - mean) * contrast + mean
    shade = _field(rng, params.shading, params.shading_cells, (h, w))
    x *= shade[:, :, None] if x.ndim == 3 else shade
    if x.ndim == 3:
        grey = x.mean(axis=2, keepdims=True)
        x = grey + (x - grey) * np.float32(rng.uniform(*params.saturation))
        if params.colour_shading > 0:
            x *= np.stack(
                [_field(rng, params.colour_shading, params.shading_cells, (h, w)) for _ in "bgr"],
                axis=2,
            )
    sigma = float(rng.uniform(*params.blur_sigma))
    if sigma > 0.05:
        x = cv2.GaussianBlur(x, (0, 0), sigma)
    out = x * 255.0 + rng.normal(0.0, rng.uniform(*params.noise_sigma), size=x.shape)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def _field(
    rng: np.random.Generator, amplitude: float, cells: int, shape: tuple[int, int]
) -> npt.NDArray[np.float32]:
    """A smooth ``(H, W) float32`` multiplicative field in about ``1 +- amplitude``: a random
    ``cells x cells`` grid, bicubically upsampled."""
    grid = rng.uniform(1.0 - amplitude, 1.0 + amplitude, size=(cells, cells)).astype(np.float32)
    field = cv2.resize(grid, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC)
    return np.asarray(field, np.float32)
