"""``teachrepeat robot run`` against a real HTTPS server: pinned to its certificate it drives;
pinned to another one it ends before the token is sent, saying so."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from robot_client.agent import AgentParams, run_agent
from robot_client.client import TeachRepeatClient
from server.bench.teleop import FakeBase
from server.cert import CertPair, write_pair
from server.process import ServerProcess, start_server

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory) -> CertPair:
    return write_pair(tmp_path_factory.mktemp("home"), ["teachrepeat-hub.local"])


@pytest.fixture(scope="module")
def server(pair: CertPair, tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    proc = start_server(tmp_path_factory.mktemp("db") / "tls.sqlite", tls=(pair.cert, pair.key))
    yield proc
    proc.stop()


def test_the_agent_pinned_to_the_servers_fingerprint_streams(
    server: ServerProcess, pair: CertPair
) -> None:
    token = server.register_robot("pinned")
    io, motors = FakeBase().io()
    lines: list[str] = []
    stopping = threading.Event()
    thread = threading.Thread(
        target=run_agent,
        args=(server.url, token, io, AgentParams()),
        kwargs={"fingerprint": pair.fingerprint, "log": lines.append, "stopping": stopping},
        daemon=True,
    )
    thread.start()
    try:
        with TeachRepeatClient(server.url, token, ca_cert=pair.cert) as client:
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline:
                control = client.state("pinned").control
                if control is not None and control.connected:
                    break
                time.sleep(0.1)
            client.teleop("pinned", 0.2, 0.0, ttl_s=1.0)
            motors.wait(lambda c: c.v == 0.2, 0, 5.0)
    finally:
        stopping.set()
        thread.join(timeout=10)
    assert lines[0].startswith("robot 'pinned' on https://"), lines


def test_the_agent_pinned_to_another_certificate_ends_before_sending_the_token(
    server: ServerProcess, tmp_path: Path
) -> None:
    other = write_pair(tmp_path, ["teachrepeat-hub.local"])
    token = server.register_robot("elsewhere")
    token_file = tmp_path / "token"
    token_file.write_text(token + "\n")
    token_file.chmod(0o600)
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "server.cli",
            "robot",
            "run",
            "--server",
            server.url,
            "--token-file",
            str(token_file),
            "--fingerprint",
            other.fingerprint,
            "--driver",
            "sim",
            "--sim-plan",
            str(ROOT / "tests" / "data" / "plans" / "two_rooms.json"),
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert done.returncode == 1, done.stderr
    assert "the server's certificate is not the pinned one" in done.stderr
    assert "Nothing was sent" in done.stderr and token not in done.stderr + done.stdout
