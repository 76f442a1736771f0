"""Smoke test of ``teachrepeat bench localize`` and its scoring helpers."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from server.bench import localize


def test_build_tour_maps_every_image_and_fine_state_to_its_frame() -> None:
    frames = list(range(5, 30))  # 25 frames, locations at positions 0, 10, 20 and 24
    tour = localize.build_tour(frames, 10)
    g = tour.graph
    assert g.n_locations == 4 and g.n_edges == 3
    assert g.n_images == len(frames)
    assert sorted(tour.image_frame.tolist()) == frames
    assert [tour.state_frames[k] for k in range(4)] == [(5,), (15,), (25,), (29,)]
    assert tour.state_frames[4] == tuple(range(6, 15))
    # fine state of an edge image -> that image's frame; location -> its frame
    assert tour.fine_frame[0] == 5 and tour.fine_frame[4] == 6
    # taught at 1 image per 0.1 s at 1 m/s: one image per frame at the same pace
    assert np.allclose(np.diff(g.edges[0].timestamps), 0.1)


def test_ground_truth_same_index_and_file(tmp_path: Path) -> None:
    same = localize.GroundTruth.parse("same-index")
    assert same.error(10, 13) == 3
    gt_file = tmp_path / "gt.json"
    gt_file.write_text(json.dumps({"0": [0, 1], "1": [4, 6]}))
    gt = localize.GroundTruth.parse(str(gt_file))
    assert gt.error(1, 5) == 1 and gt.error(1, 6) == 0 and gt.error(0, 3) == 2
    assert gt.error(7, 7) == float("inf") and not gt.has_truth(7)


def test_scoring_helpers() -> None:
    err = np.array([0.0, 3.0, 1.0, np.inf])
    s = localize.score(err, 1)
    assert s["recall@1"] == 2 / 3 and s["mean_error_frames"] == 4 / 3
    right = np.array([False, True, False, True, True, True])
    conv = localize.converged_after(right, window=3)
    assert conv == {"stays_right": 3, "first_run": 3}
    gt = localize.GroundTruth()
    localised: list[tuple[int, ...] | None] = [(0,), (9,), (9,), None, (9,), (4, 5)]
    assert localize.max_wrong_localised_run([0, 1, 2, 3, 4, 5], localised, gt, 1) == 2


def test_quick_run_writes_json(shared_data: Path, tmp_path: Path) -> None:
    parser = argparse.ArgumentParser()
    localize.add_arguments(parser)
    out = tmp_path / "loc.json"
    plot = tmp_path / "belief.png"
    recall = tmp_path / "recall.png"
    corridor = shared_data / "corridor"
    args = parser.parse_args(
        [
            "--reference",
            str(corridor / "ref"),
            "--query",
            str(corridor / "query"),
            "--gt",
            str(corridor / "ground_truth.json"),
            "--tolerance",
            "2",
            "--limit",
            "30",
            "--location-every",
            "5",
            "--size-10k",
            "300",
            "--json",
            str(out),
            "--plot",
            str(plot),
            "--recall-plot",
            str(recall),
        ]
    )
    assert localize.run(args) == 0
    r = json.loads(out.read_text())
    assert r["frames"] == 30 and r["tolerance"] == 2
    for name in ("ir_only", "tracker", "smoother"):
        assert 0.0 <= r[name]["recall@1"] <= 1.0
        assert r[name]["mean_error_frames"] >= 0.0
    for key in (
        "converged_after",
        "step_ms_p50",
        "step_ms_p50_10k",
        "table1_error_rate",
        "max_wrong_localised_run",
        "engine_ms",
    ):
        assert key in r
    assert r["step_10k"]["images"] == 300
    assert len(r["recall_curve"]["tracker"]) == len(localize.CURVE_TOLERANCES)
    # the tracker should do at least as well as chance on a same-pace traversal
    assert r["tracker"]["recall@1"] >= 0.5
    assert plot.stat().st_size > 0 and recall.stat().st_size > 0
