"""The per-stage profile of bench load: stacks named by stage, counts added up, and py-spy
sampling a real process."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from collections import Counter
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from server.bench.profile import (
    MARKERS,
    STAGES,
    WAITS,
    Sampler,
    parse_raw,
    stage_of,
    stage_profile,
)

ROOT = "Thread._bootstrap (threading.py:1002)"
STEP = "Navigator.step (server/navigation/navigator.py:174)"


def test_each_marker_names_its_stage() -> None:
    for stage, names in MARKERS:
        for name in names:
            assert stage_of([ROOT, STEP, f"{name} (x.py:1)", "leaf (y.py:2)"]) == stage


def test_the_outer_marker_wins() -> None:
    """The zoom levels of a docking step extract corners inside match_views: homing."""
    stack = [ROOT, STEP, "match_views (o.py:1)", "zoom_levels (h.py:1)", "extract (f.py:1)"]
    assert stage_of(stack) == "homing"
    assert stage_of([ROOT, STEP, "extract (f.py:1)", "match_views (o.py:1)"]) == "features"
    # matched when read: inside a behaviour, below Navigator.step
    lazy = [
        ROOT,
        STEP,
        "Docking.place (d.py:1)",
        "LazyFits.__getitem__ (o.py:1)",
        "zoomed (o.py:2)",
    ]
    assert stage_of([*lazy, "zoom_levels (h.py:1)", "extract (f.py:1)"]) == "homing"


def test_unmarked_stacks_are_motion_inside_a_step_and_http_outside() -> None:
    assert stage_of([ROOT, STEP, "arbitrate (a.py:3)"]) == "motion"
    assert stage_of([ROOT, "Runner.run (asyncio/runners.py:118)"]) == "http"
    assert stage_of([]) == "http"


def test_waits_are_left_out_of_the_stages() -> None:
    counts = Counter(
        {
            (ROOT, STEP, "extract (f.py:1)"): 3,
            (ROOT, "Condition.wait (threading.py:327)"): 10,
            (ROOT, STEP, "match_views (o.py:1)", "Semaphore.acquire (threading.py:1)"): 2,
        }
    )
    profile = stage_profile(counts)
    assert profile.waiting == 12 and profile.total == 3
    assert profile.fractions()["features"] == 1.0


def test_parse_raw_reads_counts_and_skips_other_lines() -> None:
    text = "a (x.py:1);b (x.py:2) 5\na (x.py:1);b (x.py:2) 2\nnot a line\nc (y.py:3) 1\n"
    counts = parse_raw(text)
    assert counts == Counter({("a (x.py:1)", "b (x.py:2)"): 7, ("c (y.py:3)",): 1})


names = st.sampled_from(
    [n for _, ns in MARKERS for n in ns]
    + ["Navigator.step", "foo", "Runner.run", "bar", "Condition.wait", "Thread.join"]
)
stacks = st.lists(names.map(lambda n: f"{n} (f.py:1)"), min_size=1, max_size=6).map(tuple)


@given(st.dictionaries(stacks, st.integers(1, 50), max_size=20))
def test_stage_profile_against_a_naive_sum(counts: dict[tuple[str, ...], int]) -> None:
    profile = stage_profile(Counter(counts))
    naive = {s: 0 for s in STAGES}
    waiting = 0
    for stack, n in counts.items():
        if stack[-1].split(" (")[0] in WAITS:
            waiting += n
        else:
            naive[stage_of(stack)] += n
    assert profile.samples == naive
    assert profile.waiting == waiting
    assert profile.total + waiting == sum(counts.values())
    fractions = profile.fractions()
    if profile.total:
        assert sum(fractions.values()) == pytest.approx(1.0)
        per_frame = profile.as_json(8.0)["cpu_ms_per_frame"]
        assert sum(per_frame.values()) == pytest.approx(8.0, abs=0.01)
    else:
        assert set(fractions.values()) == {0.0}


@pytest.mark.skipif(Sampler.executable() is None, reason="py-spy is not installed")
def test_py_spy_samples_a_real_process_into_its_stage(tmp_path: Path) -> None:
    """A process busy in a function named ``extract`` is profiled as ``features``."""
    busy = textwrap.dedent(
        """
        import sys, time
        def extract():
            x = 0
            while True:
                x += 1
        print("ready", flush=True)
        extract()
        """
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", busy], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == b"ready"
        spy = Sampler(proc.pid, 1.0, tmp_path / "raw.txt")
        spy.start()
        try:
            profile = spy.finish(timeout_s=20)
        except RuntimeError as exc:
            if "ermission" in str(exc):
                pytest.skip(f"py-spy may not trace processes here: {exc}")
            raise
    finally:
        proc.kill()
        proc.wait()
    assert profile.total >= 20
    assert profile.samples["features"] / profile.total > 0.9


def test_bench_load_refuses_raw_stacks_without_the_profile(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import argparse

    from server.bench import load

    parser = argparse.ArgumentParser()
    load.add_arguments(parser)
    args = parser.parse_args(["--profile-raw", str(tmp_path / "stacks.txt")])
    assert load.run(args) == 2
    assert "pass both" in capsys.readouterr().out
    assert not (tmp_path / "stacks.txt").exists()
