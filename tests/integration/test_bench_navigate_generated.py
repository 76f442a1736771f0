"""A home nobody designed, generated, taught and navigated end to end by ``teachrepeat bench
navigate --generated 1``: the home of seed 1000 x 2 (four rooms) is written to a folder, walked,
taught to a real server and navigated in the real simulator, exactly as a ``--plan`` file is.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from robot_client.sim.generate import generate_plan
from server.cli import main


@pytest.mark.slow
def test_a_generated_home_runs_as_a_plan_file_does(tmp_path: Path) -> None:
    out, homes = tmp_path / "result.json", tmp_path / "homes"
    args = ["bench", "navigate", "--generated", "1", "--seed", "2", "--condition", "same"]
    args += ["--trials", "1", "--max-steps", "40", "--generated-dir", str(homes)]
    args += ["--cache", str(tmp_path / "cache"), "--json", str(out)]
    assert main(args) == 0
    result = json.loads(out.read_text())

    # the home of seed 2000, as `sim generate --seed 2000` makes it, named by seed and SHA-256
    file = homes / "generated_2000.json"
    sha = hashlib.sha256(file.read_bytes()).hexdigest()
    assert file.read_text() == generate_plan(2000).text
    assert result["generated"] == [
        {"seed": 2000, "file": str(file), "name": "generated 2000", "sha256": sha}
    ]
    assert result["plans"] == [
        {"file": "generated_2000.json", "name": "generated 2000", "sha256": sha}
    ]
    # one group (home x condition) with its figures, as for a plan file
    assert (result["plan"], result["condition"], result["plan_sha256"]) == (
        "generated 2000",
        "same",
        sha,
    )
    (row,) = result["rows"]
    assert row["plan"] == "generated 2000" and row["steps"] <= 40
    assert row["success"] or row["cause"] in (
        "wrong place",
        "off target",
        "stuck",
        "lost",
        "timeout",
    )
    assert result["pooled"]["trials"] == 1


def test_a_bad_count_of_generated_homes_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["bench", "navigate", "--generated", "1001", "--seed", "0", "--trials", "1"]
    args += ["--generated-dir", str(tmp_path / "homes"), "--json", str(tmp_path / "r.json")]
    with pytest.raises(SystemExit) as exc:
        main(args)
    assert exc.value.code == 2
    assert "--generated: a run takes 0 to 1000 generated homes, not 1001" in capsys.readouterr().err
    assert not (tmp_path / "r.json").exists()
