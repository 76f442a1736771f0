"""The ``pi`` driver: a Raspberry Pi with a USB camera and two motors, through gpiozero.

* camera: a USB (V4L2) camera through OpenCV (:class:`~.cameras.OpenCVCamera`);
* motors: two motors on a driver board, as gpiozero's ``Robot`` drives them: ``Motor``
  (forward and backward pins, an optional enable pin; L298N, L9110S, TB6612FNG...) or
  ``PhaseEnableMotor`` (phase and enable pins; DRV8835, Pololu boards); a command ``(v, w)``
  becomes wheel speeds ``v -/+ w * wheel_base / 2``, as fractions of ``--pi-top-speed``
  (scaled down together when one would pass full power, so the robot keeps the curve);
* odometry: from wheel encoders when both are given (gpiozero ``RotaryEncoder``, counts per
  wheel revolution and wheel diameter as options), else from the commands themselves, which a
  blocked or slipping wheel does not change (the driver says which at start);
* clock: this computer's monotonic clock.

gpiozero is imported inside :func:`open_robot`. Tests set ``gpiozero.Device.pin_factory`` to
its ``MockFactory`` and drive every part of this module without a Pi.
"""

from __future__ import annotations

import argparse
import math
import threading
import time
from collections.abc import Callable
from typing import Any

from robot_client.drivers import DriverError
from robot_client.drivers.base import RobotIO
from robot_client.drivers.clock import WallClock

BOARDS = {
    "robot": ((4, 14), (17, 18)),
    "phase-enable": ((5, 12), (6, 13)),
}
"""``--pi-motors`` kind -> its default (left, right) pins: gpiozero's own examples
(``Robot(left=Motor(4, 14), right=Motor(17, 18))``; ``PhaseEnableRobot(left=(5, 12),
right=(6, 13))``, the pins of Pololu's DRV8835 board)."""


def wheel_values(v: float, w: float, *, wheel_base: float, top_speed: float) -> tuple[float, float]:
    """The ``(left, right)`` motor values in [-1, 1] that drive at ``v`` m/s and ``w`` rad/s.

    A wheel's speed is ``v -/+ w * wheel_base / 2`` m/s and its value that over ``top_speed``
    (a wheel's speed at full power); when one value would pass 1, both shrink by the same
    factor, so the robot drives the same curve, slower.
    """
    left = (v - w * wheel_base / 2) / top_speed
    right = (v + w * wheel_base / 2) / top_speed
    scale = max(1.0, abs(left), abs(right))
    return left / scale, right / scale


def body_velocity(
    left: float, right: float, *, wheel_base: float, top_speed: float
) -> tuple[float, float]:
    """The ``(v, w)`` that motor values ``(left, right)`` drive at (:func:`wheel_values`'
    inverse within full power)."""
    vl, vr = left * top_speed, right * top_speed
    return (vl + vr) / 2, (vr - vl) / wheel_base


class CommandOdometry:
    """Odometry from the motor values set, integrated over time: what the robot was told,
    not what it did (no encoders)."""

    def __init__(self, *, wheel_base: float, top_speed: float, clock: Callable[[], float]):
        self.wheel_base = wheel_base
        self.top_speed = top_speed
        self.clock = clock
        self._lock = threading.Lock()
        self._values = (0.0, 0.0)
        self._since = clock()
        self._t0 = self._since
        self._dist = 0.0
        self._turn = 0.0

    def _advance(self, now: float) -> None:
        v, w = body_velocity(*self._values, wheel_base=self.wheel_base, top_speed=self.top_speed)
        dt = now - self._since
        self._dist += v * dt
        self._turn += w * dt
        self._since = now

    def set(self, left: float, right: float) -> None:
        """The motors were just set to ``(left, right)``."""
        with self._lock:
            self._advance(self.clock())
            self._values = (left, right)

    def mean(self) -> tuple[float, float]:
        """Mean ``(v, w)`` since the last call."""
        with self._lock:
            now = self.clock()
            self._advance(now)
            elapsed = now - self._t0
            dist, turn = self._dist, self._turn
            self._dist = self._turn = 0.0
            self._t0 = now
        return (dist / elapsed, turn / elapsed) if elapsed > 0 else (0.0, 0.0)


class EncoderOdometry:
    """Odometry from two wheel encoders' step counts (gpiozero ``RotaryEncoder.steps``).

    Args:
        left, right: objects with a ``steps`` count, rising when the wheel drives forward.
        steps_per_rev: steps per wheel revolution. wheel_diameter: metres.
        wheel_base: metres between the wheels. clock: monotonic seconds.
    """

    def __init__(
        self,
        left: Any,
        right: Any,
        *,
        steps_per_rev: float,
        wheel_diameter: float,
        wheel_base: float,
        clock: Callable[[], float],
    ) -> None:
        self.left = left
        self.right = right
        self.metres_per_step = math.pi * wheel_diameter / steps_per_rev
        self.wheel_base = wheel_base
        self.clock = clock
        self._lock = threading.Lock()
        self._last = (int(left.steps), int(right.steps), clock())

    def mean(self) -> tuple[float, float]:
        """Mean ``(v, w)`` since the last call, from the steps counted meanwhile."""
        with self._lock:
            sl, sr, now = int(self.left.steps), int(self.right.steps), self.clock()
            pl, pr, then = self._last
            self._last = (sl, sr, now)
        elapsed = now - then
        if elapsed <= 0:
            return 0.0, 0.0
        dl = (sl - pl) * self.metres_per_step
        dr = (sr - pr) * self.metres_per_step
        return (dl + dr) / 2 / elapsed, (dr - dl) / self.wheel_base / elapsed


class PiMotors:
    """Two motors as ``Motors``: gpiozero's ``Robot`` (anything with ``value`` ``(left,
    right)`` and ``stop()``), and odometry from encoders or from the commands.

    Args:
        robot: the two motors.
        wheel_base: metres between the wheels. top_speed: a wheel's m/s at full power.
        encoders: ``(left, right)`` ``RotaryEncoder``s, or ``None``: odometry from commands.
        steps_per_rev, wheel_diameter: the encoders' steps per wheel revolution, metres.
        clock: monotonic seconds.
    """

    def __init__(
        self,
        robot: Any,
        *,
        wheel_base: float,
        top_speed: float,
        encoders: tuple[Any, Any] | None = None,
        steps_per_rev: float = 1.0,
        wheel_diameter: float = 0.065,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.robot = robot
        self.wheel_base = wheel_base
        self.top_speed = top_speed
        self.encoders = encoders
        self._commands = CommandOdometry(wheel_base=wheel_base, top_speed=top_speed, clock=clock)
        self._odometry: CommandOdometry | EncoderOdometry = self._commands
        if encoders is not None:
            self._odometry = EncoderOdometry(
                *encoders,
                steps_per_rev=steps_per_rev,
                wheel_diameter=wheel_diameter,
                wheel_base=wheel_base,
                clock=clock,
            )
        self._lock = threading.Lock()
        self._closed = False

    @property
    def odometry_source(self) -> str:
        """``"encoders"`` or ``"commands"``."""
        return "encoders" if self.encoders is not None else "commands"

    def command(self, v: float, w: float) -> None:
        values = wheel_values(v, w, wheel_base=self.wheel_base, top_speed=self.top_speed)
        with self._lock:
            if self._closed:
                return
            self.robot.value = values
            self._commands.set(*values)

    def odometry(self) -> tuple[float, float]:
        return self._odometry.mean()

    def stop(self) -> None:
        with self._lock:
            if self._closed:
                return
            self.robot.stop()
            self._commands.set(0.0, 0.0)

    def close(self) -> None:
        """Stop and release the pins. Safe to call twice."""
        self.stop()
        with self._lock:
            if self._closed:
                return
            self._closed = True
        for device in (self.robot, *(self.encoders or ())):
            device.close()


def _pins(text: str) -> tuple[int, ...]:
    try:
        pins = tuple(int(p) for p in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: give BCM GPIO numbers separated by commas, such as 4,14"
        ) from None
    if not 2 <= len(pins) <= 3 or any(not 0 <= p <= 27 for p in pins):
        raise argparse.ArgumentTypeError(
            f"{text!r}: give 2 or 3 BCM GPIO numbers from 0 to 27, such as 4,14"
        )
    return pins


def _camera(text: str) -> int | str:
    return int(text) if text.isdigit() else text


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``--pi-*`` options (see docs/robot.md, "Raspberry Pi robot")."""
    g = parser.add_argument_group(
        "pi driver (--driver pi): a Raspberry Pi, a USB camera and two motors (gpiozero)"
    )
    g.add_argument(
        "--pi-camera",
        type=_camera,
        default=0,
        metavar="INDEX|PATH",
        help="camera: V4L2 device index (0: /dev/video0) or path (default 0)",
    )
    g.add_argument("--pi-width", type=int, default=320, help="capture width, px (default 320)")
    g.add_argument("--pi-height", type=int, default=240, help="capture height, px (default 240)")
    g.add_argument(
        "--pi-motors",
        choices=tuple(BOARDS),
        default="robot",
        help="robot: each motor on forward,backward[,enable] pins (gpiozero Motor); "
        "phase-enable: on phase,enable pins (PhaseEnableMotor); default robot",
    )
    g.add_argument(
        "--pi-left",
        type=_pins,
        default=None,
        metavar="PINS",
        help="left motor's BCM pins (default 4,14 for robot, 5,12 for phase-enable); swap "
        "forward and backward if the wheel turns the wrong way",
    )
    g.add_argument(
        "--pi-right",
        type=_pins,
        default=None,
        metavar="PINS",
        help="right motor's BCM pins (default 17,18 for robot, 6,13 for phase-enable)",
    )
    g.add_argument(
        "--pi-wheel-base",
        type=float,
        default=0.15,
        metavar="M",
        help="distance between the wheels' contact points, metres (default 0.15)",
    )
    g.add_argument(
        "--pi-top-speed",
        type=float,
        default=0.4,
        metavar="M/S",
        help="a wheel's speed at full power, m/s (default 0.4; measure it)",
    )
    g.add_argument(
        "--pi-left-encoder",
        type=_pins,
        default=None,
        metavar="A,B",
        help="left wheel encoder's A,B pins (with --pi-right-encoder: odometry from the "
        "wheels; without: from the commands)",
    )
    g.add_argument(
        "--pi-right-encoder", type=_pins, default=None, metavar="A,B", help="right encoder's A,B"
    )
    g.add_argument(
        "--pi-encoder-steps",
        type=float,
        default=20.0,
        metavar="N",
        help="encoder steps (full A/B cycles) per wheel revolution (default 20)",
    )
    g.add_argument(
        "--pi-wheel-diameter",
        type=float,
        default=0.065,
        metavar="M",
        help="wheel diameter, metres (default 0.065)",
    )


def _check(args: argparse.Namespace) -> None:
    for name in ("pi_wheel_base", "pi_top_speed", "pi_encoder_steps", "pi_wheel_diameter"):
        if getattr(args, name) <= 0:
            raise DriverError(f"--{name.replace('_', '-')} must be positive")
    if (args.pi_left_encoder is None) != (args.pi_right_encoder is None):
        raise DriverError("give both --pi-left-encoder and --pi-right-encoder, or neither")
    for name in ("pi_left_encoder", "pi_right_encoder"):
        pins = getattr(args, name)
        if pins is not None and len(pins) != 2:
            raise DriverError(f"--{name.replace('_', '-')} takes two pins, A,B")
    if args.pi_motors == "phase-enable":
        for name in ("pi_left", "pi_right"):
            pins = getattr(args, name)
            if pins is not None and len(pins) != 2:
                raise DriverError(f"--{name.replace('_', '-')} takes two pins, phase,enable")


def open_motors(args: argparse.Namespace) -> PiMotors:
    """The motors (and encoders) the ``--pi-*`` options describe, on gpiozero's pin factory
    (``gpiozero.Device.pin_factory``, or the one ``GPIOZERO_PIN_FACTORY`` names).

    Raises:
        DriverError: gpiozero missing, no GPIO here, a pin in use or a bad option.
    """
    _check(args)
    try:
        import gpiozero
        from gpiozero import Motor, PhaseEnableMotor, Robot, RotaryEncoder
    except ImportError as exc:
        raise DriverError(
            f"the pi driver needs gpiozero ({exc}): pip install 'teachrepeat[pi]' "
            "(docs/robot.md, 'Install on the robot')"
        ) from None
    default_left, default_right = BOARDS[args.pi_motors]
    left_pins: tuple[int, ...] = args.pi_left or default_left
    right_pins: tuple[int, ...] = args.pi_right or default_right
    opened: list[Any] = []
    try:
        if args.pi_motors == "phase-enable":
            left: Any = PhaseEnableMotor(*left_pins)
            opened.append(left)
            right: Any = PhaseEnableMotor(*right_pins)
        else:
            left = Motor(*left_pins[:2], enable=left_pins[2] if len(left_pins) > 2 else None)
            opened.append(left)
            right = Motor(*right_pins[:2], enable=right_pins[2] if len(right_pins) > 2 else None)
        opened.append(right)
        robot = Robot(left=left, right=right)
        opened.append(robot)
        encoders = None
        if args.pi_left_encoder is not None:
            le = RotaryEncoder(*args.pi_left_encoder, max_steps=0)
            opened.append(le)
            re_ = RotaryEncoder(*args.pi_right_encoder, max_steps=0)
            opened.append(re_)
            encoders = (le, re_)
    except gpiozero.GPIOZeroError as exc:
        for device in reversed(opened):
            device.close()
        raise DriverError(
            f"gpiozero could not open the pins ({type(exc).__name__}: {exc}). On a Raspberry "
            "Pi: is another program using them, are the numbers BCM GPIO numbers, is a pin "
            "library there (python3-lgpio; docs/robot.md, 'Raspberry Pi robot')? Elsewhere "
            "there are no GPIO pins to drive"
        ) from None
    return PiMotors(
        robot,
        wheel_base=args.pi_wheel_base,
        top_speed=args.pi_top_speed,
        encoders=encoders,
        steps_per_rev=args.pi_encoder_steps,
        wheel_diameter=args.pi_wheel_diameter,
    )


def open_robot(args: argparse.Namespace) -> RobotIO:
    """The Pi's camera and motors (no depth sensor).

    Raises:
        DriverError: the camera does not open or gives no frame, or the motors cannot be
            opened (see :func:`open_motors`).
    """
    from robot_client.drivers.cameras import OpenCVCamera

    motors = open_motors(args)
    closers: list[Callable[[], None]] = [motors.close]
    try:
        camera = OpenCVCamera(args.pi_camera, width=args.pi_width, height=args.pi_height)
    except OSError as exc:
        motors.close()
        raise DriverError(
            f"{exc}: `v4l2-ctl --list-devices` (package v4l-utils) lists the cameras; the user "
            "needs to be in the video group"
        ) from None
    closers.append(camera.close)
    first = camera.read()
    if first is None:
        for close in reversed(closers):
            close()
        raise DriverError(
            f"camera {args.pi_camera!r} opened but gave no frame: is another program using it?"
        )
    source = (
        f"wheel encoders (left {args.pi_left_encoder}, right {args.pi_right_encoder}, "
        f"{args.pi_encoder_steps:g} steps per revolution, {args.pi_wheel_diameter:g} m wheels)"
        if motors.odometry_source == "encoders"
        else "the commands (no wheel encoders given: a blocked or slipping wheel goes unseen; "
        "--pi-left-encoder and --pi-right-encoder measure it)"
    )
    print(
        f"pi driver: camera {args.pi_camera!r} ({first.shape[1]}x{first.shape[0]}), motors "
        f"{args.pi_motors} left {args.pi_left or BOARDS[args.pi_motors][0]} right "
        f"{args.pi_right or BOARDS[args.pi_motors][1]}, wheel base {args.pi_wheel_base:g} m, "
        f"top speed {args.pi_top_speed:g} m/s; odometry from {source}",
        flush=True,
    )
    return RobotIO(camera=camera, motors=motors, clock=WallClock(), closers=closers)
