"""A home written as data, taught and navigated end to end by ``teachrepeat bench navigate``,
with the same outcome for every trial whatever the number of workers or the trials run.

The two-room plan of tests/data/plans is walked once (then taken from the cache), taught to
each worker's real server through the REST API, and navigated in the real simulator.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import pytest

from server.bench.nav_sweep import recording_key
from server.cli import main

PLAN = Path(__file__).resolve().parents[1] / "data" / "plans" / "two_rooms.json"


def bench(tmp_path: Path, name: str, *extra: str) -> dict[str, Any]:
    out = tmp_path / f"{name}.json"
    args = ["bench", "navigate", "--trials", "1", "--seed", "2", "--max-steps", "400"]
    args += ["--cache", str(tmp_path / "cache"), "--json", str(out)]
    assert main([*args, *extra]) == 0
    return json.loads(out.read_text())


def rows(result: dict[str, Any]) -> list[dict[str, Any]]:
    groups = result.get("results", [result])
    skip = ("wall_s", "recording", "recording_db")
    return [{k: v for k, v in r.items() if k not in skip} for g in groups for r in g["rows"]]


@pytest.mark.slow
def test_a_two_room_home_is_taught_and_navigated_the_same_on_any_number_of_workers(
    tmp_path: Path,
) -> None:
    # the same plan twice on one worker (two tours on its server), then once on two workers
    plans = ["--plan", str(PLAN), str(PLAN), "--condition", "same", "moved"]
    evidence, every = tmp_path / "failed", tmp_path / "every"
    one = bench(tmp_path, "one", *plans, "--workers", "1", "--record", str(evidence))
    two = bench(
        tmp_path, "two", "--plan", str(PLAN), "--condition", "same", "moved", "--workers", "2"
    )
    trace = tmp_path / "trace"
    alone = bench(
        tmp_path,
        "alone",
        *("--plan", str(PLAN), "--condition", "moved", "--only", "0"),
        *("--record", str(every), "--record-all", "--trace", str(trace)),
    )

    # trial for trial, to the robot microsecond and millimetre (recording changes nothing)
    first, second = ([r for r in rows(one) if r["plan_index"] == k] for k in (0, 1))
    assert rows(two) == first  # on two workers (and one tour on each server) as on one
    for r in second:
        r["plan_index"] = 0
    assert first == second  # a trial goes the same whatever other tours the server holds
    assert rows(alone) == [r for r in first if r["condition"] == "moved" and r["trial"] == 0]
    # the plan's identity is in every result, and the figures are per plan x condition
    assert [p["file"] for p in one["plans"]] == ["two_rooms.json"] * 2
    assert len(one["plans"][0]["sha256"]) == 64
    assert [(r["plan"], r["condition"]) for r in one["results"]] == [
        ("two rooms", "same"),
        ("two rooms", "moved"),
    ] * 2
    assert alone["plan_sha256"] == one["plans"][0]["sha256"]  # one group: at the top level too
    assert alone["success_rate"] in (0.0, 1.0) and "median_path_ratio" in alone
    pooled = one["pooled"]
    assert pooled["trials"] == 4 and pooled["wrong_arrivals"] == 0
    assert pooled["successes"] >= 3, rows(one)  # the place across the door is found
    # the evidence: a failed trial's recording is kept (and named), a successful one's not
    kept = [r for g in one["results"] for r in g["rows"] if r.get("recording")]
    assert all(not r["success"] for r in kept) and len(kept) == 4 - pooled["successes"]
    assert one["record"] == {"folder": str(evidence), "all": False, "kept": len(kept)}
    (row,) = alone["rows"]
    # its trace (recorded and traced, the trial went as it did untraced: compared above): one
    # line per step, with the judge's truth and the command
    lines = (trace / "two_rooms" / "moved" / "trial_000.jsonl").read_text().splitlines()
    steps = [json.loads(line) for line in lines]
    assert [s["step"] for s in steps] == list(range(1, row["steps"] + 1))
    assert {"pose", "action", "behaviour", "v", "w", "top", "path"} <= steps[0].keys()
    assert row["recording"] == str(every / "two_rooms" / "moved" / "trial_000.mcap")
    assert row["recording_db"] == str(every / "two_rooms.sqlite")
    from server.recording.reader import read_recording
    from server.recording.replay import replay

    recording = read_recording(row["recording"])
    assert recording.meta["goal"] == row["goal"] and recording.complete
    assert len(recording.frames) == row["steps"]
    report, _ = replay(recording, Path(row["recording_db"]))
    assert report.frames_replayed == row["steps"] and not report.differing
    for r in rows(one):
        assert r["success"] or r["cause"] in (
            "wrong place",
            "off target",
            "stuck",
            "lost",
            "timeout",
        )


@pytest.mark.slow
def test_a_trial_that_raises_is_reported_and_the_finished_trials_are_kept(tmp_path: Path) -> None:
    # a second home whose cached tour is unreadable: its trial raises in the worker teaching
    # it; the sweep goes on, the first home's trial finishes and its figures are written
    broken = tmp_path / "broken_rooms.json"
    broken.write_text(json.dumps({**json.loads(PLAN.read_text()), "name": "broken rooms"}))
    cache = tmp_path / "cache"
    cache.mkdir()
    key = recording_key(hashlib.sha256(broken.read_bytes()).hexdigest(), 2)
    (cache / key).write_bytes(b"not a tour recording")
    out = tmp_path / "out.json"
    args = ["bench", "navigate", "--plan", str(PLAN), str(broken), "--trials", "1"]
    args += ["--seed", "2", "--max-steps", "400", "--workers", "2"]
    assert main([*args, "--cache", str(cache), "--json", str(out)]) == 1  # said: not all ran
    result = json.loads(out.read_text())
    (error,) = result["errors"]
    assert (error["plan"], error["plan_index"], error["condition"], error["trial"]) == (
        "broken rooms",
        1,
        "same",
        0,
    )
    assert "is not a readable tour recording" in error["traceback"]
    (row,) = rows(result)  # the trial that finished, at the top level as one group's are
    assert row["plan"] == "two rooms" and result["trials"] == 1
