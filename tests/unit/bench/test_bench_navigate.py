"""The options and figures of ``teachrepeat bench navigate`` (the benchmark itself runs as a
command; its closed loop is tested in tests/integration/test_bench_navigate_sweep.py)."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from robot_client.sim import load_plan
from robot_client.trial import StepLog, cause, draw_trial
from server.bench.common import wilson_interval
from server.bench.nav_sweep import BENCH_SERVER_SETTINGS
from server.bench.navigate import _trial_list, navigation_env, summarise
from server.tuning import setting_argument as _setting

PLANS = Path(__file__).resolve().parents[2] / "data" / "plans"


def test_set_takes_json_values_and_bare_words() -> None:
    assert _setting("dock_second_axis=false") == ("dock_second_axis", False)
    assert _setting("motion.unstick_s=6") == ("motion.unstick_s", 6)
    assert _setting("dock_zooms=[1.3, 1.69]") == ("dock_zooms", [1.3, 1.69])
    assert _setting("x=word") == ("x", "word")
    for bad in ("nonsense", "=3"):
        with pytest.raises(argparse.ArgumentTypeError, match="NAME=VALUE"):
            _setting(bad)


def test_settings_are_checked_before_the_server_starts() -> None:
    env = navigation_env([("dock_second_axis", False), ("motion.unstick_s", 6)])
    assert json.loads(env["TEACHREPEAT_NAVIGATION"]) == {
        **BENCH_SERVER_SETTINGS,
        "dock_second_axis": False,
        "motion.unstick_s": 6,
    }
    assert json.loads(navigation_env([])["TEACHREPEAT_NAVIGATION"]) == BENCH_SERVER_SETTINGS
    with pytest.raises(ValueError, match="no setting 'dock_second_axes'"):
        navigation_env([("dock_second_axes", False)])


def test_only_takes_trial_numbers() -> None:
    assert _trial_list("2,5,14") == frozenset({2, 5, 14})
    for bad in ("a,b", "", "-1"):
        with pytest.raises(argparse.ArgumentTypeError):
            _trial_list(bad)


def test_wilson_interval_matches_the_formula_and_known_values() -> None:
    lo, hi = wilson_interval(50, 50)
    assert lo == pytest.approx(0.9287, abs=1e-4) and hi == pytest.approx(1.0)
    lo, hi = wilson_interval(47, 50)
    assert (lo, hi) == (pytest.approx(0.8378, abs=1e-4), pytest.approx(0.9794, abs=1e-4))
    assert all(math.isnan(v) for v in wilson_interval(0, 0))


@given(st.integers(1, 500), st.data())
def test_wilson_interval_holds_the_rate_and_stays_in_0_1(n: int, data: st.DataObject) -> None:
    k = data.draw(st.integers(0, n))
    lo, hi = wilson_interval(k, n)
    assert 0.0 <= lo <= k / n <= hi <= 1.0
    assert hi - lo < wilson_interval(k, n, z=2.5)[1] - wilson_interval(k, n, z=2.5)[0] + 1e-12


def test_a_trial_is_drawn_from_its_seed_and_number_alone() -> None:
    plan = load_plan()
    a = [draw_trial(plan, 5, t) for t in range(12)]
    b = [draw_trial(plan, 5, t) for t in reversed(range(12))][::-1]
    assert a == b  # the order they are drawn in does not matter
    assert draw_trial(plan, 6, 0) != a[0]
    names = {p.name for p in plan.places}
    for t, (start, goal, noise) in enumerate(a):
        assert goal in names and noise >= 0
        assert plan.room_at(start.x, start.y) is not None
        if t % 4 == 3:  # beside a look-alike place
            near = min(
                np.hypot(start.x - plan.place(n).x, start.y - plan.place(n).y)
                for n in ("bedroom", "guest room")
            )
            assert near <= 0.8 * math.sqrt(2) + 1e-9


def _log(
    points: list[tuple[float, float]], *, v: float, action: str, localised: bool = True
) -> list[StepLog]:
    return [
        StepLog(0.1 * k, x, y, v, action, "follow", localised) for k, (x, y) in enumerate(points)
    ]


def test_failure_causes() -> None:
    still = _log([(1.0, 1.0)] * 300, v=0.0, action="navigate")
    moving = _log([(0.01 * k, 1.0) for k in range(300)], v=0.2, action="navigate")
    lost = _log([(0.01 * k, 1.0) for k in range(300)], v=0.2, action="explore", localised=False)
    assert cause(success=True, state="arrived", reason=None, wrong_arrival=False, log=still) is None
    assert (
        cause(success=False, state="arrived", reason=None, wrong_arrival=True, log=moving)
        == "wrong place"
    )
    assert (
        cause(success=False, state="arrived", reason=None, wrong_arrival=False, log=moving)
        == "off target"
    )
    assert (
        cause(success=False, state="underway", reason="ran out", wrong_arrival=False, log=still)
        == "stuck"
    )
    assert (
        cause(success=False, state="underway", reason="ran out", wrong_arrival=False, log=moving)
        == "timeout"
    )
    assert (
        cause(success=False, state="underway", reason="ran out", wrong_arrival=False, log=lost)
        == "lost"
    )
    assert (
        cause(
            success=False,
            state="failed",
            reason="lost: no confident",
            wrong_arrival=False,
            log=moving,
        )
        == "lost"
    )
    # turning on the spot to search is not being stuck
    searching = _log([(1.0, 1.0)] * 300, v=0.0, action="rotate_and_find_edge")
    assert (
        cause(success=False, state="underway", reason="ran out", wrong_arrival=False, log=searching)
        == "timeout"
    )


def test_summary_counts_successes_causes_and_path_ratios() -> None:
    def row(ok: bool, ratio: float, why: str | None = None, wrong: bool = False) -> dict:
        return {
            "success": ok,
            "path_ratio": ratio,
            "time_s": 50.0,
            "free_space_ratio": ratio,
            "explore_fraction": 0.1,
            "wrong_arrival": wrong,
            "cause": why,
            "final_behaviour": None if ok else "search",
        }

    rows = [row(True, r) for r in (1.0, 1.1, 1.2, 1.3, 2.0)]
    rows += [row(False, 3.0, "timeout"), row(False, 1.0, "wrong place", wrong=True)]
    s = summarise(rows)
    assert (s["trials"], s["successes"], s["wrong_arrivals"]) == (7, 5, 1)
    assert s["success_rate"] == pytest.approx(5 / 7)
    assert s["success_ci95"] == list(wilson_interval(5, 7))
    assert s["median_path_ratio"] == pytest.approx(1.2)  # successes only
    assert s["p90_path_ratio"] == pytest.approx(np.percentile([1.0, 1.1, 1.2, 1.3, 2.0], 90))
    assert s["failures_by_cause"] == {"wrong place": 1, "timeout": 1}
    assert s["failures_by_behaviour"] == {"search": 2}


def test_a_worker_says_it_is_done_only_once_its_server_and_homes_are_closed(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The sweep lets a worker go on its last word (the seconds spent teaching): said before
    the worker closed, a SIGTERM from the sweep caught it midway through closing and left its
    scratch server running with no parent. The worker here stands in for the real one (a
    server and the simulator), recording when it closes."""
    import queue

    from server.bench import nav_sweep

    said: list[str] = []

    class Worker:
        teach_s = 1.5

        def __init__(self, config: object) -> None:
            pass

        def __enter__(self) -> Worker:
            return self

        def __exit__(self, *exc: object) -> None:
            said.append("closed")

        def run(self, spec: object) -> dict[str, object]:
            return {"trial": spec}

    class Results:
        def put(self, item: tuple[str, object, object]) -> None:
            said.append(item[0])

    tasks: queue.Queue[object] = queue.Queue()
    for item in (3, None):
        tasks.put(item)
    monkeypatch.setattr(nav_sweep, "Worker", Worker)
    monkeypatch.setattr(nav_sweep.signal, "signal", lambda *a: None)  # not this process's
    nav_sweep._serve(None, tasks, Results())  # type: ignore[arg-type]
    assert said == ["row", "closed", "teach_s"]


def test_a_trial_waits_for_a_slow_answer_instead_of_resending_the_frame(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The simulated world stands still while the robot waits for the server, so a loaded
    machine must change nothing in a trial: the robot's client waits for every answer (up to
    ``ANSWER_WAIT_S``), not the 10 s a real robot waits before it resends the frame (which
    made trials depend on the load, and ended whole runs when several ran at once). The
    worker's server, tour and world stand in here: only the client it opens is looked at."""
    import robot_client.client
    from server.bench import nav_sweep

    opened: list[dict[str, object]] = []

    class Opened(Exception):
        pass

    def client(url: str, token: str, **kwargs: object) -> object:
        opened.append(kwargs)
        raise Opened

    class Server:
        url = "http://127.0.0.1:1"

        def register_robot(self, name: str, *, timeout_s: float = 10.0) -> str:
            opened.append({"register timeout_s": timeout_s})
            return "token"

    worker = object.__new__(nav_sweep.Worker)
    worker.plans = [load_plan(PLANS / "two_rooms.json")]
    worker.server = Server()  # type: ignore[assignment]
    worker.config = nav_sweep.SweepConfig(("two_rooms.json",), ("none.npz",), 0, 10, (), None)
    worker._tours, worker._worlds = {0: object()}, {(0, "same"): object()}
    monkeypatch.setattr(robot_client.client, "TeachRepeatClient", client)
    with pytest.raises(Opened):
        worker.run(nav_sweep.TrialSpec(0, "same", 0))
    wait = nav_sweep.ANSWER_WAIT_S
    assert opened == [{"register timeout_s": wait}, {"timeout_s": wait}]  # the admin's too
    assert nav_sweep.ANSWER_WAIT_S >= 300  # minutes: only a hung server is given up on
