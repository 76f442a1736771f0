"""Visual homing offset."""

from __future__ import annotations

import numpy as np
import pytest
from vision_testkit import scene, shifted

from server.vision import extract, homing_offset


@pytest.mark.parametrize("dx", [-30, -10, 15, 40])
def test_offset_follows_the_shift(dx: int) -> None:
    img = scene(11)
    current = extract(img)
    target = extract(shifted(img, dx))  # target features lie dx px to the right
    res = homing_offset(current, target)
    assert res is not None and res.n_matches >= 10
    assert res.offset_px == pytest.approx(dx, abs=2.0)
    assert res.offset == pytest.approx(dx / 320, abs=0.01)
    assert -1.0 <= res.offset <= 1.0


def test_identical_images_give_zero() -> None:
    f = extract(scene(12))
    res = homing_offset(f, f)
    assert res is not None and res.offset == 0.0


def test_no_features_gives_none() -> None:
    blank = extract(np.full((240, 320, 3), 90, np.uint8))
    assert homing_offset(blank, extract(scene(13))) is None
    assert homing_offset(extract(scene(13)), blank) is None
