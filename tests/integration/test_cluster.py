"""``serve --workers 2``: real HAProxy in front of two real server processes on one database.

Affinity (each robot's requests reach one process, two robots on two processes), a process
killed with SIGKILL in the middle of a navigation comes back and its robot carries on, and
several processes opening or writing the same database at once: each on a SQLite file and on a
PostgreSQL database (the ``store`` fixture, tests/conftest.py).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from conftest import assert_stored_in

from robot_client.client import GATEWAY_ERRORS
from server.bench.load_cluster import WORKER_HEADER, cluster_processes
from server.cluster import WorkerAddress, haproxy_config
from server.process import ADMIN, ServerProcess, start_server
from server.storage.repo import Repo

needs_haproxy = pytest.mark.skipif(
    shutil.which("haproxy") is None, reason="HAProxy not installed (scripts/setup-system.sh)"
)
JPEG = {"Content-Type": "image/jpeg"}
PLACES = {0: "entry", 50: "hall", 110: "kitchen"}


@needs_haproxy
def test_the_shipped_configuration_is_valid_haproxy(tmp_path: Path) -> None:
    workers = [WorkerAddress("w0", 18001), WorkerAddress("w1", 18002)]
    config = tmp_path / "haproxy.cfg"
    config.write_text(haproxy_config(host="127.0.0.1", port=18000, workers=workers))
    checked = subprocess.run(["haproxy", "-c", "-f", str(config)], capture_output=True, text=True)
    assert checked.returncode == 0, checked.stderr + checked.stdout
    text = config.read_text()
    assert "server w0 127.0.0.1:18001" in text and "server w1 127.0.0.1:18002" in text
    assert "bind 127.0.0.1:18000" in text and "balance hdr(X-Teachrepeat-Robot)" in text
    settings = [line.split("#")[0] for line in text.splitlines()]
    assert not any(" check" in line or "redispatch" in line for line in settings)
    # nothing logged: a robot's bearer token travels in a header
    assert not any(line.split()[:1] == ["log"] or "httplog" in line for line in settings)


def test_the_configuration_refuses_what_haproxy_could_not_run() -> None:
    with pytest.raises(ValueError, match="at least one"):
        haproxy_config(host="127.0.0.1", port=8000, workers=[])
    with pytest.raises(ValueError, match="must differ"):
        haproxy_config(
            host="127.0.0.1", port=8000, workers=[WorkerAddress("w", 1), WorkerAddress("w", 2)]
        )
    assert "bind ipv6@::1:8000" in haproxy_config(
        host="::1", port=8000, workers=[WorkerAddress("w0", 8001)]
    )


OPEN_AND_WRITE = textwrap.dedent(
    """
    import sys
    from server.storage.repo import Repo
    repo = Repo(sys.argv[1])
    for k in range(int(sys.argv[3])):
        with repo.transaction():
            repo.add_robot(f"{sys.argv[2]}-{k}", f"hash-{sys.argv[2]}-{k}")
    repo.close()
    """
)


def test_processes_migrate_and_write_one_fresh_database_at_once(store: Path | str) -> None:
    """Four processes open a database that is empty or does not exist yet at the same moment
    (each migrates it, or finds it migrated while it waited), then write to it together: they
    take turns (SQLite: WAL and the busy timeout; PostgreSQL: the write lock); nothing fails
    and nothing is lost."""
    db = store
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", OPEN_AND_WRITE, str(db), f"p{i}", "100"],
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(4)
    ]
    for proc in procs:
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 0, err
    repo = Repo(db)
    try:
        assert len(repo.robots()) == 400
        assert repo.integrity_ok()
    finally:
        repo.close()


# --- the cluster --------------------------------------------------------------------------


@pytest.fixture()
def cluster(tmp_path: Path, store: Path | str) -> Iterator[ServerProcess]:
    url = store if isinstance(store, str) else None
    # the silence watchdog (wall clock) waits longer than a killed process takes to come back
    # on a busy machine (its 5 s default failed a task whose process restarted in 6 s)
    quiet = {"TEACHREPEAT_NAVIGATION": '{"frame_timeout_s": 60}'}
    server = start_server(tmp_path / "cluster.sqlite", workers=2, database_url=url, extra_env=quiet)
    yield server
    server.stop()


def _admin() -> dict[str, str]:
    return {"Authorization": f"Bearer {ADMIN}"}


def _teach(http: httpx.Client, frames: list[Path]) -> int:
    """Teach a short corridor tour (every 10th reference frame) through HAProxy."""
    token = http.post("/robots", json={"name": "teacher"}, headers=_admin()).json()["token"]
    auth = {"Authorization": f"Bearer {token}"}
    tour = http.post("/tours", json={"name": "corridor"}, headers=auth).json()["id"]
    assert http.post("/robots/teacher/teach/start", json={"tour": tour}, headers=auth).is_success
    for k, path in enumerate(frames):
        if k % 10 and k not in PLACES:
            continue
        url = "/robots/teacher/frames"
        if k in PLACES:
            r = http.post("/robots/teacher/teach/locations", json={"name": PLACES[k]}, headers=auth)
            assert r.status_code == 200, r.text
            url = "/robots/teacher/teach/spin"
        params = {"timestamp": k / 10, "v": 0.3}
        r = http.post(url, params=params, content=path.read_bytes(), headers={**auth, **JPEG})
        assert r.status_code == 200, r.text
    assert http.post("/robots/teacher/teach/finish", headers=auth).status_code == 200
    return int(tour)


def _frame(
    http: httpx.Client, robot: str, token: str, jpeg: bytes, t: float, *, retries: int = 0
) -> httpx.Response:
    """Post one navigation frame; a lost connection or HAProxy's 502 / 504 (the process died
    with the request) is retried ``retries`` times after 0.5, 1, 2 ... s, as the robot client
    does (TeachRepeatClient backoff)."""
    for attempt in range(retries + 1):
        if attempt:
            time.sleep(0.5 * 2 ** (attempt - 1))
        try:
            r = http.post(
                f"/robots/{robot}/frames",
                params={"timestamp": t, "v": 0.3},
                content=jpeg,
                headers={"Authorization": f"Bearer {token}", **JPEG},
            )
            if r.status_code not in GATEWAY_ERRORS or attempt == retries:
                return r
        except httpx.TransportError:
            if attempt == retries:
                raise
    raise AssertionError("unreachable")


@needs_haproxy
def test_robots_stay_on_their_process_and_one_killed_comes_back(
    cluster: ServerProcess, shared_data: Path
) -> None:
    ref = sorted((shared_data / "corridor" / "ref").glob("*.jpg"))
    query = [p.read_bytes() for p in sorted((shared_data / "corridor" / "query").glob("*.jpg"))]
    with httpx.Client(base_url=cluster.url, timeout=60) as http:
        tour = _teach(http, ref)
        tokens: dict[str, str] = {}
        holder: dict[str, str] = {}
        for i in range(8):  # robots until two are held by different processes
            name = f"r{i}"
            tokens[name] = http.post("/robots", json={"name": name}, headers=_admin()).json()[
                "token"
            ]
            r = http.post(
                f"/robots/{name}/goto",
                json={"location": "kitchen", "tour": tour},
                headers={"Authorization": f"Bearer {tokens[name]}"},
            )
            assert r.status_code == 200, r.text
            holder[name] = r.headers[WORKER_HEADER]
            if len(set(holder.values())) == 2:
                break
        a, b = next(iter(holder)), list(holder)[-1]
        assert holder[a] != holder[b], holder

        # affinity: every frame of each robot is answered by the process that took its goto
        for k in range(6):
            for robot in (a, b):
                r = _frame(http, robot, tokens[robot], query[k], k / 10)
                assert r.status_code == 200, r.text
                assert r.headers[WORKER_HEADER] == holder[robot]
                assert r.json()["task"]["state"] == "underway", r.json()["task"]

        # SIGKILL the process holding b, as a crash would. b's next frame waits for the
        # restart (HAProxy tries the same process again) and b carries on with its task.
        # A request that reaches the process as it dies is lost with it (HAProxy closes the
        # connection unanswered); a robot client sends it again (TeachRepeatClient(retries=
        # ...)), as this test does.
        pids = cluster_processes(cluster.proc.pid)
        os.kill(pids[holder[b]], signal.SIGKILL)
        for k in range(6, 12):
            for robot in (a, b):
                r = _frame(http, robot, tokens[robot], query[k], k / 10, retries=4)
                assert r.status_code == 200, r.text
                assert r.headers[WORKER_HEADER] == holder[robot]
                assert r.json()["task"]["state"] == "underway", r.json()["task"]
        after = cluster_processes(cluster.proc.pid)
        assert after[holder[b]] != pids[holder[b]]  # a new process, same name and port
        assert after[holder[a]] == pids[holder[a]]  # the other one never stopped
        # nothing taught was lost
        shown = http.get(f"/tours/{tour}", headers={"Authorization": f"Bearer {tokens[b]}"})
        assert shown.status_code == 200, shown.text
        places = shown.json()["locations"]
        assert sorted(p["name"] for p in places) == sorted(PLACES.values())
    assert_stored_in(cluster, tour, (3, 2))


# --- two processes, one tour ----------------------------------------------------------------


def test_a_tour_taught_further_in_another_process_is_seen_here(
    store: Path | str, shared_data: Path
) -> None:
    """Two apps on one database file, as two server processes behind HAProxy: a robot held by
    the second navigates a tour, a robot held by the first teaches it a new place, and the
    second sends its robot there (its tour runtime is prepared again, not kept stale)."""
    from fastapi.testclient import TestClient
    from pydantic import SecretStr

    from server.app import create_app
    from server.config import Settings

    where = {"database_url": store} if isinstance(store, str) else {"db": store}
    settings = Settings(**where, admin_token=SecretStr(ADMIN), dashboard_port=None)
    ref = sorted((shared_data / "corridor" / "ref").glob("*.jpg"))
    with (
        TestClient(create_app(settings.model_copy(update={"worker_name": "w0"}))) as first,
        TestClient(create_app(settings.model_copy(update={"worker_name": "w1"}))) as second,
    ):
        teacher = {
            "Authorization": "Bearer "
            + first.post("/robots", json={"name": "teacher"}, headers=_admin()).json()["token"]
        }
        tour = first.post("/tours", json={"name": "corridor"}, headers=teacher).json()["id"]

        def teach(places: dict[int, str], frames: range) -> None:
            first.post("/robots/teacher/teach/start", json={"tour": tour}, headers=teacher)
            for k in frames:
                url = "/robots/teacher/frames"
                if k in places:
                    r = first.post(
                        "/robots/teacher/teach/locations",
                        json={"name": places[k]},
                        headers=teacher,
                    )
                    assert r.status_code == 200, r.text
                    url = "/robots/teacher/teach/spin"
                r = first.post(
                    url,
                    params={"timestamp": k / 10, "v": 0.3},
                    content=ref[k].read_bytes(),
                    headers={**teacher, **JPEG},
                )
                assert r.status_code == 200, r.text
            assert first.post("/robots/teacher/teach/finish", headers=teacher).is_success

        teach({0: "entry", 50: "hall"}, range(0, 51, 5))
        rover = {
            "Authorization": "Bearer "
            + second.post("/robots", json={"name": "rover"}, headers=_admin()).json()["token"]
        }
        r = second.post("/robots/rover/goto", json={"location": "hall"}, headers=rover)
        assert r.status_code == 200 and r.headers[WORKER_HEADER] == "w1", r.text
        teach({50: "hall", 110: "kitchen"}, range(50, 111, 5))
        r = second.post("/robots/rover/goto", json={"location": "kitchen"}, headers=rover)
        assert r.status_code == 200, r.text
        r = second.post(
            "/robots/rover/frames",
            params={"timestamp": 1.0, "v": 0.3},
            content=ref[60].read_bytes(),
            headers={**rover, **JPEG},
        )
        assert r.status_code == 200, r.text
        assert r.json()["task"]["goal"] == "kitchen"
