"""Photographic textures for the simulated home, decoded from files that packages ship.

Two sources, both installed by a package manager and read from disk (nothing is downloaded):

* ``gimp`` - the patterns of the Debian package ``gimp-data`` (``/usr/share/gimp/2.0/patterns``):
  small photographs of wood, parquet, marble, stone, paper, fabric. Format: a big-endian header
  ``(header_size, version, width, height, bytes_per_pixel, b"GPAT", name)`` then raw pixels.
  Another folder can be given with ``TEACHREPEAT_GIMP_PATTERNS``.
* ``skimage`` - the sample photographs shipped inside the ``scikit-image`` wheel (``skimage/data``:
  astronaut, coffee, chelsea, rocket, ...). Only files in the wheel are used, never the ones
  ``skimage.data`` would fetch.

A :class:`TextureSpec` names a source file plus a tint, a tiling and a frame, so "beige wall paint"
is the photographed paper pattern tinted beige. Floor plans refer to textures by the names in
:data:`TEXTURES`. If ``gimp-data`` is missing, its patterns are replaced (with a warning) by the
tinted scikit-image gravel photograph so the simulator still runs, but looks poorer.
"""

from __future__ import annotations

import functools
import importlib.util
import os
import struct
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import numpy.typing as npt
from PIL import Image

RGBImage = npt.NDArray[np.uint8]
"""``(H, W, 3)`` uint8, RGB channel order (what MuJoCo textures use)."""

GIMP_PATTERN_DIR = Path("/usr/share/gimp/2.0/patterns")


class TextureError(ValueError):
    """A texture name is unknown or its source file cannot be read."""


@dataclass(frozen=True)
class TextureSpec:
    """How to make one texture image.

    Attributes:
        source: ``"gimp"`` (a ``.pat`` from gimp-data) or ``"skimage"`` (a scikit-image sample).
        file: path of the file relative to its source folder, e.g. ``"Wood/parque1.pat"``.
        tint: RGB multipliers in [0, 2] applied to the photograph (paint colour on paper, ...).
        tile: the source is repeated ``tile x tile`` times in the output image (small patterns).
        size_m: metres one output image spans on a wall or floor (sets the texture's repeat).
        frame_px: width in pixels of a dark picture frame drawn around the image (0 = none).
    """

    source: Literal["gimp", "skimage"]
    file: str
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    tile: int = 1
    size_m: float = 1.0
    frame_px: int = 0


def _gimp(
    file: str,
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0),
    *,
    tile: int = 4,
    size_m: float = 1.0,
) -> TextureSpec:
    return TextureSpec("gimp", file, tint, tile, size_m)


def _photo(file: str, *, frame_px: int = 14) -> TextureSpec:
    return TextureSpec("skimage", file, frame_px=frame_px)


TEXTURES: dict[str, TextureSpec] = {
    # floors
    "parquet": _gimp("Wood/parque1.pat", tile=6, size_m=1.2),
    "parquet_dark": _gimp("Wood/parque3.pat", tile=6, size_m=1.2),
    "oak_floor": _gimp("Wood/wood5.pat", tile=4, size_m=1.2),
    "marble_tiles": _gimp("Stone/marble2.pat", tile=4, size_m=1.6),
    "checker_tiles": _gimp("Stone/marble3.pat", tile=4, size_m=1.0),
    "slate_floor": _gimp("Stone/slate.pat", (0.9, 0.9, 1.0), tile=4, size_m=1.5),
    "carpet_blue": _gimp("Fabric/burlap.pat", (0.55, 0.7, 1.3), tile=4, size_m=1.0),
    # walls
    "paint_beige": _gimp("Paper/paper.pat", (1.05, 0.97, 0.82), tile=4, size_m=1.5),
    "paint_sage": _gimp("Paper/paper.pat", (0.78, 0.92, 0.76), tile=4, size_m=1.5),
    "paint_blue": _gimp("Paper/crinklepaper.pat", (0.7, 0.82, 1.1), tile=3, size_m=1.5),
    "paint_rose": _gimp("Paper/crinklepaper.pat", (1.05, 0.82, 0.8), tile=3, size_m=1.5),
    "paint_grey": _gimp("Paper/crinklepaper.pat", (0.9, 0.9, 0.88), tile=3, size_m=1.5),
    "brick_wall": _gimp("Stone/brick.pat", tile=4, size_m=1.6),
    "wall_tiles": _gimp("Stone/marble1.pat", (0.95, 1.0, 1.05), tile=4, size_m=1.2),
    "wall_pink": _gimp("Stone/pink_marble.pat", tile=3, size_m=1.4),
    "stone_wall": _gimp("Stone/stone33.pat", tile=3, size_m=1.8),
    "cork": _gimp("Wood/corkboard.pat", tile=4, size_m=1.0),
    "ceiling": _gimp("Paper/paper.pat", (1.0, 1.0, 0.98), tile=4, size_m=2.0),
    # furniture
    "walnut": _gimp("Wood/walnut.pat", tile=2),
    "pine": _gimp("Wood/pine.pat", tile=3),
    "wood_light": _gimp("Wood/wood2.pat", tile=2),
    "wood_red": _gimp("Wood/wood1.pat", tile=2),
    "burlwood": _gimp("Wood/burlwood.pat", tile=2),
    "leather": _gimp("Animal/leather.pat", tile=3),
    "leopard": _gimp("Animal/leopard.pat", tile=3),
    "fabric": _gimp("Fabric/burlap.pat", (1.0, 0.85, 0.6), tile=3),
    "fabric_green": _gimp("Fabric/burlap.pat", (0.6, 1.0, 0.6), tile=3),
    "marble_white": _gimp("Stone/marble1.pat", tile=2),
    "pink_marble": _gimp("Stone/pink_marble.pat", tile=2),
    "granite": _gimp("Stone/granite1.pat", (0.7, 0.7, 0.75), tile=3),
    "leaves": _gimp("Plant/leaves.pat", tile=3),
    "terracotta": _gimp("Stone/terra.pat", tile=3),
    "rock": _gimp("Stone/rock.pat", tile=2),
    "ice": _gimp("Water/ice.pat", tile=2),
    # pictures (scikit-image sample photographs, framed)
    "photo_astronaut": _photo("astronaut.png"),
    "photo_coffee": _photo("coffee.png"),
    "photo_chelsea": _photo("chelsea.png"),
    "photo_rocket": _photo("rocket.jpg"),
    "photo_motorcycle": _photo("motorcycle_left.png"),
    "photo_hubble": _photo("hubble_deep_field.jpg"),
    "photo_camera": _photo("camera.png"),
    "photo_moon": _photo("moon.png"),
    "photo_coins": _photo("coins.png"),
    "photo_page": _photo("page.png"),
    "photo_text": _photo("text.png"),
    "photo_ihc": _photo("ihc.png"),
    "photo_retina": _photo("retina.jpg"),
    "photo_grass": _photo("grass.png"),
    "photo_gravel": _photo("gravel.png"),
    "photo_brick": _photo("brick.png"),
    "photo_clock": _photo("clock_motion.png"),
    # abstract art from patterns, framed
    "art_lightning": TextureSpec("gimp", "Sky/lightning.pat", tile=2, frame_px=10),
    "art_pastel": TextureSpec("gimp", "Legacy/pastel.pat", tile=3, frame_px=10),
    "art_starfield": TextureSpec("gimp", "Sky/starfield.pat", tile=2, frame_px=10),
    "art_amethyst": TextureSpec("gimp", "Stone/amethyst.pat", tile=3, frame_px=10),
}


def gimp_pattern_dir() -> Path:
    """Where gimp-data's patterns are (``TEACHREPEAT_GIMP_PATTERNS`` overrides)."""
    return Path(os.environ.get("TEACHREPEAT_GIMP_PATTERNS", str(GIMP_PATTERN_DIR)))


def skimage_data_dir() -> Path:
    """The ``skimage/data`` folder of the installed scikit-image wheel (not imported)."""
    spec = importlib.util.find_spec("skimage")
    if spec is None or not spec.submodule_search_locations:
        raise TextureError(
            "scikit-image is not installed; the simulator takes its photographs from it "
            "(pip install scikit-image)"
        )
    return Path(next(iter(spec.submodule_search_locations))) / "data"


def read_gimp_pattern(path: Path) -> RGBImage:
    """Decode a GIMP ``.pat`` file.

    Returns:
        ``(H, W, 3)`` uint8 RGB (grey patterns are expanded, alpha is dropped).
    """
    raw = path.read_bytes()
    if len(raw) < 24 or raw[20:24] != b"GPAT":
        raise TextureError(f"{path} is not a GIMP pattern (no GPAT magic)")
    header_size, _version, width, height, depth = struct.unpack(">5I", raw[:20])
    n = width * height * depth
    if depth not in (1, 2, 3, 4) or len(raw) < header_size + n:
        raise TextureError(f"{path}: truncated or unsupported pattern ({depth} bytes per pixel)")
    pixels = np.frombuffer(raw[header_size : header_size + n], np.uint8)
    pixels = pixels.reshape(height, width, depth)
    if depth <= 2:
        return np.repeat(pixels[..., :1], 3, axis=2)
    return np.ascontiguousarray(pixels[..., :3])


def _read_source(spec: TextureSpec) -> RGBImage:
    if spec.source == "gimp":
        path = gimp_pattern_dir() / spec.file
        if path.is_file():
            return read_gimp_pattern(path)
        warnings.warn(
            f"GIMP pattern {path} not found (install the Debian package gimp-data); "
            "using a tinted scikit-image photograph instead",
            RuntimeWarning,
            stacklevel=3,
        )
        # A stable per-file colour so substitutes of different patterns still differ.
        hue = (sum(spec.file.encode()) % 180) / 180.0 * 2 * np.pi
        tint = 0.75 + 0.25 * np.cos(hue + np.array([0.0, 2.1, 4.2]))
        gravel = _read_skimage("gravel.png").astype(np.float32) * tint
        return np.clip(cv2.resize(gravel, (128, 128)), 0, 255).astype(np.uint8)
    return _read_skimage(spec.file)


def _read_skimage(file: str) -> RGBImage:
    path = skimage_data_dir() / file
    try:  # Pillow (a scikit-image dependency) reads these without libpng's iCCP warnings
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"), dtype=np.uint8).copy()
    except OSError as exc:
        raise TextureError(
            f"cannot read {path} ({exc}); is scikit-image installed completely?"
        ) from None


@functools.cache
def load_texture(name: str) -> RGBImage:
    """The image of texture ``name`` (see :data:`TEXTURES`), tinted, tiled and framed.

    Returns:
        ``(H, W, 3)`` uint8 RGB; the same (read-only) array on every call.
    """
    try:
        spec = TEXTURES[name]
    except KeyError:
        known = ", ".join(sorted(TEXTURES))
        raise TextureError(f"unknown texture {name!r}; known textures: {known}") from None
    image = _read_source(spec)
    if spec.tile > 1:
        image = np.tile(image, (spec.tile, spec.tile, 1))
    if spec.tint != (1.0, 1.0, 1.0):
        image = np.clip(image.astype(np.float32) * np.asarray(spec.tint), 0, 255).astype(np.uint8)
    longest = max(image.shape[:2])
    if longest > 512:
        scale = 512 / longest
        size = (round(image.shape[1] * scale), round(image.shape[0] * scale))
        image = np.asarray(cv2.resize(image, size, interpolation=cv2.INTER_AREA), dtype=np.uint8)
    if spec.frame_px:
        f = spec.frame_px
        image = np.asarray(
            cv2.copyMakeBorder(image, f, f, f, f, cv2.BORDER_CONSTANT, value=(40, 28, 20)),
            dtype=np.uint8,
        )
    image = np.ascontiguousarray(image)
    image.setflags(write=False)
    return image


def texture_size_m(name: str) -> float:
    """Metres one image of texture ``name`` spans on a wall or floor."""
    return TEXTURES[name].size_m if name in TEXTURES else 1.0
