"""``python -m server.bench.localize_table``: bench localize results as one Markdown table."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from server.bench import localize_table

METHODS = ("ir_only", "tracker", "smoother")


def summary(reference: str, query: str, recall: float, *, halves: bool = False) -> dict[str, Any]:
    at = {
        t: {m: {"recall@1": recall + 0.1 * k, "mean_error_frames": 4.5} for m in METHODS}
        for k, t in enumerate(("0", "2", "10"))
    }
    d: dict[str, Any] = {
        "reference": reference,
        "query": query,
        "frames": 900,
        "weights": "learned",
        "weights_used": [0.6, 0.1, 0.0, 0.0, 0.3],
        "weight_blocks": ["hist", "thumb", "desc_mean", "desc_var", "patch"],
        "recall_at": at,
    }
    if halves:
        half = {"frames": 450, "recall_at": at}
        d["halves"] = {"first": half, "second": half}
    return d


def test_table_has_a_row_per_dataset_direction_and_tolerance() -> None:
    result = {
        "half": "second",
        "directions": {
            "forward": summary("d/nordland/winter", "d/nordland/summer", 0.25),
            "reverse": summary("d/nordland/summer", "d/nordland/winter", 0.5),
        },
    }
    text = localize_table.table([result])
    lines = text.splitlines()
    assert len(lines) == 2 + 2 * 3
    assert lines[0].startswith("| data | half | query -> reference | weights (hist/thumb/")
    assert lines[2] == (
        "| nordland | second | summer -> winter | learned: 0.60/0.10/0.00/0.00/0.30 | 900 | 0 | "
        "0.250 (4.50) | 0.250 (4.50) | 0.250 (4.50) |"
    )
    assert lines[4] == "|  |  |  |  |  | 10 | 0.450 | 0.450 | 0.450 |"
    assert lines[5].startswith("| nordland | second | winter -> summer |")
    assert "0.700 | 0.700 | 0.700" in lines[7]


def test_halves_rows_only_when_asked() -> None:
    result = {
        "half": "all",
        "directions": {"forward": summary("c/ref", "c/query", 0.5, halves=True)},
    }
    assert len(localize_table.rows(result)) == 3
    rows = localize_table.rows(result, halves=True)
    assert len(rows) == 9
    assert rows[3].startswith("| c | first of all | query -> ref |")
    assert "| 450 | 0 |" in rows[6]


def test_result_without_directions_gives_its_forward_run_from_the_recall_curve() -> None:
    curve: dict[str, Any] = {"tolerance": list(range(21))}
    for m in METHODS:
        curve[m] = [t / 20 for t in range(21)]
    old = {
        "reference": "x/corridor/ref",
        "query": "x/corridor/query",
        "frames": 111,
        "weights": "patch",
        "recall_curve": curve,
        **{m: {"recall@1": 0.0, "mean_error_frames": 2.0} for m in METHODS},
    }
    rows = localize_table.rows(old)
    assert len(rows) == 3
    assert rows[0].startswith("| corridor | all | query -> ref | patch | 111 | 0 | 0.000 (2.00)")
    assert rows[2] == "|  |  |  |  |  | 10 | 0.500 | 0.500 | 0.500 |"


def test_dataset_name() -> None:
    assert localize_table.dataset_name("a/nordland/winter", "a/nordland/summer") == "nordland"
    assert localize_table.dataset_name("a/day", "b/night") == "day / night"


def test_main_prints_the_table_of_every_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    paths = []
    for k, name in enumerate(("corridor", "nordland")):
        path = tmp_path / f"{name}.json"
        result = {"directions": {"forward": summary(f"{name}/a", f"{name}/b", 0.1 * k)}}
        path.write_text(json.dumps(result))
        paths.append(str(path))
    assert localize_table.main(paths) == 0
    out = capsys.readouterr().out
    assert "| corridor | all | b -> a |" in out and "| nordland | all | b -> a |" in out
    assert localize_table.main([]) == 2
