"""The motor watchdog: a command drives for at most its time-to-live, whatever the loop does."""

from __future__ import annotations

import threading
import time

import pytest

from robot_client.drivers.watchdog import MotorWatchdog


class RecordingMotors:
    """Motors that remember every call with the time it came (a stand-in for hardware)."""

    def __init__(self) -> None:
        self.calls: list[tuple[float, str, float, float]] = []
        self.lock = threading.Lock()

    def command(self, v: float, w: float) -> None:
        with self.lock:
            self.calls.append((time.monotonic(), "command", v, w))

    def stop(self) -> None:
        with self.lock:
            self.calls.append((time.monotonic(), "stop", 0.0, 0.0))

    def odometry(self) -> tuple[float, float]:
        return 0.25, -0.5

    def last(self) -> str:
        with self.lock:
            return self.calls[-1][1]


def test_a_command_stops_by_itself_once_its_time_to_live_has_run_out() -> None:
    motors = RecordingMotors()
    late: list[float] = []
    dog = MotorWatchdog(motors, poll_s=0.005, on_expire=late.append)
    try:
        t0 = time.monotonic()
        dog.command(0.3, 0.1, ttl_s=0.2)
        assert motors.last() == "command" and dog.driving
        time.sleep(0.1)
        assert motors.last() == "command"  # still within its time-to-live
        deadline = time.monotonic() + 2.0
        while dog.driving and time.monotonic() < deadline:
            time.sleep(0.005)
        stopped_at = motors.calls[-1][0]
        assert motors.last() == "stop" and not dog.driving
        assert 0.2 <= stopped_at - t0 <= 0.3
        assert len(late) == 1 and 0 <= late[0] < 0.1
    finally:
        dog.close()


def test_a_newer_command_extends_the_deadline_and_stop_is_at_once() -> None:
    motors = RecordingMotors()
    dog = MotorWatchdog(motors, poll_s=0.005)
    try:
        for _ in range(5):  # commands every 0.1 s with a 0.2 s time-to-live: never stops
            dog.command(0.2, 0.0, ttl_s=0.2)
            time.sleep(0.1)
        assert all(kind == "command" for _, kind, _, _ in motors.calls)
        dog.stop()
        assert motors.last() == "stop" and not dog.driving
        dog.command(0.2, 0.0, ttl_s=0.0)  # nothing to drive on
        assert motors.last() == "stop" and not dog.driving
        assert dog.odometry() == (0.25, -0.5)
    finally:
        dog.close()


def test_close_stops_the_base_and_refuses_to_drive_afterwards() -> None:
    motors = RecordingMotors()
    dog = MotorWatchdog(motors)
    dog.command(0.2, 0.0, ttl_s=10.0)
    dog.close()
    dog.close()
    assert motors.last() == "stop"
    dog.command(0.2, 0.0, ttl_s=10.0)
    assert motors.last() == "stop" and not dog.driving


def test_a_poll_period_must_be_positive() -> None:
    with pytest.raises(ValueError, match="poll_s"):
        MotorWatchdog(RecordingMotors(), poll_s=0)
