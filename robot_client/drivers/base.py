"""The interfaces every robot driver implements: real hardware and the simulator alike.

A robot loop only ever talks to these Protocols, so the same loop drives a real base, a
recorded folder of images or the simulated home. Units: metres, seconds, radians.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

Image = npt.NDArray[np.uint8]
"""``(H, W, 3)`` uint8, BGR channel order (OpenCV's)."""


@runtime_checkable
class Camera(Protocol):
    """A source of colour frames."""

    def read(self) -> Image | None:
        """The next frame, ``(H, W, 3)`` uint8 BGR; ``None`` when the stream has ended."""
        ...

    def close(self) -> None:
        """Release the device. Safe to call twice."""
        ...


@runtime_checkable
class Motors(Protocol):
    """A differential-drive base that takes velocity commands and reports odometry."""

    def command(self, v: float, w: float) -> None:
        """Drive at linear velocity ``v`` (m/s, forward positive) and angular velocity ``w``
        (rad/s, counter-clockwise positive) until the next command or :meth:`stop`."""
        ...

    def odometry(self) -> tuple[float, float]:
        """Measured ``(v, w)`` in m/s and rad/s since the last call (noisy on a real base)."""
        ...

    def stop(self) -> None:
        """Stop at once."""
        ...


@runtime_checkable
class DepthSensor(Protocol):
    """A forward-looking row of ranges, for obstacle avoidance and exploring."""

    def profile(self) -> npt.NDArray[np.float32]:
        """``(n_rays,)`` float32 ranges in metres, from the leftmost ray to the rightmost;
        ``inf`` where nothing is within range."""
        ...


@runtime_checkable
class Clock(Protocol):
    """Time as the robot sees it: wall time on hardware, simulated time in the simulator."""

    def now(self) -> float:
        """Seconds since an arbitrary origin, monotonic."""
        ...

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` pass (the simulator advances its world by that much)."""
        ...


@dataclass
class RobotIO:
    """One robot's devices as the robot agent drives them: what a driver module's
    ``open_robot(args)`` returns (see :mod:`robot_client.drivers`). ``depth`` is ``None`` on a
    robot without a depth sensor; ``close`` releases everything (safe to call twice).

    ``simulated``: the clock is a simulator's, whose time stands still between the loop's
    steps; the agent then keeps each command's time-to-live in that time itself. A wall-clock
    robot (False, every real one) has its motors guarded by a
    :class:`~robot_client.drivers.watchdog.MotorWatchdog` instead."""

    camera: Camera
    motors: Motors
    clock: Clock
    depth: DepthSensor | None = None
    closers: list[Callable[[], None]] = field(default_factory=list)
    simulated: bool = False

    def close(self) -> None:
        """Stop the motors, then release every device in the reverse order of opening."""
        try:
            self.motors.stop()
        finally:
            while self.closers:
                self.closers.pop()()
