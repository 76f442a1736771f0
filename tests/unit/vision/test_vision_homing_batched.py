"""homing_scales and the zoomed fits made in one vectorised pass: exactly the fits made pair by
pair (the naive references: homing_scale in a loop, and the zoomed fits as they were written
before, a loop over levels keeping the first with the most inliers)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from vision_testkit import scene, shifted, zoomed

from server.vision.features import FeatureParams, ImageFeatures, extract
from server.vision.homing import (
    ScaleResult,
    ZoomLevel,
    homing_scale,
    homing_scale_taught_zoomed,
    homing_scale_zoomed,
    homing_scales,
    taught_zoom_levels,
    zoom_levels,
)

ZOOMS = (1.3, 1.69)


def naive_zoomed(levels: list[ZoomLevel], target: ImageFeatures) -> ScaleResult | None:
    best: ScaleResult | None = None
    best_factor = 1.0
    for level in levels:
        r = homing_scale(level.features, target)
        if r is not None and (best is None or r.inliers > best.inliers):
            best, best_factor = r, level.factor
    if best is None or best_factor == 1.0:
        return best
    return replace(best, scale=best.scale * best_factor)


def views() -> list[np.ndarray]:
    """Synthetic views related by zooms and shifts (so that many fits succeed) and some
    unrelated ones (so that some do not)."""
    base = [scene(seed) for seed in range(4)]
    out = []
    for img in base:
        out += [img, zoomed(img, 1.2), zoomed(img, 0.8), shifted(zoomed(img, 1.5), 12)]
    return out


def test_homing_scales_equals_homing_scale_pair_by_pair() -> None:
    feats = [extract(v) for v in views()]
    pairs = [(a, b) for a in feats for b in feats[::3]]
    expected = [homing_scale(a, b) for a, b in pairs]
    assert homing_scales(pairs) == expected
    assert sum(r is not None for r in expected) >= len(pairs) // 3  # the check has teeth


def test_empty_one_corner_and_unmatched_pairs_are_as_pair_by_pair() -> None:
    feats = extract(scene(1))
    blank = extract(np.full((240, 320, 3), 128, np.uint8))
    assert blank.n_keypoints == 0
    one = replace(feats, keypoints=feats.keypoints[:1], descriptors=feats.descriptors[:1])
    few = replace(feats, keypoints=feats.keypoints[:3], descriptors=feats.descriptors[:3])
    pairs = [(blank, feats), (feats, blank), (feats, one), (one, feats), (few, feats)]
    pairs += [(feats, feats), (feats, extract(scene(2)))]
    assert homing_scales(pairs) == [homing_scale(a, b) for a, b in pairs]
    assert homing_scales([]) == []
    assert homing_scales([(blank, blank)]) == [None]


def test_features_of_different_descriptors_are_refused() -> None:
    img = scene(3)
    orb = extract(img, FeatureParams(descriptor="orb"))
    with pytest.raises(ValueError, match="cannot match"):
        homing_scales([(extract(img), extract(img)), (extract(img), orb)])


@pytest.mark.parametrize("factor", [0.6, 0.8, 1.0, 1.25, 1.6])
def test_zoomed_fits_equal_the_loop_over_levels(factor: float) -> None:
    for seed in range(3):
        taught = scene(seed)
        frame = shifted(zoomed(taught, factor), 5)
        ff, tf = extract(frame), extract(taught)
        levels = list(zoom_levels(frame, ff, ZOOMS, FeatureParams()))
        assert homing_scale_zoomed(levels, tf) == naive_zoomed(levels, tf)
        t_levels = taught_zoom_levels(taught, tf, ZOOMS, FeatureParams())
        got = homing_scale_taught_zoomed(ff, t_levels)
        assert got is not None and got == homing_scale_taught_zoomed_reference(ff, t_levels)


def homing_scale_taught_zoomed_reference(
    current: ImageFeatures, levels: tuple[ZoomLevel, ...]
) -> ScaleResult | None:
    """The taught zooms pair by pair: each taught level as the frame zoomed by its factor."""
    from server.vision.homing import _as_frame_zoom

    order = sorted((lv.factor for lv in levels), key=lambda f: (round(abs(np.log(f)), 9), f < 1))
    taught = {lv.factor: lv.features for lv in levels}
    as_levels = []
    for f in order:
        if f == 1.0:
            as_levels.append((f, current, taught[f]))
        else:
            cur, tgt = _as_frame_zoom(current, taught[f], f, FeatureParams())
            as_levels.append((f, cur, tgt))
    best: ScaleResult | None = None
    best_factor = 1.0
    for f, cur, tgt in as_levels:
        r = homing_scale(cur, tgt)
        if r is not None and (best is None or r.inliers > best.inliers):
            best, best_factor = r, f
    if best is None or best_factor == 1.0:
        return best
    return replace(best, scale=best.scale * best_factor)


def test_real_corridor_frames_fit_as_pair_by_pair(shared_data: Path) -> None:
    """Real frames (the corridor's query frames against its reference frames near them), with
    the frame's five zoom levels: the batched fits are the loop's to the last bit."""
    root = shared_data / "corridor"
    queries = sorted((root / "query").glob("*.jpg"))[::9]
    refs = sorted((root / "ref").glob("*.jpg"))
    fitted = 0
    for k, q in enumerate(queries):
        frame = cv2.imread(str(q))
        ff = extract(frame)
        levels = list(zoom_levels(frame, ff, ZOOMS, FeatureParams()))
        for r in refs[max(0, 9 * k - 3) : 9 * k + 4 : 2]:
            tf = extract(cv2.imread(str(r)))
            pairs = [(lv.features, tf) for lv in levels]
            expected = [homing_scale(a, b) for a, b in pairs]
            assert homing_scales(pairs) == expected
            assert homing_scale_zoomed(levels, tf) == naive_zoomed(levels, tf)
            fitted += sum(e is not None for e in expected)
    assert fitted >= 50
