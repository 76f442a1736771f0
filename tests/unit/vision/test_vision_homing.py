"""Visual homing: the offset and the scale between the current frame and a target image."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from vision_testkit import scene, shifted, zoomed

from server.vision import FeatureParams, extract, homing_offset, homing_scale, match_features
from server.vision.homing import homing_scale_zoomed, zoom_image, zoom_levels


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


@pytest.mark.parametrize("factor", [0.8, 0.9, 1.0, 1.12, 1.25])
def test_scale_follows_a_zoom(factor: float) -> None:
    img = scene(21)
    res = homing_scale(extract(img), extract(zoomed(img, factor)))
    assert res is not None and res.inliers >= 10
    assert res.scale == pytest.approx(factor, rel=0.02)
    assert abs(res.rotation) < 0.02
    assert abs(res.offset) < 0.02  # zoomed about the centre: nothing to steer


def test_swapping_the_views_inverts_the_scale() -> None:
    near, far = extract(zoomed(scene(22), 1.2)), extract(scene(22))
    there = homing_scale(far, near)
    back = homing_scale(near, far)
    assert there is not None and back is not None
    assert there.scale * back.scale == pytest.approx(1.0, rel=0.03)


def test_scale_agrees_with_opencv_on_the_same_matches() -> None:
    """Naive reference: OpenCV's RANSAC similarity fit on the matches the scale is fitted to."""
    img = scene(23)
    cur, tgt = extract(shifted(img, 12)), extract(zoomed(img, 1.15))
    src, dst = match_features(cur, tgt)
    ref, _ = cv2.estimateAffinePartial2D(src, dst, method=cv2.RANSAC, ransacReprojThreshold=3.0)
    res = homing_scale(cur, tgt)
    assert res is not None and ref is not None
    assert res.scale == pytest.approx(float(np.hypot(ref[0, 0], ref[1, 0])), rel=0.02)


def test_scale_ignores_a_minority_of_wrong_matches() -> None:
    """Half the target is replaced by another scene: the fit rests on the other half."""
    img = scene(24)
    target = zoomed(img, 1.15)
    target[:, 160:] = scene(25)[:, 160:]
    res = homing_scale(extract(img), extract(target))
    assert res is not None and res.scale == pytest.approx(1.15, rel=0.03)


def test_scale_of_unrelated_or_blank_views_is_none_or_weak() -> None:
    blank = extract(np.full((240, 320, 3), 90, np.uint8))
    assert homing_scale(blank, extract(scene(26))) is None
    assert homing_scale(extract(scene(26)), blank) is None
    other = homing_scale(extract(scene(26)), extract(scene(27)))
    assert other is None or other.inliers < 10


# --- zoom levels: scales the corner descriptors cannot match at zoom 1 -------------------------


def test_zoom_by_one_is_the_image_and_bad_factors_are_refused() -> None:
    img = scene(31)
    assert np.array_equal(zoom_image(img, 1.0), img)
    assert zoom_image(img, 1.7).shape == img.shape
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="zoom factor"):
            zoom_image(img, bad)


def test_zoom_levels_are_the_frame_then_in_and_out_per_factor() -> None:
    img = scene(32)
    feats = extract(img)
    levels = zoom_levels(img, feats, (1.3, 1.69), FeatureParams())
    assert [lv.factor for lv in levels] == pytest.approx([1.0, 1.3, 1 / 1.3, 1.69, 1 / 1.69])
    assert levels[0].features is feats
    assert zoom_levels(img, feats, (), FeatureParams())[0].features is feats


@pytest.mark.parametrize("factor", [1.7, 2.0, 1 / 1.7, 1 / 2.0])
def test_zoomed_fit_reads_large_scales_on_many_more_corners(factor: float) -> None:
    """The target taken 1.7-2 times nearer (or further): at zoom 1 few corners match (in a real
    room the far scene, at scale ~1, then outvotes them); through the zoom levels at least
    twice as many agree, on the right scale."""
    img = scene(22)
    feats, target = extract(img), extract(zoom_image(img, factor))
    single = homing_scale(feats, target)
    res = homing_scale_zoomed(zoom_levels(img, feats, (1.3, 1.69), FeatureParams()), target)
    assert res is not None and res.inliers >= 30
    assert single is None or res.inliers >= 2 * single.inliers
    assert res.scale == pytest.approx(factor, rel=0.02)


def test_zoomed_fit_with_one_level_is_the_plain_fit() -> None:
    """Naive reference: with the frame itself as the only level, the plain fit."""
    img = scene(22)
    feats, target = extract(img), extract(zoom_image(img, 1.15))
    plain = homing_scale(feats, target)
    res = homing_scale_zoomed(zoom_levels(img, feats, (), FeatureParams()), target)
    assert plain is not None and res == plain
