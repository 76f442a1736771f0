"""Docking's zoom levels of the taught images (``dock_taught_zooms`` "look", the default):
made once per taught image from its pixels, kept within a bound, read only to look for a view,
and the frame's own zooms when the pixels cannot be read or the option is "off"."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "vision"))
from navigation_testkit import FEATURES, GRAPH, runtime
from vision_testkit import scene, zoomed

from server.navigation import runtime as runtime_module
from server.navigation.observation import ViewNotRequested, ViewRequest, match_views
from server.vision.features import extract
from server.vision.homing import (
    homing_offset,
    homing_scale,
    homing_scale_taught_zoomed,
    homing_scale_zoomed,
    taught_zoom_levels,
    zoom_levels,
)

IMAGES = [int(i) for i in GRAPH.image_ids]


def counting_reader(reads: list[int]):  # type: ignore[no-untyped-def]
    def read(k: int) -> np.ndarray:
        reads.append(k)
        return scene(IMAGES[k])

    return read


def test_levels_are_made_once_per_taught_image_from_its_pixels() -> None:
    rt = runtime()
    reads: list[int] = []
    rt.taught_pixels = counting_reader(reads)
    levels = rt.taught_levels(5)
    assert levels is not None and rt.taught_levels(5) is levels
    assert reads == [5]
    p = rt.params
    reference = taught_zoom_levels(scene(IMAGES[5]), FEATURES[5], p.dock_zooms, p.features)
    assert [lv.factor for lv in levels] == pytest.approx([1.0, 1.3, 1 / 1.3, 1.69, 1 / 1.69])
    assert levels[0].features is FEATURES[5]
    assert all(a.features == b.features for a, b in zip(levels, reference, strict=True))


def test_the_least_recently_asked_for_are_forgotten_first(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(runtime_module, "ZOOM_CACHE_IMAGES", 2)
    rt = runtime()
    reads: list[int] = []
    rt.taught_pixels = counting_reader(reads)
    for k in (1, 2, 1, 3, 1, 2):  # 2 is forgotten when 3 comes, 3 when 2 comes back
        rt.taught_levels(k)
    assert reads == [1, 2, 3, 2]
    assert len(rt._zoomed) == 2


def test_without_pixels_there_are_no_taught_levels_and_nothing_is_remembered() -> None:
    rt = runtime()
    rt.taught_pixels = None
    assert rt.taught_levels(3) is None
    assert len(rt._zoomed) == 0
    rt.taught_pixels = lambda k: None  # an image no longer stored
    assert rt.taught_levels(3) is None and rt.taught_levels(3) is None


def test_off_docking_zooms_the_frame_only_and_reads_no_pixels() -> None:
    assert runtime().params.dock_taught_zooms == "look"  # the default
    rt = runtime(dock_taught_zooms="off")
    assert rt.taught_levels(6) is None
    reads: list[int] = []
    rt.taught_pixels = counting_reader(reads)
    frame = zoomed(scene(IMAGES[7]), 1 / 1.4)
    feats = extract(frame)
    views = match_views(rt, frame, feats, ViewRequest(zoomed=frozenset({6, 7})))
    p = rt.params
    frame_levels = zoom_levels(frame, feats, p.dock_zooms, p.features)
    for k in (6, 7):
        assert views.zoomed_scale(k) == homing_scale_zoomed(frame_levels, FEATURES[k])
    assert reads == []


@pytest.mark.parametrize("choice", ["yes", "out", "both"])  # "out", "both": removed
def test_an_unknown_choice_is_refused_with_the_choices(choice: str) -> None:
    with pytest.raises(ValueError, match="must be 'off' or 'look', got '"):
        runtime(dock_taught_zooms=choice)


def test_views_are_matched_when_read_once_each_and_as_made_at_once() -> None:
    """Naive reference: the fits made when read equal those made directly; a requested view
    never read costs nothing (here: its taught pixels are never read), and the frame's zoomed
    fits read no taught pixels."""
    rt = runtime()
    reads: list[int] = []
    rt.taught_pixels = counting_reader(reads)
    frame = zoomed(scene(IMAGES[7]), 1.2)
    feats = extract(frame)
    request = ViewRequest(
        offsets=frozenset({7}), scales=frozenset({7}), zoomed=frozenset({6, 7, 8})
    )
    views = match_views(rt, frame, feats, request)
    assert reads == [] and set(views.taught_zoomed) == {6, 7, 8} and len(views.zoomed) == 3
    fit = views.taught_zoomed_scale(7)
    assert reads == [7] and views.taught_zoomed_scale(7) is fit
    p = rt.params
    levels = taught_zoom_levels(scene(IMAGES[7]), FEATURES[7], p.dock_zooms, p.features)
    assert fit == homing_scale_taught_zoomed(feats, levels)
    frame_levels = zoom_levels(frame, feats, p.dock_zooms, p.features)
    assert views.zoomed_scale(8) == homing_scale_zoomed(frame_levels, FEATURES[8])
    assert views.offset(7) == homing_offset(feats, FEATURES[7])
    assert views.scale(7) == homing_scale(feats, FEATURES[7])
    with pytest.raises(ViewNotRequested):
        views.taught_zoomed_scale(9)
    assert reads == [7]


def test_look_reads_the_taught_zooms_and_extracts_no_frame_zoom(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """With "look", the zoomed fits are the frame's (as "off": creeping and verdicts) and the
    taught-zoomed fits are those on the taught images' own levels, made without one
    extraction of the frame's zooms; where the pixels cannot be read, the frame's."""
    from server.navigation import observation

    rt = runtime(dock_taught_zooms="look")
    made: list[tuple[float, ...]] = []

    def counting_zoom_levels(*args, **kwargs):  # type: ignore[no-untyped-def]
        levels = zoom_levels(*args, **kwargs)
        made.append(tuple(lv.factor for lv in levels))
        return levels

    monkeypatch.setattr(observation, "zoom_levels", counting_zoom_levels)
    frame = zoomed(scene(IMAGES[4]), 1.3)
    feats = extract(frame)
    missing = {6}
    rt.taught_pixels = lambda k: None if k in missing else scene(IMAGES[k])
    views = match_views(rt, frame, feats, ViewRequest(zoomed=frozenset({4, 5, 6})))
    p = rt.params
    for k in (4, 5):
        levels = taught_zoom_levels(scene(IMAGES[k]), FEATURES[k], p.dock_zooms, p.features)
        assert views.taught_zoomed_scale(k) == homing_scale_taught_zoomed(feats, levels)
    assert made == []  # looking extracted nothing from the frame
    fit = views.taught_zoomed_scale(4)
    assert fit is not None and fit.scale == pytest.approx(1 / 1.3, rel=0.05)
    frame_levels = zoom_levels(frame, feats, p.dock_zooms, p.features)
    assert views.taught_zoomed_scale(6) == homing_scale_zoomed(frame_levels, FEATURES[6])
    assert views.zoomed_scale(4) == homing_scale_zoomed(frame_levels, FEATURES[4])
    assert views.zoomed_scale(5) == homing_scale_zoomed(frame_levels, FEATURES[5])
    assert made == [(1.0, 1.3, 1 / 1.3, 1.69, 1 / 1.69)]  # the frame's four zooms, once
    with pytest.raises(ViewNotRequested):
        views.taught_zoomed_scale(9)


def test_look_fit_reads_the_taught_zooms_only_with_look() -> None:
    """Naive reference: the best of the candidates by inliers, from the mapping the option
    names (the other mapping holds better fits, which must not be read)."""
    from server.navigation.docking import look_fit
    from server.navigation.observation import Views
    from server.vision.homing import ScaleResult

    def fit(inliers: int) -> ScaleResult:
        return ScaleResult(scale=1.0, rotation=0.0, inliers=inliers, n_matches=40, offset=0.0)

    views = Views(
        zoomed={1: fit(12), 2: fit(30), 3: None},
        taught_zoomed={1: fit(25), 2: fit(11), 3: fit(40)},
    )
    assert look_fit(views, [1, 2, 3], runtime(dock_taught_zooms="off").params) == (2, fit(30))
    assert look_fit(views, [1, 2, 3], runtime(dock_taught_zooms="look").params) == (3, fit(40))
    assert look_fit(views, [3], runtime(dock_taught_zooms="off").params) == (3, None)
