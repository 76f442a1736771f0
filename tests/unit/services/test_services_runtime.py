"""Tour runtimes: a new task never starts on a runtime older than the tour's last change."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from pathlib import Path

from server.imaging import ImageLimits
from server.services.navigation import NavigationService
from server.storage.repo import Repo


@dataclass
class FakeRuntime:
    version: int


class SlowBuilds(NavigationService):
    """The real build rules around a build that takes ``build_s`` and returns a stand-in."""

    build_s = 0.3

    def _build(self, tour_id: int, *, version: int) -> FakeRuntime:  # type: ignore[override]
        time.sleep(self.build_s)
        return FakeRuntime(version)


def _service(tmp_path: Path) -> SlowBuilds:
    nav = SlowBuilds(Repo(tmp_path / "t.sqlite"), ImageLimits())
    nav._closed = True  # no background prebuild: the test starts the builds itself
    return nav


def _build_in_background(nav: SlowBuilds) -> threading.Thread:
    t = threading.Thread(target=nav.runtime, args=(1,))
    t.start()
    deadline = time.monotonic() + 5
    while not nav._build_locks[1].locked():  # wait until the build is under way
        assert time.monotonic() < deadline
        time.sleep(0.005)
    return t


def test_a_new_task_waits_for_the_build_after_a_change(tmp_path: Path) -> None:
    nav = _service(tmp_path)
    first = nav.runtime(1)
    nav.tour_changed(1)
    builder = _build_in_background(nav)
    # before the fix, a caller during the build got the previous runtime and the task ran on
    # the tour as it was before the change
    assert nav.runtime(1).version == first.version + 1
    builder.join()


def test_a_step_under_way_keeps_the_previous_runtime_while_the_build_runs(tmp_path: Path) -> None:
    nav = _service(tmp_path)
    first = nav.runtime(1)
    nav.tour_changed(1)
    builder = _build_in_background(nav)
    started = time.monotonic()
    assert nav.runtime(1, wait=False) is first
    assert time.monotonic() - started < SlowBuilds.build_s / 2  # did not wait for the build
    builder.join()
    assert nav.runtime(1, wait=False).version == first.version + 1


def test_a_change_during_a_build_leaves_the_tour_stale(tmp_path: Path) -> None:
    nav = _service(tmp_path)
    nav.runtime(1)
    nav.tour_changed(1)
    builder = _build_in_background(nav)
    nav.tour_changed(1)  # teaching goes on while the build runs
    builder.join()
    built = nav._runtimes[1]
    assert nav.runtime(1).version == built.version + 1  # rebuilt once more
    assert nav.runtime(1).version == built.version + 1  # and then cached
