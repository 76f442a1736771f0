"""Image checks run before decoding: sizes from the header, limits, truncation."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import make_jpeg

from server.errors import Invalid, TooLarge, UnsupportedMedia
from server.imaging import ImageLimits, decode_jpeg, encode_jpeg, jpeg_size


@pytest.mark.parametrize(("w", "h"), [(16, 16), (64, 48), (320, 240), (641, 479)])
def test_header_size_matches_the_decoded_size(w: int, h: int) -> None:
    data = make_jpeg(0, w, h)
    assert jpeg_size(data) == (w, h)
    image, width, height = decode_jpeg(data, ImageLimits())
    assert image.shape == (h, w, 3) and (width, height) == (w, h)


def test_progressive_jpeg_is_read() -> None:
    import cv2

    img = np.random.default_rng(0).integers(0, 255, (30, 40, 3), dtype=np.uint8)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])
    assert ok
    assert jpeg_size(buf.tobytes()) == (40, 30)


def test_a_claimed_bomb_is_refused_before_decoding(monkeypatch: pytest.MonkeyPatch) -> None:
    import cv2

    def never(*args: object) -> None:
        raise AssertionError("decoded an image that should have been refused from its header")

    monkeypatch.setattr(cv2, "imdecode", never)
    data = bytearray(make_jpeg(0, 16, 16))
    pos = 2
    while data[pos + 1] != 0xC0:
        pos += 2 + int.from_bytes(data[pos + 2 : pos + 4], "big")
    data[pos + 5 : pos + 9] = (20000).to_bytes(2, "big") + (20000).to_bytes(2, "big")
    with pytest.raises(TooLarge, match="20000x20000"):
        decode_jpeg(bytes(data), ImageLimits())


@pytest.mark.parametrize(
    ("data", "error"),
    [
        (b"", Invalid),
        (b"GIF89a....", UnsupportedMedia),
        (b"\xff\xd8\xff", UnsupportedMedia),
        (b"\xff\xd8\xff\xe0\x00\x10JFIF", Invalid),
    ],
)
def test_broken_bodies(data: bytes, error: type[Exception]) -> None:
    with pytest.raises(error):
        decode_jpeg(data, ImageLimits())


def test_byte_limit() -> None:
    with pytest.raises(TooLarge, match="bytes"):
        decode_jpeg(make_jpeg(0, 64, 48), ImageLimits(max_bytes=100))


def test_encode_round_trip() -> None:
    img = np.full((24, 32, 3), 128, dtype=np.uint8)
    out, _, _ = decode_jpeg(encode_jpeg(img), ImageLimits())
    assert np.abs(out.astype(int) - 128).max() <= 2
