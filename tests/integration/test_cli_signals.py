"""A benchmark stopped with SIGTERM stops the scratch server it started (as Ctrl-C does)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest


def _children(pid: int) -> set[int]:
    """Process ids whose parent is ``pid`` (from /proc)."""
    out = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        # field 4 (after the parenthesised command name) is the parent id
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
            out.add(int(entry.name))
    return out


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def test_sigterm_to_a_benchmark_stops_its_scratch_server(shared_data: Path) -> None:
    command = ["bench", "upload", "--data", str(shared_data), "--runs", "1000"]
    bench = subprocess.Popen(
        [sys.executable, "-m", "server.cli", *command],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    children: set[int] = set()
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not children:
            time.sleep(0.2)
            children = {c for c in _children(bench.pid) if _alive(c)}
        assert children, "the benchmark did not start its server"
        time.sleep(1.0)  # let it get going
        bench.send_signal(signal.SIGTERM)
        code = bench.wait(timeout=30)
        assert code == 128 + signal.SIGTERM, bench.stderr.read() if bench.stderr else code
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline and any(_alive(c) for c in children):
            time.sleep(0.1)
        assert not any(_alive(c) for c in children), "the scratch server outlived the benchmark"
    finally:
        if bench.poll() is None:
            bench.kill()
        for c in children | _children(bench.pid):  # (an orphan has left bench's children)
            if _alive(c):
                os.kill(c, signal.SIGKILL)


def test_a_server_interrupted_while_it_starts_is_stopped(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """SIGTERM or Ctrl-C can reach a benchmark while its scratch server is still importing
    (before ``start_server`` returned it to anyone who could stop it): ``start_server`` stops
    it itself instead of leaving an orphan."""
    import server.process as process

    started: list[subprocess.Popen[str]] = []
    real_popen = subprocess.Popen

    def popen(*args: object, **kwargs: object) -> subprocess.Popen[str]:
        proc = real_popen(*args, **kwargs)  # type: ignore[call-overload]
        started.append(proc)
        return proc

    def interrupted(*args: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(process.subprocess, "Popen", popen)
    monkeypatch.setattr(process, "_wait_until_up", interrupted)
    with pytest.raises(KeyboardInterrupt):
        process.start_server(tmp_path / "never.sqlite")
    assert len(started) == 1
    assert started[0].poll() is not None, "the server outlived the interrupted start"
