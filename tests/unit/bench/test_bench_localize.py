"""Smoke test of ``teachrepeat bench localize`` and its scoring helpers."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

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


# --- both directions, several tolerances, halves ---------------------------------------------


def test_invert_matches_swaps_roles_and_drops_frames_without_matches() -> None:
    matches = {0: (0, 1), 1: (1, 2), 2: (), 5: (2, 9)}
    inv = localize.invert_matches(matches)
    # reference 1 is listed by queries 0 and 1; reference 3..8 by none: no entry, not scored
    assert inv == {0: (0,), 1: (0, 1), 2: (1, 5), 9: (5,)}
    gt = localize.GroundTruth(matches).inverted()
    assert gt.has_truth(9) and not gt.has_truth(4)
    assert gt.error(2, 4) == 1  # reference 2 (now the query) <-> query frames 1 and 5
    # query 2 listed nothing: it comes back without an entry
    assert localize.invert_matches(inv) == {0: (0, 1), 1: (1, 2), 5: (2, 9)}
    same = localize.GroundTruth()
    assert same.inverted() is same


@given(st.dictionaries(st.integers(0, 60), st.lists(st.integers(0, 60), max_size=6), max_size=30))
def test_invert_matches_round_trip(raw: dict[int, list[int]]) -> None:
    inv = localize.invert_matches(raw)
    assert localize.invert_matches(inv) == {q: tuple(sorted(set(v))) for q, v in raw.items() if v}
    # every pair survives, nothing is invented
    pairs = {(q, r) for q, v in raw.items() for r in v}
    assert {(q, r) for r, v in inv.items() for q in v} == pairs


def test_select_half_same_index() -> None:
    gt = localize.GroundTruth()
    ref, qry = list(range(3, 13)), list(range(3, 13))  # 10 frames each, e.g. --skip-first 3
    assert localize.select_half(qry, ref, gt, "first") == (list(range(3, 8)), list(range(3, 8)))
    assert localize.select_half(qry, ref, gt, "second") == (
        list(range(8, 13)),
        list(range(8, 13)),
    )
    assert localize.select_half(qry, ref, gt, "all") == (qry, ref)
    # an odd count: the second half takes the middle frame
    assert localize.half_frames(list(range(7)), "first") == [0, 1, 2]
    assert localize.half_frames(list(range(7)), "second") == [3, 4, 5, 6]
    # a shorter reference: only the frames it has
    assert localize.select_half(list(range(10)), list(range(7)), gt, "second") == (
        [5, 6, 7, 8, 9],
        [5, 6],
    )


def test_select_half_ground_truth_file() -> None:
    # 8 query frames; query 2 has no truth; the second half lists references 9..14
    gt = localize.GroundTruth(
        {0: (0, 1), 1: (1, 3), 3: (4,), 4: (9, 10), 5: (), 6: (12,), 7: (14, 13)}
    )
    qry, ref = list(range(8)), list(range(20))
    assert localize.select_half(qry, ref, gt, "first") == ([0, 1, 2, 3], [0, 1, 2, 3, 4])
    assert localize.select_half(qry, ref, gt, "second") == ([4, 5, 6, 7], list(range(9, 15)))
    # the reference range is cut to the frames the run has (--limit)
    assert localize.select_half(qry, list(range(12)), gt, "second") == ([4, 5, 6, 7], [9, 10, 11])
    with pytest.raises(ValueError, match="no reference frame"):
        localize.select_half(qry, list(range(5)), gt, "second")


def test_plan_directions_swaps_traversals_and_inverts_the_truth(tmp_path: Path) -> None:
    gt_file = tmp_path / "gt.json"
    gt_file.write_text(json.dumps({str(k): [k + 1, k + 2] for k in range(10)}))
    args = argparse.Namespace(
        reference=Path("ref"),
        query=Path("qry"),
        gt=str(gt_file),
        half="second",
        both_directions=True,
    )
    gt = localize.GroundTruth.parse(str(gt_file))
    fwd, rev = localize.plan_directions(args, gt, list(range(12)), list(range(10)))
    assert (fwd.reference, fwd.query, rev.reference, rev.query) == (
        Path("ref"),
        Path("qry"),
        Path("qry"),
        Path("ref"),
    )
    assert fwd.qry_frames == [5, 6, 7, 8, 9] and fwd.ref_frames == list(range(6, 12))
    # reverse: the second half of the 12 reference frames replayed, the query frames listing
    # them taught; reference 6 is listed by queries 4 and 5
    assert rev.qry_frames == list(range(6, 12)) and rev.ref_frames == list(range(4, 10))
    assert rev.gt.matches is not None and rev.gt.matches[6] == (4, 5)
    assert rev.gt_spec.endswith("(inverted)")


def naive_recall_at(
    errs: dict[str, np.ndarray], tolerances: list[int]
) -> dict[str, dict[str, dict[str, float]]]:
    return {str(t): {m: localize.score(e, t) for m, e in errs.items()} for t in tolerances}


@given(
    st.lists(
        st.one_of(st.integers(0, 30).map(float), st.just(float("inf"))), min_size=0, max_size=40
    ),
    st.lists(st.integers(0, 25), min_size=1, max_size=5, unique=True),
)
def test_recall_at_equals_scoring_each_tolerance_separately(
    values: list[float], tolerances: list[int]
) -> None:
    err = np.asarray(values, np.float64)
    errs = {"ir_only": err, "tracker": err[::-1].copy(), "smoother": np.minimum(err, 3.0)}
    got = localize.recall_at(errs, tolerances)
    want = naive_recall_at(errs, tolerances)
    assert got.keys() == want.keys()
    for t in want:
        for m in want[t]:
            for key, value in want[t][m].items():
                assert got[t][m][key] == pytest.approx(value, nan_ok=True)


def test_halves_scores_score_each_half_of_the_query_frames() -> None:
    err = np.array([0.0, 0.0, 5.0, np.inf, 1.0, 12.0, 0.0])
    halves = localize.halves_scores({"tracker": err}, [0, 2, 10])
    assert halves["first"]["frames"] == 3 and halves["second"]["frames"] == 4
    assert halves["first"]["recall_at"]["0"]["tracker"]["recall@1"] == 2 / 3
    assert halves["second"]["recall_at"]["2"]["tracker"]["recall@1"] == 2 / 3  # inf not scored
    assert halves["second"]["recall_at"]["10"] == naive_recall_at({"tracker": err[3:]}, [10])["10"]


def test_both_directions_run_reports_every_tolerance_direction_and_half(
    shared_data: Path, tmp_path: Path
) -> None:
    parser = argparse.ArgumentParser()
    localize.add_arguments(parser)
    corridor = shared_data / "corridor"
    out = tmp_path / "loc.json"
    common = [
        *("--reference", str(corridor / "ref"), "--query", str(corridor / "query")),
        *("--gt", str(corridor / "ground_truth.json"), "--limit", "24", "--location-every", "5"),
        *("--size-10k", "0", "--no-table1", "--both-directions"),
    ]
    assert localize.run(parser.parse_args([*common, "--tolerance", "1", "--json", str(out)])) == 0
    r = json.loads(out.read_text())
    # old keys at --tolerance, the forward run
    assert r["tolerance"] == 1 and r["frames"] == 24 and "tracker" in r and "per_frame" in r
    assert set(r["recall_at"]) == {"0", "1", "2", "10"}
    assert r["recall_at"]["1"]["tracker"] == r["tracker"]
    assert set(r["directions"]) == {"forward", "reverse"}
    fwd, rev = r["directions"]["forward"], r["directions"]["reverse"]
    assert fwd["recall_at"] == r["recall_at"]
    assert (rev["reference"], rev["query"]) == (r["query"], r["reference"])
    assert rev["gt"].endswith("(inverted)")
    for d in (fwd, rev):
        assert d["frames"] == 24 and len(d["weights_used"]) == 5
        assert d["weight_blocks"] == ["hist", "thumb", "desc_mean", "desc_var", "patch"]
        assert sum(d["weights_used"]) == pytest.approx(1.0, abs=1e-3)
        assert {"converged_after", "max_wrong_localised_run", "scored_frames"} <= d.keys()
        for t in ("0", "2", "10"):
            for m in ("ir_only", "tracker", "smoother"):
                assert 0.0 <= d["recall_at"][t][m]["recall@1"] <= 1.0
        # recall can only grow with the tolerance
        assert (
            d["recall_at"]["0"]["tracker"]["recall@1"]
            <= d["recall_at"]["10"]["tracker"]["recall@1"]
        )
        assert d["halves"]["first"]["frames"] == 12 and d["halves"]["second"]["frames"] == 12
    # the reverse run replays the reference folder: its estimates are query-folder frames
    assert rev["per_frame"]["query"] == list(range(24))

    half = tmp_path / "half.json"
    assert localize.run(parser.parse_args([*common, "--half", "second", "--json", str(half)])) == 0
    h = json.loads(half.read_text())
    assert h["half"] == "second" and "halves" not in h
    for d in h["directions"].values():
        assert d["frames"] == 12 and d["query_span"] == [12, 23]
        assert d["reference_span"][0] >= 9 and d["reference_span"][1] == 23
