"""``teachrepeat bench dock-views``: docking's verdict on single views, the frame's zooms and
the taught image's."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from server.bench.dock_views import METHODS, summary, verdict
from server.cli import main


def test_verdict_is_docking_s_reading_of_one_scale() -> None:
    assert verdict(1.2, 0.06) == 1  # the taught view looks larger: short of it
    assert verdict(0.8, 0.06) == -1  # smaller: past it
    assert verdict(1.05, 0.06) == 0 and verdict(0.95, 0.06) == 0
    assert verdict(math.exp(math.log1p(0.06)) * 1.001, 0.06) == 1


def test_summary_counts_only_views_docking_acts_on() -> None:
    def row(d: float, inl: int, v: int) -> dict:
        fit = {"inliers": inl, "scale": 1.0, "verdict": v}
        return {"offset_m": d, "frame": fit, "taught": dict(fit, verdict=0, inliers=inl - 1)}

    rows = [row(-0.4, 20, 1), row(-0.4, 5, 1), row(-0.4, 30, 0), row(0.4, 12, -1)]
    table = summary(rows, [-0.4, 0.4], min_inliers=10)
    behind = table["-0.40"]
    assert behind["views"] == 3
    assert behind["frame"]["acted_share"] == pytest.approx(2 / 3)
    assert behind["frame"]["right_share"] == pytest.approx(1 / 3)  # the 5-inlier view: no say
    assert behind["frame"]["mean_inliers"] == pytest.approx(55 / 3)
    assert behind["taught"]["right_share"] == 0.0
    assert behind["taught"]["acted_share"] == pytest.approx(2 / 3)  # 19 and 29 inliers
    assert table["+0.40"]["frame"]["right_share"] == 1.0
    assert table["+0.40"]["taught"]["acted_share"] == 1.0  # 11 inliers
    assert set(behind) == {"views", *METHODS}


@pytest.mark.slow
def test_dock_views_on_the_apartment(tmp_path: Path) -> None:
    out = tmp_path / "dock.json"
    code = main(
        ["bench", "dock-views", "--headings", "1", "--offsets", "0", "-0.4", "--json", str(out)]
    )
    assert code == 0
    result = json.loads(out.read_text())
    there = result["summary"]["+0.00"]
    assert there["views"] >= 6
    for m in METHODS:  # on the spot both ways are the plain fit of the same view
        assert there[m]["right_share"] >= 0.8
        assert there[m]["mean_inliers"] >= 30
    assert result["summary"]["-0.40"]["views"] >= 4
