"""Docking's zoomed scale fit with the zooms on the taught side (``taught_zoom_levels``,
``homing_scale_taught_zoomed``) against the frame-side zooms it replaces."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vision_testkit import scene

from server.vision import FeatureParams, ImageFeatures, extract, homing_scale
from server.vision.homing import (
    ZoomLevel,
    homing_scale_taught_zoomed,
    homing_scale_zoomed,
    taught_zoom_levels,
    zoom_image,
    zoom_levels,
)

ZOOMS = (1.3, 1.69)
FP = FeatureParams()
W, H = FP.width, FP.height
CENTRE = np.array([W / 2, H / 2], np.float32)


def test_taught_levels_pair_with_the_frame_s_levels_and_make_no_corner_on_the_rim() -> None:
    img = scene(41)
    feats = extract(img)
    levels = taught_zoom_levels(img, feats, ZOOMS, FP)
    assert [lv.factor for lv in levels] == [lv.factor for lv in zoom_levels(img, feats, ZOOMS, FP)]
    assert levels[0].features is feats
    for which, kept in (("in", lambda f: f > 1), ("out", lambda f: f < 1)):
        some = taught_zoom_levels(img, feats, ZOOMS, FP, which)
        assert [lv.factor for lv in some] == [1.0] + [lv.factor for lv in levels if kept(lv.factor)]
        frame = zoom_levels(img, feats, ZOOMS, FP, which)
        assert [lv.factor for lv in frame] == [lv.factor for lv in some]
    for lv in levels[1:]:
        assert lv.features.n_keypoints >= 20
        if lv.factor > 1:  # the taught view shrunk into the central 1 / factor: corners in it
            half = CENTRE / lv.factor
            assert np.all(np.abs(lv.features.keypoints - CENTRE) <= half), lv.factor


def _features(points: np.ndarray, desc: np.ndarray) -> ImageFeatures:
    return ImageFeatures(
        keypoints=np.ascontiguousarray(points, np.float32),
        descriptors=np.ascontiguousarray(desc),
        signature=np.zeros(0, np.float32),
    )


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    scale=st.floats(0.45, 2.2),
    dx=st.floats(-40.0, 40.0),
    dy=st.floats(-8.0, 8.0),
)
def test_bookkeeping_equals_the_frame_zoom_on_exact_corners(
    seed: int, scale: float, dx: float, dy: float
) -> None:
    """Naive reference: corners that move exactly with the zoom (what a perfect detector would
    find). The frame zoomed in by ``f`` sees the frame's corners at ``f (p - c) + c`` (those
    still inside the image, ``border`` px in); the taught image zoomed out by ``f`` sees the
    taught corners at ``(q - c) / f + c``. Both fits must then agree on every field: scale
    (times the winning level's factor), rotation, inliers, matches and offset."""
    rng = np.random.default_rng(seed)
    n = 70
    p = np.column_stack([rng.uniform(20, W - 20, n), rng.uniform(20, H - 20, n)])
    desc = rng.integers(0, 256, (n, 36), dtype=np.uint8)
    q = scale * (p - CENTRE) + CENTRE + np.array([dx, dy])
    seen = (q[:, 0] >= 0) & (q[:, 0] < W) & (q[:, 1] >= 0) & (q[:, 1] < H)
    frame, taught = _features(p, desc), _features(q[seen], desc[seen])
    frame_levels, taught_levels = [ZoomLevel(1.0, frame)], [ZoomLevel(1.0, taught)]
    b = FP.border
    for z in ZOOMS:
        for f in (z, 1 / z):
            pf = f * (p - CENTRE) + CENTRE
            inside = (pf[:, 0] >= b) & (pf[:, 0] <= W - b) & (pf[:, 1] >= b) & (pf[:, 1] <= H - b)
            frame_levels.append(ZoomLevel(f, _features(pf[inside], desc[inside])))
            qf = (q[seen] - CENTRE) / f + CENTRE
            taught_levels.append(ZoomLevel(f, _features(qf, desc[seen])))
    old = homing_scale_zoomed(frame_levels, taught)
    frame_in = [lv for lv in frame_levels if lv.factor > 1]  # as docking mixes them
    taught_out = [lv for lv in taught_levels if lv.factor <= 1]
    for new in (
        homing_scale_taught_zoomed(frame, taught_levels),
        homing_scale_taught_zoomed(frame, taught_out, frame_levels=frame_in),
    ):
        assert (old is None) == (new is None)
        if old is None or new is None:
            continue
        assert new.inliers == old.inliers and new.n_matches == old.n_matches
        assert new.scale == pytest.approx(old.scale, rel=1e-4)
        assert new.rotation == pytest.approx(old.rotation, abs=1e-4)
        assert new.offset == pytest.approx(old.offset, abs=1e-4)
        if old.inliers >= 10:
            assert new.scale == pytest.approx(scale, rel=1e-3)


@pytest.mark.parametrize("factor", [1.7, 2.0, 1 / 1.7, 1 / 2.0, 1.15, 1.0])
def test_taught_zooms_read_the_scale_the_frame_zooms_read(factor: float) -> None:
    """A rendered scene, the target taken ``factor`` times nearer, through the levels docking
    uses (frame zoomed in, taught image zoomed in for the frame zoomed out) and through the
    frame's four zooms: both read the scale within 2 %. Where the frame zoomed in wins the
    two are the same fit; a taught image zoomed in found 64, 67, 47 inliers where the frame
    zoomed out found 80, 73, 69 (1 / 1.4, 1 / 1.7, 1 / 2): the rendered target seen further
    is a shrunk copy and the shrunk frame resembles it more (the simulated homes measure the
    other way, homing_scale_taught_zoomed's docstring)."""
    img = scene(22)
    feats = extract(img)
    target_img = zoom_image(img, factor)
    target = extract(target_img)
    old = homing_scale_zoomed(zoom_levels(img, feats, ZOOMS, FP), target)
    new = homing_scale_taught_zoomed(
        feats,
        taught_zoom_levels(target_img, target, ZOOMS, FP, "out"),
        frame_levels=zoom_levels(img, feats, ZOOMS, FP, "in"),
    )
    assert old is not None and new is not None
    assert new.scale == pytest.approx(factor, rel=0.02)
    assert old.scale == pytest.approx(factor, rel=0.02)
    assert new.inliers >= 0.6 * old.inliers and new.inliers >= 30
    if factor >= 1:
        assert new == old
    # zoomed about the centre: little to steer (what is left is the scale the level did not
    # take out, over the inliers' spread about the centre)
    assert abs(new.offset) < 0.05 and abs(old.offset) < 0.05


def test_with_the_taught_image_as_the_only_level_it_is_the_plain_fit() -> None:
    img = scene(23)
    feats, target = extract(img), extract(zoom_image(img, 1.15))
    res = homing_scale_taught_zoomed(feats, taught_zoom_levels(img, target, (), FP))
    assert res == homing_scale(feats, target)


def test_with_every_level_on_the_frame_s_side_it_is_the_frame_zoomed_fit() -> None:
    """Naive reference: frame levels for every factor leave the taught levels unused."""
    img = scene(24)
    feats = extract(img)
    target_img = zoom_image(img, 1.5)
    target = extract(target_img)
    frame_levels = zoom_levels(img, feats, ZOOMS, FP)
    taught = taught_zoom_levels(target_img, target, ZOOMS, FP)
    res = homing_scale_taught_zoomed(feats, taught, frame_levels=frame_levels)
    assert res == homing_scale_zoomed(frame_levels, target)


def test_the_first_taught_level_must_be_the_taught_image() -> None:
    img = scene(25)
    levels = taught_zoom_levels(img, extract(img), ZOOMS, FP)
    with pytest.raises(ValueError, match="factor 1"):
        homing_scale_taught_zoomed(levels[0].features, levels[1:])


def test_real_corridor_pairs_read_about_the_same_scale(shared_data: Path) -> None:
    """Real frames (the corridor set: 160x120 queries against their ground-truth references,
    every 8th query), docking's levels against the frame's four zooms: where both fit on >= 10
    inliers, the scales agree within 10 % for at least 80 % of the pairs, and the inliers
    found are about as many (sums within 20 %). Measured on all 549 pairs: both fit on every
    pair, 92 % of the 145 pairs with >= 8 inliers agree within 10 %, mean inliers 7.0 (frame
    zooms) and 6.7."""
    folder = shared_data / "corridor"
    truth = json.loads((folder / "ground_truth.json").read_text())
    refs = sorted((folder / "ref").glob("*.jpg"))
    taught: dict[int, tuple[ZoomLevel, ...]] = {}
    agree = strong = old_inliers = new_inliers = 0
    for qi in range(0, len(truth), 8):
        frame = cv2.imread(str(folder / "query" / f"{qi:07d}.jpg"))
        feats = extract(frame)
        frame_levels = zoom_levels(frame, feats, ZOOMS, FP)
        frame_in = zoom_levels(frame, feats, ZOOMS, FP, "in")
        for ri in truth[str(qi)]:
            if ri not in taught:
                ref = cv2.imread(str(refs[ri]))
                taught[ri] = taught_zoom_levels(ref, extract(ref), ZOOMS, FP, "out")
            old = homing_scale_zoomed(frame_levels, taught[ri][0].features)
            new = homing_scale_taught_zoomed(feats, taught[ri], frame_levels=frame_in)
            old_inliers += old.inliers if old else 0
            new_inliers += new.inliers if new else 0
            if old and new and old.inliers >= 10 and new.inliers >= 10:
                strong += 1
                agree += abs(np.log(new.scale / old.scale)) < np.log(1.1)
    assert strong >= 10
    assert agree >= 0.8 * strong, f"{agree} of {strong}"
    assert new_inliers == pytest.approx(old_inliers, rel=0.2)
