"""``teachrepeat bench sim-retrieval`` on a short route: it runs and reports every cell."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from server.bench.sim_retrieval import CONDITIONS
from server.cli import main


@pytest.mark.slow
def test_sim_retrieval_on_a_short_route(tmp_path: Path) -> None:
    out = tmp_path / "sim.json"
    code = main(
        [
            "bench",
            "sim-retrieval",
            "--route",
            "entry,living room",
            "--queries",
            "80",
            "--radius",
            "1.0",
            "--angle",
            "45",
            "--json",
            str(out),
        ]
    )
    assert code == 0
    result = json.loads(out.read_text())
    assert set(result["configs"]) == {
        "grey_world/learned",
        "grey_world/robust",
        "raw/learned",
        "raw/robust",
    }
    for cells in result["configs"].values():
        assert len(cells["weights"]) == 5
        for condition in CONDITIONS:
            cell = cells[condition]
            assert cell["queries"] > 0
            assert 0.0 <= cell["image_recall@1"] <= 1.0
            assert 0.0 <= cell["state_recall@1"] <= 1.0
