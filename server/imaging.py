"""Checking and decoding uploaded images without ever decoding a bomb.

The JPEG header is parsed first (a few hundred bytes) to learn the image size; only a body
within the byte and pixel limits is handed to OpenCV to decode.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from server.errors import Invalid, TooLarge, UnsupportedMedia

# Start-of-frame markers that carry the image size (baseline, progressive, lossless...).
_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


@dataclass(frozen=True)
class ImageLimits:
    max_bytes: int = 4 * 1024 * 1024
    """Largest body, bytes."""
    max_pixels: int = 4096 * 3072
    """Largest width x height."""
    max_side: int = 8192
    """Largest width or height, pixels."""
    min_side: int = 16
    """Smallest width or height, pixels (features need room)."""


def jpeg_size(data: bytes) -> tuple[int, int]:
    """``(width, height)`` read from a JPEG's start-of-frame header, without decoding.

    Raises :class:`UnsupportedMedia` when ``data`` is not a JPEG and :class:`Invalid` when
    its header is broken or truncated.
    """
    if len(data) < 4 or data[:2] != b"\xff\xd8":
        raise UnsupportedMedia(
            "the body is not a JPEG image (it must start with FF D8); send the frame "
            "JPEG-encoded with Content-Type: image/jpeg"
        )
    pos = 2
    n = len(data)
    while pos + 4 <= n:
        if data[pos] != 0xFF:
            raise Invalid(f"corrupt JPEG header at byte {pos}; re-encode the image")
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            pos += 2
            continue
        length = int.from_bytes(data[pos + 2 : pos + 4], "big")
        if length < 2:
            raise Invalid(f"corrupt JPEG segment length at byte {pos}; re-encode the image")
        if marker in _SOF:
            if pos + 9 > n:
                break
            height = int.from_bytes(data[pos + 5 : pos + 7], "big")
            width = int.from_bytes(data[pos + 7 : pos + 9], "big")
            if width == 0 or height == 0:
                raise Invalid("the JPEG header gives a zero width or height")
            return width, height
        if marker == 0xDA:  # start of scan before any frame header
            break
        pos += 2 + length
    raise Invalid("the JPEG is truncated or has no frame header; send the complete file")


def decode_jpeg(data: bytes, limits: ImageLimits) -> tuple[npt.NDArray[np.uint8], int, int]:
    """Check ``data`` against ``limits`` and decode it to ``(H, W, 3)`` uint8 BGR.

    Returns ``(image, width, height)``. Errors: :class:`TooLarge` (413) over the byte or pixel
    limits, checked before decoding; :class:`UnsupportedMedia` (415) for non-JPEG bodies;
    :class:`Invalid` (422) for empty, truncated or undecodable images.
    """
    if len(data) == 0:
        raise Invalid("the image body is empty; send the JPEG bytes as the request body")
    if len(data) > limits.max_bytes:
        raise TooLarge(
            f"the image is {len(data)} bytes; the limit is {limits.max_bytes} bytes. "
            "Send a smaller or more compressed frame"
        )
    width, height = jpeg_size(data)
    if width > limits.max_side or height > limits.max_side or width * height > limits.max_pixels:
        raise TooLarge(
            f"the image claims {width}x{height} pixels; the limit is {limits.max_pixels} pixels "
            f"and {limits.max_side} per side. Resize the frame before sending it"
        )
    if width < limits.min_side or height < limits.min_side:
        raise Invalid(
            f"the image is {width}x{height} pixels; send frames of at least "
            f"{limits.min_side} pixels per side"
        )
    if not data.rstrip(b"\x00").endswith(b"\xff\xd9"):
        raise Invalid("the JPEG is truncated (no end-of-image marker); send the complete file")
    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR)
    if image is None or image.shape[0] != height or image.shape[1] != width:
        raise Invalid("the body could not be decoded as a JPEG image; re-encode it")
    return np.asarray(image, dtype=np.uint8), width, height


def encode_jpeg(image: npt.NDArray[np.uint8], quality: int = 90) -> bytes:
    """``(H, W, 3)`` uint8 BGR (or ``(H, W)`` grey) -> JPEG bytes."""
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("OpenCV could not encode the image as JPEG")
    return buf.tobytes()
