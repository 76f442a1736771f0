"""Recording files: a crash leaves every whole frame readable; names, listings and retention."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from conftest import make_jpeg

from server import schemas
from server.errors import NotFound
from server.recording import topics
from server.recording.mcapfile import McapFile
from server.recording.messages import log_message, teaching_frame
from server.recording.reader import read_recording
from server.recording.store import RecordingStore, Retention


def write_frames(path: Path, n: int) -> tuple[McapFile, list[int]]:
    """An open recording of ``n`` teaching frames; the file size after each whole frame."""
    f = McapFile(path, metadata={"kind": "teach", "robot": "rover", "tour": "1"}, max_bytes=1 << 30)
    f.write(topics.TOUR, {"id": 1, "name": "home", "fingerprint": "x"}, 1)
    ends = []
    for k in range(n):
        meta = schemas.FrameMeta(timestamp=0.1 * k, v=0.2, w=0.0)
        for topic, payload in teaching_frame(
            make_jpeg(k), meta, index=k, wall=1.0 + k, spin=False, depth_fov_deg=90
        ):
            f.write(topic, payload, 10 + k)
        f.end_frame()
        ends.append(f.size)
    return f, ends


def test_a_file_cut_anywhere_reads_up_to_its_last_whole_frame(tmp_path: Path) -> None:
    path = tmp_path / "rover.tour1.20261126-101502.teach.mcap"
    f, ends = write_frames(path, 6)
    data = path.read_bytes()  # as a killed server leaves it: flushed, never closed
    f.close()
    alive = read_recording(path)
    assert alive.complete and len(alive.frames) == 6
    cut_file = tmp_path / "cut.mcap"
    for cut in range(ends[0] - 40, len(data) + 1, 7):
        cut_file.write_bytes(data[:cut])
        rec = read_recording(cut_file)
        whole = sum(end <= cut for end in ends)
        assert not rec.complete and len(rec.frames) == whole, cut
        assert [fr.index for fr in rec.frames] == list(range(whole))
        assert rec.cut_at is not None and rec.cut_at <= cut
    frame = alive.frames[3]
    assert frame.jpeg == make_jpeg(3) and frame.v == 0.2 and frame.kind == "path"


def test_the_file_reports_when_it_reaches_its_size_limit(tmp_path: Path) -> None:
    f = McapFile(tmp_path / "a.mcap", metadata={"kind": "teach"}, max_bytes=3000)
    assert not f.full()
    topic, payload = log_message(1.0, "rover", "x" * 4000)
    f.write(topic, payload, 1)
    f.end_frame()
    assert f.full()
    f.close()
    f.close()  # twice is fine


def touch(path: Path, size: int, mtime: float) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"\0" * size)
    os.utime(path, (mtime, mtime))
    return path


def test_names_say_robot_tour_time_and_task_and_never_repeat(tmp_path: Path) -> None:
    store = RecordingStore(tmp_path)
    at = 1_795_680_000.0  # 2026-11-26 08:00:00 UTC
    first = store.new_path(2, "rover", 3, 17, at)
    again = store.new_path(2, "rover", 3, 17, at)
    teach = store.new_path(2, "rover", 3, None, at)
    assert first == tmp_path / "household2" / "rover.tour3.20261126-080000.task17.mcap"
    assert again.name == "rover.tour3.20261126-080000-1.task17.mcap"
    assert teach.name == "rover.tour3.20261126-080000.teach.mcap"
    store.new_path(2, "rover-2", 3, 18, at + 5)
    listed = store.files(2, robot="rover")
    assert {r.name for r in listed} == {first.name, again.name, teach.name}
    assert all(r.robot == "rover" and r.tour == 3 and r.started_at == at for r in listed)
    assert {r.task for r in listed} == {17, None}
    assert store.files(2)[0].name == "rover-2.tour3.20261126-080005.task18.mcap"
    assert store.files(1) == [] and len(store.files()) == 4


def test_find_answers_only_the_robots_own_recordings(tmp_path: Path) -> None:
    store = RecordingStore(tmp_path)
    mine = store.new_path(1, "rover", 1, 4, 1_795_680_000.0)
    store.new_path(2, "scout", 1, 5, 1_795_680_000.0)
    assert store.find(1, "rover", mine.name).path == mine
    for household, robot, name in (
        (2, "rover", mine.name),  # another household's folder
        (1, "scout", mine.name),  # another robot's name
        (1, "rover", "../household2/scout.tour1.20261126-080000.task5.mcap"),
        (1, "rover", "rover.tour1.20261126-080000.task9.mcap"),  # no such file
    ):
        with pytest.raises(NotFound):
            store.find(household, robot, name)


def test_retention_deletes_the_oldest_finished_recordings_first(tmp_path: Path) -> None:
    store = RecordingStore(tmp_path, Retention(keep_files=3, keep_bytes=1000, file_bytes=10))
    folder = tmp_path / "household1"
    paths = [
        touch(folder / f"rover.tour1.20261116-0640{k:02d}.task{k}.mcap", 300, 1000.0 + k)
        for k in range(5)
    ]
    other = touch(tmp_path / "household2" / "bob.tour2.20261116-064010.task9.mcap", 300, 999.0)
    deleted = store.enforce(open_paths={other})  # the oldest, but being written
    assert deleted == [paths[0], paths[1], paths[2]]
    assert sorted(p.name for p in tmp_path.rglob("*.mcap")) == sorted(
        [paths[3].name, paths[4].name, other.name]
    )
    # bytes: 900 kept of 1000; one more file of 300 bytes makes it 1200
    touch(folder / "rover.tour1.20261116-064100.task7.mcap", 300, 2000.0)
    assert store.enforce() == [other]
