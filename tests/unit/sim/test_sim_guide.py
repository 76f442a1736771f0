"""The teaching guide walks the plan's route; a recorded tour is the same tour, kept in a file."""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from robot_client.guide import guided_tour_steps, record_tour, rehearse
from robot_client.sim import SimulatedRobot, SimWorld, load_plan
from robot_client.sim.world import Pose
from robot_client.tour_recording import RecordingError, TourRecording

PLAN = Path(__file__).resolve().parents[2] / "data" / "plans" / "two_rooms.json"


@pytest.fixture(scope="module")
def recording() -> TourRecording:
    plan = load_plan(PLAN)
    with SimWorld(plan) as world:
        robot = SimulatedRobot(world, Pose(4.5, 1.0, 0.0), seed=3)
        return record_tour(robot, plan)


def test_the_guide_names_every_place_where_it_stands_and_spins_once() -> None:
    plan = load_plan(PLAN)
    with SimWorld(plan, condition="moved") as world:
        robot = SimulatedRobot(world, Pose(4.5, 1.0, 0.0), seed=4)
        marks, spins = [], {}
        for item in guided_tour_steps(robot, plan):
            if item.kind == "mark":
                p = plan.place(item.place)
                assert math.dist((robot.pose.x, robot.pose.y), (p.x, p.y)) < 0.1
                assert abs(math.remainder(robot.pose.theta - p.yaw, 2 * math.pi)) < 0.05
                marks.append(item.place)
            elif item.kind == "spin":
                spins[item.place] = spins.get(item.place, 0) + 1
    assert marks == ["desk", "sofa", "desk"]  # the derived route: there and back
    assert set(spins) == {"desk", "sofa"} and min(spins.values()) >= 30  # first visits only
    assert robot.blocked_time == 0.0


def test_rehearsal_counts_what_teaching_uploads(recording: TourRecording) -> None:
    walk = rehearse(load_plan(PLAN))
    assert walk.uploads == pytest.approx(recording.images, rel=0.05)
    assert walk.seconds > 30


def test_a_recording_round_trips_through_a_file(recording: TourRecording, tmp_path: Path) -> None:
    path = tmp_path / "tour.npz"
    recording.save(path)
    again = TourRecording.load(path)
    assert again == recording
    assert again.plan_sha256 == load_plan(PLAN).sha256
    assert [s.kind for s in again.steps].count("mark") == 3
    assert all(
        s.jpeg is not None and s.jpeg[:2] == b"\xff\xd8" for s in again.steps if s.kind != "mark"
    )
    # every image carries the simulator's true pose; a mark has none
    assert all((s.pose is None) == (s.kind == "mark") for s in again.steps)


def test_two_writers_of_one_recording_at_once_both_finish(
    recording: TourRecording, tmp_path: Path
) -> None:
    """Two benchmarks walking the same tour into one cache at once: each writes a file of its
    own and renames it; neither finds its temporary file taken away (they shared one name)."""
    path = tmp_path / "cache" / "tour.npz"
    with ThreadPoolExecutor(2) as pool:
        for f in [pool.submit(recording.save, path) for _ in range(4)]:
            f.result()
    assert TourRecording.load(path) == recording
    assert [p.name for p in path.parent.iterdir()] == ["tour.npz"]


def test_a_save_that_fails_leaves_nothing_behind(
    recording: TourRecording, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def full(*args: object, **kwargs: object) -> None:
        raise OSError("No space left on device")

    monkeypatch.setattr(np, "savez", full)
    with pytest.raises(OSError, match="No space"):
        recording.save(tmp_path / "tour.npz")
    assert list(tmp_path.iterdir()) == []


def test_a_recording_of_format_1_reads_without_poses(
    recording: TourRecording, tmp_path: Path
) -> None:
    import json

    path = tmp_path / "tour.npz"
    recording.save(path)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files if k != "pose"}
    header = json.loads(bytes(arrays["header"]).decode())
    arrays["header"] = np.frombuffer(json.dumps({**header, "format": 1}).encode(), np.uint8)
    np.savez(path, **arrays)
    old = TourRecording.load(path)
    assert all(s.pose is None for s in old.steps)
    assert [s.jpeg for s in old.steps] == [s.jpeg for s in recording.steps]


def test_a_file_that_is_not_a_recording_is_refused(tmp_path: Path) -> None:
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not an archive")
    with pytest.raises(RecordingError, match="not a readable tour recording"):
        TourRecording.load(bad)
    with pytest.raises(RecordingError, match="not a readable tour recording"):
        TourRecording.load(tmp_path / "missing.npz")
