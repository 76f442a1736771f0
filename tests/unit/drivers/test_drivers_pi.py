"""The Raspberry Pi driver on gpiozero's mock pins: motors follow commands, stop when a
command's time-to-live runs out, odometry from encoders or from the commands."""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from gpiozero import Device, RotaryEncoder
from gpiozero.pins.mock import MockFactory, MockPWMPin

from robot_client.drivers import DRIVERS, DriverError
from robot_client.drivers import pi as driver
from robot_client.drivers.base import Camera, Clock, Motors
from robot_client.drivers.watchdog import MotorWatchdog


@pytest.fixture
def pins() -> Iterator[MockFactory]:
    """gpiozero's mock pins (PWM-capable) as the default pin factory."""
    previous = Device.pin_factory
    factory = MockFactory(pin_class=MockPWMPin)
    Device.pin_factory = factory
    yield factory
    factory.reset()
    Device.pin_factory = previous


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    driver.add_arguments(parser)
    return parser.parse_args(list(argv))


def state(factory: MockFactory, *numbers: int) -> list[float]:
    return [float(factory.pin(n).state) for n in numbers]


class FakeClock:
    def __init__(self) -> None:
        self.t = 10.0

    def __call__(self) -> float:
        return self.t


def test_the_registry_names_the_driver() -> None:
    assert DRIVERS["pi"] == "robot_client.drivers.pi"


def test_speeds_map_to_wheel_values_and_back() -> None:
    left, right = driver.wheel_values(0.2, 0.0, wheel_base=0.15, top_speed=0.4)
    assert (left, right) == pytest.approx((0.5, 0.5))
    left, right = driver.wheel_values(0.0, 2.0, wheel_base=0.15, top_speed=0.4)
    assert (left, right) == pytest.approx((-0.375, 0.375))  # turns left on the spot
    left, right = driver.wheel_values(0.6, 1.0, wheel_base=0.2, top_speed=0.4)
    assert max(abs(left), abs(right)) == pytest.approx(1.0)  # full power, not past it
    assert right / left == pytest.approx(0.7 / 0.5)  # the same curve, slower
    v, w = driver.body_velocity(
        *driver.wheel_values(0.1, -0.8, wheel_base=0.15, top_speed=0.4),
        wheel_base=0.15,
        top_speed=0.4,
    )
    assert (v, w) == pytest.approx((0.1, -0.8))


def test_motor_pins_follow_the_commands(pins: MockFactory) -> None:
    motors = driver.open_motors(parse("--pi-top-speed", "0.4", "--pi-wheel-base", "0.15"))
    try:
        assert isinstance(motors, Motors)
        motors.command(0.2, 0.0)  # forward, half power: PWM on the forward pins
        assert state(pins, 4, 14, 17, 18) == pytest.approx([0.5, 0, 0.5, 0])
        motors.command(-0.1, 0.0)  # backward
        assert state(pins, 4, 14, 17, 18) == pytest.approx([0, 0.25, 0, 0.25])
        motors.command(0.0, 2.0)  # on the spot to the left: left wheel back, right forward
        assert state(pins, 4, 14, 17, 18) == pytest.approx([0, 0.375, 0.375, 0])
        motors.stop()
        assert state(pins, 4, 14, 17, 18) == [0, 0, 0, 0]
    finally:
        motors.close()


def test_phase_enable_boards_and_enable_pins(pins: MockFactory) -> None:
    motors = driver.open_motors(parse("--pi-motors", "phase-enable"))
    try:
        motors.command(0.2, 0.0)  # phase low = forward, PWM on enable (pins 12 and 13)
        assert state(pins, 5, 12, 6, 13) == pytest.approx([0, 0.5, 0, 0.5])
        motors.command(-0.2, 0.0)
        assert state(pins, 5, 12, 6, 13) == pytest.approx([1, 0.5, 1, 0.5])
    finally:
        motors.close()
    motors = driver.open_motors(parse("--pi-left", "4,14,25", "--pi-right", "17,18,24"))
    try:
        motors.command(0.2, 0.0)
        assert state(pins, 4, 14, 25, 17, 18, 24) == pytest.approx([0.5, 0, 1, 0.5, 0, 1])
    finally:
        motors.close()


def test_the_pins_fall_to_stop_when_the_time_to_live_runs_out(pins: MockFactory) -> None:
    motors = driver.open_motors(parse())
    dog = MotorWatchdog(motors, poll_s=0.005)
    try:
        dog.command(0.3, 0.5, ttl_s=0.15)
        assert all(s > 0 for s in state(pins, 4, 17))
        time.sleep(0.05)
        assert all(s > 0 for s in state(pins, 4, 17))  # still within its time-to-live
        deadline = time.monotonic() + 2.0
        while dog.driving and time.monotonic() < deadline:
            time.sleep(0.005)
        assert state(pins, 4, 14, 17, 18) == [0, 0, 0, 0]
    finally:
        dog.close()
        motors.close()


def test_odometry_from_the_commands_integrates_what_the_motors_were_set_to() -> None:
    clock = FakeClock()
    robot = _Recorder()
    motors = driver.PiMotors(robot, wheel_base=0.15, top_speed=0.4, clock=clock)
    assert motors.odometry_source == "commands"
    motors.command(0.2, 0.5)
    clock.t += 1.0
    assert motors.odometry() == pytest.approx((0.2, 0.5))
    motors.command(0.3, 0.0)
    clock.t += 0.5
    motors.stop()
    clock.t += 0.5
    assert motors.odometry() == pytest.approx((0.15, 0.0))  # half the time at 0.3, half at rest
    motors.command(2.0, 0.0)  # past full power: the wheels cannot do more than top speed
    clock.t += 1.0
    assert motors.odometry() == pytest.approx((0.4, 0.0))


class _Recorder:
    """A stand-in for gpiozero's Robot (for the clock-driven odometry tests)."""

    def __init__(self) -> None:
        self.value: tuple[float, float] = (0.0, 0.0)

    def stop(self) -> None:
        self.value = (0.0, 0.0)

    def close(self) -> None:
        pass


def turn(factory: MockFactory, a: int, b: int, steps: int) -> None:
    """Drive an encoder's mock pins through ``steps`` full quadrature cycles (negative: the
    other way); the pins are pulled up, so active is low."""
    pa, pb = factory.pin(a), factory.pin(b)
    cycle = [(1, 0), (1, 1), (0, 1), (0, 0)] if steps > 0 else [(0, 1), (1, 1), (1, 0), (0, 0)]
    for _ in range(abs(steps)):
        for av, bv in cycle:
            (pa.drive_low if av else pa.drive_high)()
            (pb.drive_low if bv else pb.drive_high)()


def test_odometry_from_mock_encoder_pins(pins: MockFactory) -> None:
    clock = FakeClock()
    left = RotaryEncoder(20, 21, max_steps=0)
    right = RotaryEncoder(22, 23, max_steps=0)
    motors = driver.PiMotors(
        _Recorder(),
        wheel_base=0.2,
        top_speed=0.4,
        encoders=(left, right),
        steps_per_rev=40,
        wheel_diameter=0.1,
        clock=clock,
    )
    assert motors.odometry_source == "encoders"
    per_step = np.pi * 0.1 / 40
    turn(pins, 20, 21, 30)  # both wheels 30 steps forward in 0.5 s
    turn(pins, 22, 23, 30)
    clock.t += 0.5
    assert motors.odometry() == pytest.approx((30 * per_step / 0.5, 0.0))
    turn(pins, 20, 21, -10)  # on the spot to the left
    turn(pins, 22, 23, 10)
    clock.t += 1.0
    v, w = motors.odometry()
    assert v == pytest.approx(0.0) and w == pytest.approx(20 * per_step / 0.2)
    motors.command(0.3, 0.0)  # a wheel that does not turn counts nothing: no motion
    clock.t += 1.0
    assert motors.odometry() == (0.0, 0.0)
    motors.close()


def test_open_robot_with_encoders_and_a_camera(
    pins: MockFactory, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    video = _video(tmp_path)
    io = driver.open_robot(
        parse(
            "--pi-camera",
            str(video),
            "--pi-left-encoder",
            "20,21",
            "--pi-right-encoder",
            "22,23",
            "--pi-encoder-steps",
            "40",
        )
    )
    try:
        assert isinstance(io.camera, Camera) and isinstance(io.clock, Clock) and io.depth is None
        frame = io.camera.read()
        assert frame is not None and frame.shape == (48, 64, 3)
        io.motors.odometry()
        turn(pins, 20, 21, 40)
        turn(pins, 22, 23, 40)
        v, w = io.motors.odometry()
        assert v > 0 and w == pytest.approx(0.0)  # one revolution forward of both wheels
        assert "odometry from wheel encoders (left (20, 21), right (22, 23), 40 steps" in (
            capsys.readouterr().out
        )
    finally:
        io.close()
    assert state(pins, 4, 14, 17, 18) == [0, 0, 0, 0]


def test_without_encoders_the_driver_says_odometry_comes_from_the_commands(
    pins: MockFactory, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    io = driver.open_robot(parse("--pi-camera", str(_video(tmp_path))))
    io.close()
    out = capsys.readouterr().out
    assert "odometry from the commands (no wheel encoders given" in out


def _video(tmp_path: Path) -> Path:
    path = tmp_path / "camera.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
    for k in range(5):
        writer.write(np.full((48, 64, 3), 40 * k, np.uint8))
    writer.release()
    return path


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--pi-left-encoder", "20,21"], "give both --pi-left-encoder and --pi-right-encoder"),
        (["--pi-wheel-base", "0"], "--pi-wheel-base must be positive"),
        (["--pi-motors", "phase-enable", "--pi-left", "5,12,7"], "takes two pins, phase,enable"),
        (
            ["--pi-left-encoder", "20,21,22", "--pi-right-encoder", "23,24"],
            "--pi-left-encoder takes two pins, A,B",
        ),
    ],
)
def test_bad_options_say_what_to_fix(pins: MockFactory, argv: list[str], message: str) -> None:
    with pytest.raises(DriverError, match=message):
        driver.open_motors(parse(*argv))


def test_pins_that_are_not_gpio_numbers_are_refused_by_the_parser(
    capsys: pytest.CaptureFixture[str],
) -> None:
    for bad in ("4", "4,x", "4,14,15,16", "4,40"):
        with pytest.raises(SystemExit):
            parse("--pi-left", bad)
        assert "BCM GPIO numbers" in capsys.readouterr().err


def test_a_missing_camera_says_how_to_find_one(pins: MockFactory, tmp_path: Path) -> None:
    with pytest.raises(DriverError, match="v4l2-ctl --list-devices"):
        driver.open_robot(parse("--pi-camera", str(tmp_path / "no-such-camera")))
    assert state(pins, 4, 14, 17, 18) == [0, 0, 0, 0]


@pytest.mark.filterwarnings("ignore::gpiozero.PinFactoryFallback")
def test_without_gpio_pins_the_error_says_where_the_driver_runs(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv("GPIOZERO_PIN_FACTORY", raising=False)
    previous: Any = Device.pin_factory
    Device.pin_factory = None
    try:
        try:
            Device._default_pin_factory()
        except Exception:
            pass
        else:
            pytest.skip("this machine has GPIO pins")
        with pytest.raises(DriverError, match=r"gpiozero could not open the pins.*Raspberry Pi"):
            driver.open_motors(parse())
    finally:
        Device.pin_factory = previous
