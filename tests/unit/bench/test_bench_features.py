"""``teachrepeat bench features``: a quick run on real data reports every option it was given."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from server.bench.common import DESCRIPTOR_CHOICES
from server.cli import main
from server.vision.features import DESCRIPTOR_KINDS


def test_bench_descriptor_choices_are_the_engine_s_kinds() -> None:
    assert DESCRIPTOR_CHOICES == DESCRIPTOR_KINDS


def test_unknown_option_is_refused_with_the_choices(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "features", "--descriptors", "grad36,surf"]) == 2
    out = capsys.readouterr().out
    assert "surf" in out and ",".join(DESCRIPTOR_KINDS) in out


def test_quick_run_reports_every_chosen_option(shared_data: Path, tmp_path: Path) -> None:
    out = tmp_path / "features.json"
    code = main(
        [
            "bench",
            "features",
            "--data",
            str(shared_data),
            "--descriptors",
            "orb_fast,grad36",
            "--quick",
            "--timing-frames",
            "8",
            "--nordland-frames",
            "30",
            "--sim-queries",
            "0",
            "--sizes",
            "100",
            "--queries",
            "5",
            "--no-geometric",
            "--json",
            str(out),
        ]
    )
    assert code == 0
    result = json.loads(out.read_text())
    res = result["descriptors"]
    assert list(res) == ["grad36", "orb_fast"]  # in DESCRIPTOR_KINDS order
    for r in res.values():
        ext = r["extraction"]
        assert ext["frames"] == 8 and 0.0 < ext["extract_ms"]["p50"] <= ext["extract_ms"]["p95"]
        assert ext["local_ms"]["p50"] > 0.0 and 0 < ext["keypoints_mean"] <= 100
        for key in ("corridor_recall@1", "corridor_recall@5", "triplets_top1"):
            assert 0.0 <= r["retrieval"][key] <= 1.0
        assert r["retrieval"]["corridor_recall@1"] <= r["retrieval"]["corridor_recall@5"]
        assert 0.0 <= r["retrieval"]["ukbench_score"] <= 4.0
        loc = r["corridor_localize"]
        assert loc["frames"] == 40
        for name in ("ir_only", "tracker"):
            assert 0.0 <= loc[name]["tol0"] <= loc[name]["tol2"] <= 1.0
        nord = r["nordland"]
        assert nord["frames"] == 30
        assert nord["retrieval_recall@1_tol1"] <= nord["retrieval_recall@1_tol10"]
        assert r["query_speed"]["100"]["total_ms_p50"] > 0.0
        assert "sim" not in r and "retrieval_geometric" not in r
    # grad36 beats chance on the corridor by far: the bench measures something
    assert res["grad36"]["corridor_localize"]["tracker"]["tol2"] >= 0.8
    assert result["meta"]["nordland"] == {"first_frame": 17, "frames": 30}
