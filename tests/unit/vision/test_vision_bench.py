"""Smoke test of ``teachrepeat bench retrieval --quick``."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from server.bench import retrieval

REQUIRED = [
    "corridor.recall@1",
    "corridor.recall@5",
    "nordland.recall@1_tol1",
    "nordland.recall@1_tol10",
    "triplets.top1",
    "ukbench.score",
]
SPEED = [
    "total_ms_p50",
    "total_ms_p95",
    "first_pass_ms_p50",
    "second_pass_ms_p50",
    "bytes_per_image",
]


def _get(d: dict, dotted: str):
    for part in dotted.split("."):
        d = d[part]
    return d


def test_quick_run_writes_json_with_required_keys(shared_data: Path, tmp_path: Path) -> None:
    parser = argparse.ArgumentParser()
    retrieval.add_arguments(parser)
    out = tmp_path / "r.json"
    plot = tmp_path / "p.png"
    args = parser.parse_args(
        [
            "--data",
            str(shared_data),
            "--quick",
            "--sizes",
            "200",
            "--json",
            str(out),
            "--plot",
            str(plot),
        ]
    )
    assert retrieval.run(args) == 0
    result = json.loads(out.read_text())
    for who in ("engine", "baseline"):
        for key in REQUIRED:
            value = _get(result[who], key)
            assert 0.0 <= value <= 4.0, (who, key, value)
        for key in SPEED:
            assert key in result[who]["speed"]["200"], (who, key)
    assert plot.stat().st_size > 1000
    # exhaustive first pass and inverted files side by side on the same tour
    sp = result["engine"]["speed"]["200"]
    assert sp["automatic"] == "exhaustive"  # 200 images: far below the threshold
    for name in ("exhaustive", "inverted_files"):
        side = sp[name]
        assert 0.0 < side["total_ms_p50"] <= side["total_ms_p95"]
        assert 0.0 <= side["recall@1"] <= side["recall@5"] <= 1.0
    assert sp["total_ms_p50"] == sp["exhaustive"]["total_ms_p50"]
    assert sp["inverted_files"]["build_s"] > 0.0
    assert sp["inverted_files"]["index_bytes_per_image"] > 0.0
    assert sp["exhaustive"]["scored_p50"] == 200 > sp["inverted_files"]["scored_p50"]


def test_missing_data_folder_is_a_clear_error(tmp_path: Path, capsys) -> None:
    parser = argparse.ArgumentParser()
    retrieval.add_arguments(parser)
    assert retrieval.run(parser.parse_args(["--data", str(tmp_path), "--quick"])) == 2
    assert "TEACHREPEAT_DATA" in capsys.readouterr().out
