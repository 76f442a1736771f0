"""Recordings end to end: a real server recording (``TEACHREPEAT_RECORD``), the simulated home,
the robot client; the files read back with the ``mcap`` package's own reader, and replayed.

One module-scoped run (teach the two-room home, then a short navigation task of
:data:`STEPS` frames) serves every test here.
"""

from __future__ import annotations

import json
import math
import platform
import shutil
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader

from robot_client.client import ApiError, TeachRepeatClient
from robot_client.guide import teach_route
from robot_client.sim import SimulatedRobot, SimWorld, load_plan
from robot_client.sim.world import Pose
from robot_client.trial import run_trial
from server import schemas
from server.cli import main
from server.process import ADMIN, start_server
from server.recording.reader import RecordingError, read_recording
from server.recording.replay import Tolerance, replay
from server.threads import openblas_core

PLAN = Path(__file__).resolve().parents[1] / "data" / "plans" / "two_rooms.json"
STEPS = 30
"""Frames of the recorded navigation task (it need not arrive: it is stopped after them)."""


@dataclass(frozen=True)
class Recorded:
    db: Path
    folder: Path
    task: Path
    teach: Path
    token: str
    steps: int  # frames the server answered for the task
    tour: schemas.TourGraphPublic


def other_numerics() -> dict[str, str]:
    """Environment for a server that sums float32 otherwise than this process: two BLAS
    threads instead of one and, on x86-64, another OpenBLAS kernel than this CPU's (as another
    machine would). Replay in this process must find no difference all the same."""
    env = {"OPENBLAS_NUM_THREADS": "2", "OMP_NUM_THREADS": "2"}
    if platform.machine().lower() in ("x86_64", "amd64"):
        env["OPENBLAS_CORETYPE"] = "Sandybridge" if openblas_core() == "Haswell" else "Haswell"
    return env


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Recorded]:
    tmp = tmp_path_factory.mktemp("recording")
    folder = tmp / "recordings"
    env = {
        "TEACHREPEAT_RECORD": "true",
        "TEACHREPEAT_RECORD_DIR": str(folder),
        **other_numerics(),
    }
    server = start_server(tmp / "rec.sqlite", extra_env=env)
    try:
        with TeachRepeatClient(server.url, ADMIN) as admin:
            token = admin.register_robot("sim").token
        plan = load_plan(PLAN)
        with (
            TeachRepeatClient(server.url, token) as client,
            SimWorld(plan, condition="same", seed=3) as world,
        ):
            robot = SimulatedRobot(world, Pose(1.8, 1.75, math.pi), seed=3)
            tour = teach_route(client, "sim", robot, plan, tour="two rooms")
            robot.teleport(Pose(5.0, 1.2, math.pi / 2))  # carried into the east room
            run_trial(client, "sim", robot, plan, "desk", tour=tour, max_steps=STEPS)
            state = client.state("sim")
            listed = client.recordings("sim")
    finally:
        server.stop()  # finishes every open recording (summary and footer)
    assert state.navigation is not None and state.navigation.task is not None
    by_kind = {r.kind: r for r in listed}
    assert set(by_kind) == {"teach", "navigate"}, listed
    household = folder / "household1"
    yield Recorded(
        db=tmp / "rec.sqlite",
        folder=folder,
        task=household / by_kind["navigate"].name,
        teach=household / by_kind["teach"].name,
        token=token,
        steps=state.navigation.task.steps,
        tour=tour,
    )


def test_a_task_reads_back_with_the_mcap_reader(recorded: Recorded) -> None:
    with open(recorded.task, "rb") as fh:
        reader = make_reader(fh)
        assert reader.get_header().profile == "teachrepeat"
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        channels = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
        assert {t: (s.name, s.encoding) for t, s in channels.items()} == {
            "/tour": ("teachrepeat.Tour", "jsonschema"),
            "/scene": ("foxglove.SceneUpdate", "jsonschema"),
            "/start": ("teachrepeat.Start", "jsonschema"),
            "/task": ("teachrepeat.Task", "jsonschema"),
            "/log": ("foxglove.Log", "jsonschema"),
            "/camera": ("foxglove.CompressedImage", "jsonschema"),
            "/odometry": ("teachrepeat.Odometry", "jsonschema"),
            "/depth": ("foxglove.LaserScan", "jsonschema"),
            "/belief": ("teachrepeat.Belief", "jsonschema"),
            "/votes": ("teachrepeat.Votes", "jsonschema"),
            "/path": ("teachrepeat.Path", "jsonschema"),
            "/command": ("teachrepeat.Command", "jsonschema"),
            "/frame": ("teachrepeat.Frame", "jsonschema"),
        }
        assert all(c.message_encoding == "json" for c in summary.channels.values())
        messages = [(ch.topic, json.loads(m.data)) for _, ch, m in reader.iter_messages()]
    counts = Counter(topic for topic, _ in messages)
    n = recorded.steps
    assert n >= STEPS - 1
    for topic in (
        "/camera",
        "/odometry",
        "/depth",
        "/belief",
        "/votes",
        "/path",
        "/command",
        "/frame",
    ):
        assert counts[topic] == n, (topic, counts)
    assert counts["/tour"] == counts["/start"] == 1 and counts["/task"] == 2
    assert counts["/scene"] == n + 1  # the tour, then the robot at every frame
    start = next(p for t, p in messages if t == "/start")  # a fresh task: from the prior
    assert start == {"resumed": False, "fresh": True, "belief": None, "memory": None}
    tasks = [p for t, p in messages if t == "/task"]
    assert tasks[0]["state"] == "underway" and tasks[-1]["state"] in ("cancelled", "arrived")
    assert [p["index"] for t, p in messages if t == "/frame"] == list(range(n))

    camera = next(p for t, p in messages if t == "/camera")
    assert camera["format"] == "jpeg" and set(camera["timestamp"]) == {"sec", "nsec"}
    import base64

    image = cv2.imdecode(np.frombuffer(base64.b64decode(camera["data"]), np.uint8), 1)
    assert image is not None and image.shape[2] == 3 and image.shape[1] >= 160
    assert float(image.std()) > 10  # a view of the home, not a blank frame
    belief = next(p for t, p in messages if t == "/belief")
    names = {loc.name for loc in recorded.tour.locations}
    assert belief["top"] and {s["name"] for s in belief["top"]} & names
    assert math.isclose(sum(belief["states"]), 1.0, abs_tol=1e-6)
    command = next(p for t, p in messages if t == "/command")
    assert command["behaviour"] and command["action"]
    tour = next(p for t, p in messages if t == "/tour")
    assert [loc["name"] for loc in tour["locations"]] == [
        loc.name for loc in recorded.tour.locations
    ]


def test_teaching_is_recorded_with_its_marks(recorded: Recorded) -> None:
    rec = read_recording(recorded.teach)
    assert rec.kind == "teach" and rec.complete
    spins = [f for f in rec.frames if f.kind == "spin"]
    assert spins and len(rec.frames) > len(spins)
    assert any(text.startswith("marked new place desk") for _, text in rec.logs), rec.logs
    assert rec.logs[-1][1].startswith("teaching finished")


def test_no_token_is_written_into_a_recording(recorded: Recorded) -> None:
    for path in (recorded.task, recorded.teach):
        data = path.read_bytes()
        for secret in (recorded.token, ADMIN):
            assert secret.encode() not in data


def test_replay_finds_no_difference_twice_alike_and_reports_a_changed_setting(
    recorded: Recorded, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    first, second = tmp_path / "first.json", tmp_path / "second.json"
    for out in (first, second):
        assert (
            main(["replay", str(recorded.task), "--db", str(recorded.db), "--json", str(out)]) == 0
        )
    assert first.read_bytes() == second.read_bytes()  # deterministic
    report = json.loads(first.read_text())
    assert report["frames_replayed"] == report["frames_recorded"] == recorded.steps
    assert report["frames_differing"] == 0 and report["differences"] == []
    out = capsys.readouterr()
    assert "no differences" in out.out and "x real time" in out.err

    # recorded on other numerics (other_numerics): to the last bit, only numbers may differ
    # (never an action, an edge, an image, a behaviour or the task's state), and by little
    strict, _ = replay(read_recording(recorded.task), recorded.db, tolerance=Tolerance.strict())
    for frame in strict.differing:
        for d in frame.differences:
            assert isinstance(d.recorded, float) and isinstance(d.replayed, float), d
            assert abs(d.recorded - d.replayed) <= 1e-5 * max(abs(d.recorded), 1e-3), d

    # a slower turn while searching for an edge: the robot starts by searching
    changed, _ = replay(read_recording(recorded.task), recorded.db, settings={"motion.spin_w": 0.1})
    assert changed.settings == {"motion.spin_w": 0.1}
    assert changed.differing, "turning slower changed no command"
    first = changed.differing[0]
    assert any(d.path == "command.w" and d.replayed == 0.1 for d in first.differences), first


def test_a_truncated_file_is_refused_clearly_and_its_whole_frames_replay(
    recorded: Recorded, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = recorded.task.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    assert main(["replay", str(cut), "--db", str(recorded.db)]) == 2
    err = capsys.readouterr().err
    assert "cut.mcap is truncated" in err and "--partial" in err, err
    rec = read_recording(cut)
    assert not rec.complete and 0 < len(rec.frames) < recorded.steps
    report, _ = replay(rec, recorded.db, partial=True)
    assert report.frames_replayed == len(rec.frames) and not report.differing


def test_files_that_cannot_be_replayed_say_why(recorded: Recorded, tmp_path: Path) -> None:
    text = tmp_path / "notes.mcap"
    text.write_text("not a recording")
    with pytest.raises(RecordingError, match="is not an MCAP file"):
        read_recording(text)
    with pytest.raises(RecordingError, match="records a teaching tour"):
        replay(read_recording(recorded.teach), recorded.db)
    # another database, with another tour under the same id
    other = tmp_path / "other.sqlite"
    from server.storage.repo import Repo

    repo = Repo(other)
    repo.add_tour("two rooms")
    repo.close()
    with pytest.raises(RecordingError, match=r"recorded against tour 1 'two rooms'.*--db"):
        replay(read_recording(recorded.task), other)
    with pytest.raises(RecordingError, match="no database at"):
        replay(read_recording(recorded.task), tmp_path / "missing.sqlite")


def test_the_api_serves_a_robots_recording_to_it_only(recorded: Recorded, tmp_path: Path) -> None:
    """Against a restarted server on the same database and recordings folder."""
    env = {"TEACHREPEAT_RECORD_DIR": str(recorded.folder)}
    db = tmp_path / "again.sqlite"
    shutil.copy(recorded.db, db)
    server = start_server(db, extra_env=env)
    try:
        with TeachRepeatClient(server.url, recorded.token) as client:
            listed = client.recordings("sim")
            names = {r.name for r in listed}
            assert names == {recorded.task.name, recorded.teach.name}
            assert all(not r.recording and r.size_bytes > 1000 for r in listed)
            assert client.recording("sim", recorded.task.name) == recorded.task.read_bytes()
            with pytest.raises(ApiError) as missing:
                client.recording("sim", "sim.tour1.20260101-000000.task99.mcap")
            assert missing.value.status == 404
        with TeachRepeatClient(server.url, ADMIN) as admin:
            other = admin.register_robot("other").token
        with TeachRepeatClient(server.url, other) as client, pytest.raises(ApiError) as denied:
            client.recording("sim", recorded.task.name)
        assert denied.value.status == 403
    finally:
        server.stop()
