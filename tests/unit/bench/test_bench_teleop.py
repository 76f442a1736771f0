"""The teleop benchmark's instruments: motors that note each change of command, and the
wall-clock robot that stands for hardware we do not have."""

from __future__ import annotations

import threading
import time

import pytest

from server.bench.teleop import FakeBase, RecordingMotors, fmt, turning_at, turning_toward


def test_recording_motors_note_changes_only_and_pass_them_on() -> None:
    base = FakeBase()
    motors = RecordingMotors(base)
    motors.command(0.2, 0.0)
    motors.command(0.2, 0.0)  # no change
    motors.command(0.0, -0.5)
    motors.stop()
    motors.stop()
    assert [(c.v, c.w) for c in motors.changes] == [(0.2, 0.0), (0.0, -0.5), (0.0, 0.0)]
    assert (base.v, base.w) == (0.0, 0.0) and motors.odometry() == (0.0, 0.0)
    times = [c.at for c in motors.changes]
    assert times == sorted(times)


def test_waiting_for_a_change_finds_it_after_an_index_or_times_out() -> None:
    motors = RecordingMotors(FakeBase())
    motors.command(0.0, 0.5)
    threading.Timer(0.05, lambda: motors.command(0.0, -0.5)).start()
    found = motors.wait(turning_at(-0.5), 1, 2.0)
    assert found.w == -0.5
    assert motors.wait(turning_toward(1.0), 0, 0.1).w == 0.5
    started = time.monotonic()
    with pytest.raises(TimeoutError):
        motors.wait(turning_toward(1.0), 2, 0.1)
    assert time.monotonic() - started >= 0.1


def test_the_fake_base_is_a_wall_clock_robot_with_a_frame() -> None:
    io, motors = FakeBase().io()
    assert not io.simulated and io.motors is motors
    frame = io.camera.read()
    assert frame is not None and frame.shape == (240, 320, 3) and frame.std() > 30
    t0 = io.clock.now()
    io.clock.sleep(0.02)
    assert io.clock.now() - t0 >= 0.02


def test_figures_are_printed_with_their_count() -> None:
    line = fmt({"p50": 41.9, "p95": 170.1, "p99": 200.0, "mean": 50.0, "n": 40, "max": 210.0})
    assert line == "p50 42 ms, p95 170 ms, max 210 (n=40)"
