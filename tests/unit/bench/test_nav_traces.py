"""``python -m server.bench.nav_traces``: the path tracker's locks counted from a traced
``bench navigate`` run, on synthetic traces whose every count is known."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from server.bench.nav_traces import load, main, summary


def frame(step: int, *, behaviour: str = "follow", action: str = "navigate", path=None) -> dict:
    return {
        "step": step,
        "behaviour": behaviour,
        "action": action,
        "reason": behaviour,
        "path": path,
    }


def tracked(edge: int, along: float, error: float, *, locked: bool, sd=(0.05, 0.05, 0.02)) -> dict:
    return {
        "edge": edge,
        "along": along,
        "lateral": 0.4,
        "sd": list(sd),
        "locked": locked,
        "true_error": error,
    }


def write(root: Path, plan: str, condition: str, trial: int, frames: list[dict]) -> None:
    folder = root / plan.replace(" ", "_") / condition
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"trial_{trial:03d}.jsonl").write_text("".join(json.dumps(f) + "\n" for f in frames))


def row(plan: str, trial: int, *, success: bool, state: str, distance: float) -> dict[str, Any]:
    return {
        "plan": plan,
        "condition": "same",
        "trial": trial,
        "success": success,
        "state": state,
        "distance_m": distance,
    }


@pytest.fixture
def run(tmp_path: Path) -> tuple[Path, Path]:
    """Two traced trials of 'office floor' and one without a trace."""
    lost = [
        frame(1, behaviour="explore", action="explore"),
        # locked while searching at the place, 1 m off the path: taken off it, searching
        frame(
            2,
            behaviour="search",
            action="rotate_and_find_edge",
            path=tracked(0, 0.0, 1.0, locked=False),
        ),
        frame(3, path=tracked(0, 0.1, 1.0, locked=True)),
        frame(4, path=tracked(0, 0.2, 1.0, locked=True)),
        # let go off the path within the lock's bounds: for want of measurements
        frame(
            5,
            behaviour="search",
            action="rotate_and_find_edge",
            path=tracked(0, 0.2, 1.0, locked=False),
        ),
        frame(
            6,
            behaviour="search",
            action="rotate_and_find_edge",
            path=tracked(0, 0.2, 1.0, locked=False),
        ),
        # locked on the path while driving: taken on it, otherwise
        frame(7, path=tracked(0, 2.0, 0.1, locked=True)),
        # let go on the path, uncertain, never again
        frame(
            8,
            behaviour="settle",
            action="do_nothing",
            path=tracked(0, 2.0, 0.1, locked=False, sd=(0.5, 0.6, 1.0)),
        ),
        frame(
            9,
            behaviour="settle",
            action="do_nothing",
            path=tracked(0, 2.0, 0.1, locked=False, sd=(0.5, 0.6, 1.0)),
        ),
    ]
    wrong = [
        frame(1, path=tracked(1, 3.0, 0.05, locked=True)),
        frame(2, path=tracked(1, 3.1, 0.05, locked=True)),
        frame(3, behaviour="stand", action="do_nothing", path=tracked(1, 3.1, 0.05, locked=True)),
    ]
    write(tmp_path / "trace", "office floor", "same", 0, lost)
    write(tmp_path / "trace", "office floor", "same", 1, wrong)
    result = {
        "results": [
            {
                "rows": [
                    row("office floor", 0, success=False, state="underway", distance=5.0),
                    row("office floor", 1, success=False, state="arrived", distance=2.5),
                    row("office floor", 2, success=True, state="arrived", distance=0.1),
                ]
            }
        ]
    }
    (tmp_path / "result.json").write_text(json.dumps(result))
    return tmp_path / "trace", tmp_path / "result.json"


def test_locks_let_go_and_taken_are_counted_where_and_why(run: tuple[Path, Path]) -> None:
    trace, result = run
    trials = load(trace, json.loads(result.read_text()))
    assert [t.trial for t in trials] == [0, 1]  # trial 2 has no trace
    out = summary(trials)
    assert out["let_go"] == {"off / measurements": 1, "on / uncertain": 1}
    # only a lock let go on the path counts toward locking again; this one never did
    assert out["frames_to_lock_again_after_on_path"] == 0
    assert out["behaviours_until_locked_again_after_on_path"] == {"settle": 2}
    # the one lock let go for want of measurements: off the path, locked 2 frames, 0.1 m gained
    assert out["let_go_for_measurements_medians"] == {
        "off": {
            "locked_frames": 2.0,
            "lateral_m": 0.4,
            "sd_along_m": 0.05,
            "gained_m": 0.1,
            "belief_on_an_edge": 0.0,
        }
    }
    assert out["taken"] == {
        "off / searching at a place": {"all": 1, "in failed trials": 1},
        "on / otherwise": {"all": 1, "in failed trials": 1},  # (a trace's first frame: none)
    }
    [false] = out["false_arrivals"]
    assert false["trial"] == "office floor / same / 1" and false["distance_m"] == 2.5
    assert false["behaviour"] == "follow" and false["locked"] and false["along_m"] == 3.1


def test_the_command_prints_and_saves_the_counts_and_refuses_a_run_without_traces(
    run: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    trace, result = run
    main([str(trace), str(result), "--json", str(tmp_path / "out.json")])
    printed = json.loads(capsys.readouterr().out)
    assert printed == json.loads((tmp_path / "out.json").read_text())
    assert printed["trials"] == 2
    with pytest.raises(SystemExit):
        main([str(tmp_path / "nowhere"), str(result)])
    assert "no trace of any trial" in capsys.readouterr().err


def at(step: int, x: float, v: float, w: float, top: str, **kw: Any) -> dict:
    """A frame with the true pose (``x``, 0), the command and the belief's top state."""
    return frame(step, **kw) | {"pose": [x, 0.0, 0.0], "v": v, "w": w, "top": [[top, 0.9]]}


def test_with_the_plans_the_belief_while_turning_and_the_search_locks_are_counted_by_place(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    frames = [
        at(1, 0.5, 0.0, 0.5, "hall"),  # turning near the hall, believed at it
        at(2, 3.0, 0.0, 0.5, "hall"),  # turning 3 m from it, believed at it
        at(3, 3.0, 0.0, 0.5, "hall -> den"),  # turning far, believed on an edge
        at(4, 3.0, 0.01, 0.1, "hall"),  # too slow a turn: not counted
        at(5, 3.0, 0.3, 0.0, "hall -> den"),  # driving far, on an edge
        # a lock taken searching at the hall 2.5 m from its spot, in a trial that failed
        at(
            6,
            2.5,
            0.0,
            0.5,
            "hall",
            behaviour="search",
            action="rotate_and_find_edge",
            path=tracked(0, 0.0, 1.0, locked=False),
        ),
        at(7, 2.5, 0.0, 0.5, "hall", path=tracked(0, 0.1, 1.0, locked=True)),
    ]
    write(tmp_path / "trace", "flat", "same", 0, frames)
    result = {"results": [{"rows": [row("flat", 0, success=False, state="underway", distance=4)]}]}
    (tmp_path / "result.json").write_text(json.dumps(result))
    plan = {"name": "flat", "places": [{"name": "hall", "x": 0.0, "y": 0.0}]}
    (tmp_path / "flat.json").write_text(json.dumps(plan))
    trials = load(tmp_path / "trace", result)
    out = summary(trials, spots={"flat": {"hall": (0.0, 0.0)}})["by_place"]
    assert out["belief_while"]["turning, near"] == {"frames": 1, "belief_top_a_place": 1.0}
    # frames 2, 3, 6 and 7 turn 2.5-3 m from the hall; three of them believed at it
    assert out["belief_while"]["turning, far"] == {"frames": 4, "belief_top_a_place": 0.75}
    assert out["belief_while"]["driving, far"] == {"frames": 1, "belief_top_a_place": 0.0}
    assert out["belief_while"]["driving, near"] == {"frames": 0, "belief_top_a_place": None}
    assert out["locks_taken_searching_by_distance_from_the_place"][">= 2.0 m"] == {
        "all": 1,
        "in failed trials": 1,
    }
    assert summary(trials).get("by_place") is None  # without the plans: not counted
    trace, res = str(tmp_path / "trace"), str(tmp_path / "result.json")
    main([trace, res, "--plan", str(tmp_path / "flat.json")])
    assert "by_place" in json.loads(capsys.readouterr().out)
    (tmp_path / "other.json").write_text(json.dumps(plan | {"name": "other"}))
    with pytest.raises(SystemExit):
        main([trace, res, "--plan", str(tmp_path / "other.json")])
    assert "no plan named flat" in capsys.readouterr().err


def test_locks_taken_are_also_judged_by_the_estimates_own_error_where_the_trace_has_it(
    tmp_path: Path,
) -> None:
    def judged(along: float, missed: float, *, locked: bool) -> dict:
        return tracked(0, along, 0.05, locked=locked) | {"estimate_error": missed}

    frames = [
        frame(1, path=judged(0.0, 3.0, locked=False)),
        frame(2, path=judged(0.1, 3.0, locked=True)),  # on the path's line, 3 m from the robot
        frame(3, path=judged(0.2, 3.0, locked=False)),
        frame(4, path=judged(1.0, 0.1, locked=True)),  # right
    ]
    write(tmp_path / "trace", "flat", "same", 0, frames)
    result = {"results": [{"rows": [row("flat", 0, success=True, state="arrived", distance=0)]}]}
    out = summary(load(tmp_path / "trace", result))
    assert out["taken"] == {"on / otherwise": {"all": 2, "in failed trials": 0}}
    assert out["taken_by_estimate_error"] == {
        "path on / estimate off": {"all": 1, "in failed trials": 0},
        "path on / estimate on": {"all": 1, "in failed trials": 0},
    }
