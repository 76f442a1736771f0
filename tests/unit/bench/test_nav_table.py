"""``server.bench.nav_table``: a change measured on several seeds, paired trial by trial, with the
sign test against a naive reference."""

from __future__ import annotations

import itertools
import json
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from server.bench.nav_table import main, paired, pairs_table, sign_test


def naive_sign_test(fixed: int, broken: int) -> float:
    """Every sequence of fair coin flips for the changed trials, counted."""
    n = fixed + broken
    if n == 0:
        return 1.0
    k = min(fixed, broken)
    as_uneven = sum(
        1 for flips in itertools.product((0, 1), repeat=n) if min(sum(flips), n - sum(flips)) <= k
    )
    return min(1.0, as_uneven / 2**n)


@given(st.integers(0, 9), st.integers(0, 9))
def test_the_sign_test_matches_counting_every_outcome(fixed: int, broken: int) -> None:
    p = sign_test(fixed, broken)
    assert p == pytest.approx(naive_sign_test(fixed, broken))
    assert p == sign_test(broken, fixed)
    assert 0 < p <= 1


def test_known_values_of_the_sign_test() -> None:
    assert sign_test(0, 0) == 1.0
    assert sign_test(5, 5) == 1.0
    assert sign_test(26, 17) == pytest.approx(0.222, abs=1e-3)  # place_depth, four seeds
    assert sign_test(10, 0) == pytest.approx(2 / 1024)
    with pytest.raises(ValueError):
        sign_test(-1, 2)


def run(outcomes: list[str | None]) -> dict[str, Any]:
    """A ``bench navigate`` result of one home and condition: ``None`` arrived, else the cause."""
    rows = [
        {
            "plan": "studio",
            "condition": "same",
            "trial": i,
            "success": cause is None,
            "cause": cause,
            "wrong_arrival": cause == "wrong place",
            "goal": "couch",
            "time_s": 10.0,
        }
        for i, cause in enumerate(outcomes)
    ]
    return {"results": [{"rows": rows}]}


def test_paired_counts_arrivals_wrong_places_fixed_and_broken() -> None:
    before = run([None, None, "timeout", "wrong place", None])
    after = run([None, "wrong place", None, None, "lost"])
    assert paired(before, after) == {
        "trials": 5,
        "before": 3,
        "after": 3,
        "wrong_before": 1,
        "wrong_after": 1,
        "fixed": 2,
        "broken": 2,
        "wrong_gone": 1,
        "wrong_new": 1,
    }


def test_runs_of_other_trials_are_refused() -> None:
    other = run([None])
    other["results"][0]["rows"][0]["plan"] = "apartment"
    with pytest.raises(ValueError, match="share no trials"):
        paired(run([None]), other)


def test_pairs_prints_each_seed_and_the_pooled_row(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    files = {}
    for name, outcomes in {
        "a_new": [None, None, None],
        "a_old": [None, "timeout", "lost"],
        "b_new": [None, "wrong place"],
        "b_old": [None, None],
    }.items():
        files[name] = tmp_path / f"{name}.json"
        files[name].write_text(json.dumps(run(outcomes)))
    main(["--pairs", f"{files['a_new']}:{files['a_old']}", f"{files['b_new']}:{files['b_old']}"])
    lines = capsys.readouterr().out.splitlines()
    assert lines[2] == "| a_new / a_old | 3 | 3 / 1 | 0 / 0 | 2 | 0 | 0.50 | 0 | 0 | 1.00 |"
    assert lines[3] == "| b_new / b_old | 2 | 1 / 2 | 1 / 0 | 0 | 1 | 1.00 | 0 | 1 | 1.00 |"
    assert lines[4] == "| **pooled** | 5 | 4 / 3 | 1 / 0 | 2 | 1 | 1.00 | 0 | 1 | 1.00 |"
    with pytest.raises(SystemExit, match=r"AFTER\.json:BEFORE\.json"):
        main(["--pairs", str(files["a_new"])])
    for nothing in ([], ["--pairs"]):
        with pytest.raises(SystemExit, match=r"usage: .*--pairs AFTER\.json:BEFORE\.json"):
            main(nothing)
    with pytest.raises(ValueError, match="at least one"):
        pairs_table([])
