"""Through a real uvicorn server: teaching real frames, and a SIGKILL in the middle of a tour;
on a SQLite file and on a PostgreSQL database (the ``store`` fixture, tests/conftest.py)."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import assert_stored_in, make_jpeg, serve_exits_2

from robot_client.client import TeachRepeatClient
from robot_client.teach import read_marks, teach_folder
from server.cluster import free_port
from server.process import ADMIN, ServerProcess, start_server
from server.storage.repo import Repo


@pytest.fixture()
def server(tmp_path: Path, store: Path | str) -> Iterator[ServerProcess]:
    url = store if isinstance(store, str) else None
    proc = start_server(tmp_path / "live.sqlite", database_url=url)
    yield proc
    proc.stop()


def robot_client(server: ServerProcess, name: str = "rover") -> TeachRepeatClient:
    with TeachRepeatClient(server.url, ADMIN) as admin:
        token = admin.register_robot(name).token
    return TeachRepeatClient(server.url, token, retries=3)


def test_teach_the_real_corridor_frames(
    server: ServerProcess, shared_data: Path, tmp_path: Path
) -> None:
    marks_file = tmp_path / "marks.csv"
    marks_file.write_text("frame,place\n0,entry\n36,hall\n73,office\n110,kitchen\n")
    with robot_client(server) as client:
        report = teach_folder(
            client,
            tour="corridor",
            frames=shared_data / "corridor" / "ref",
            marks=read_marks(marks_file),
            fps=10.0,
            progress=False,
        )
        graph = client.tour(report.tour.id)
    assert report.uploaded == 111
    assert [loc.name for loc in graph.locations] == ["entry", "hall", "office", "kitchen"]
    assert [loc.image_count for loc in graph.locations] == [1, 1, 1, 1]
    # the frames strictly between two marks form the edge: 1..35, 37..72, 74..109
    edges = [(e.source_name, e.target_name, e.image_count, e.duration_s) for e in graph.edges]
    assert edges == [
        ("entry", "hall", 35, pytest.approx(3.4)),
        ("hall", "office", 36, pytest.approx(3.5)),
        ("office", "kitchen", 36, pytest.approx(3.5)),
    ]
    assert_stored_in(server, report.tour.id, (4, 3))


def test_serve_says_when_postgresql_cannot_be_reached_without_the_password(
    tmp_path: Path,
) -> None:
    url = f"postgresql://teachrepeat:pw-never-shown@127.0.0.1:{free_port()}/home"
    done = serve_exits_2(tmp_path / "t.sqlite", env={"TEACHREPEAT_DATABASE_URL": url})
    assert "cannot connect to the database server postgresql://teachrepeat:***@127.0.0.1" in (
        done.stderr
    )
    assert "pw-never-shown" not in done.stdout + done.stderr


def test_sigkill_during_teaching_leaves_a_consistent_file(server: ServerProcess) -> None:
    client = robot_client(server)
    token = client._http.headers["Authorization"].split(" ", 1)[1]
    client.retries = 0
    tour = client.create_tour("crashy")
    client.start_teaching("rover", tour.id)
    client.mark_location("rover", "a")
    client.upload_spin_image("rover", make_jpeg(99), timestamp=0.0)  # the first place's image
    t = 0.0
    for k in range(5):
        t += 0.1
        client.upload_frame("rover", make_jpeg(k), timestamp=t)
    client.mark_location("rover", "b")
    for k in range(3):
        t += 0.1
        client.upload_frame("rover", make_jpeg(k), timestamp=t)

    # keep marking and uploading from another thread while the server dies
    stop = threading.Event()

    def hammer() -> None:
        n = 0
        while not stop.is_set():
            n += 1
            try:
                client.upload_frame("rover", make_jpeg(n), timestamp=t + n)
                client.upload_frame("rover", make_jpeg(n + 1), timestamp=t + n + 0.5)
                client.mark_location("rover", f"p{n % 3}")
            except Exception:  # the server is being killed
                return

    worker = threading.Thread(target=hammer)
    worker.start()
    threading.Event().wait(0.3)
    server.kill()
    stop.set()
    worker.join(timeout=10)
    client.close()

    repo = Repo(server.database())
    assert repo.integrity_ok()
    assert repo.short_edges() == []
    graph = repo.graph(tour.id)
    assert graph.n_edges >= 1
    assert all(e.n_images >= 2 for e in graph.edges)
    repo.close()

    # restart on the same file: teaching goes on where the file says it was
    again = start_server(server.db, database_url=server.database_url)
    try:
        with TeachRepeatClient(again.url, token) as robot:  # itself, after the restart
            state = robot.state("rover")
            assert state.mode == "teaching"
            pending = state.teaching.open_path_images if state.teaching else -1
            last = state.teaching.last_timestamp if state.teaching else None
            ts = (last or 0.0) + 1.0
            for k in range(2):
                robot.upload_frame("rover", make_jpeg(k), timestamp=ts + k)
            marked = robot.mark_location("rover", "after-crash")
            assert marked.edge is not None and marked.edge.image_count == pending + 2
            robot.finish_teaching("rover")
    finally:
        again.stop()
