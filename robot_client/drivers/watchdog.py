"""Motors that stop by themselves when a command outlives its time-to-live.

Every command the server sends carries a time-to-live (``ttl_s``): the robot may drive on it
for that long and no longer. The robot agent's loop stops the motors when no newer command has
come in time, but the loop itself can be held up (a request hanging on a dead Wi-Fi link, a
slow camera read): :class:`MotorWatchdog` keeps the promise whatever the loop is doing, with a
thread of its own that stops the base once the command's deadline has passed.

Wall-clock robots only: a simulated robot's clock stands still between its loop's steps, so its
loop keeps the time-to-live itself (:func:`robot_client.navigate.drive`).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from robot_client.drivers.base import Motors


class MotorWatchdog:
    """``Motors`` with a deadline: :meth:`command` drives for at most ``ttl_s`` seconds.

    Args:
        motors: the base it guards (not owned: :meth:`close` stops it but does not close it).
        clock: monotonic seconds (``time.monotonic``; tests pass their own).
        poll_s: how often the guard thread looks at the deadline, seconds; the base stops at
            most this long after the deadline.
        on_expire: called (from the guard thread) each time a command ran out, with how late
            the stop came, seconds: for logs and measurements.
    """

    def __init__(
        self,
        motors: Motors,
        *,
        clock: Callable[[], float] = time.monotonic,
        poll_s: float = 0.01,
        on_expire: Callable[[float], None] | None = None,
    ) -> None:
        if poll_s <= 0:
            raise ValueError("poll_s must be positive")
        self.motors = motors
        self.clock = clock
        self.poll_s = poll_s
        self.on_expire = on_expire
        self._lock = threading.Lock()
        self._deadline: float | None = None  # None: standing still, nothing to guard
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._guard, name="motor-watchdog", daemon=True)
        self._thread.start()

    def command(self, v: float, w: float, ttl_s: float) -> None:
        """Drive at ``v`` m/s and ``w`` rad/s for at most ``ttl_s`` seconds from now (a
        command with ``ttl_s <= 0``, or after :meth:`close`, stops the base)."""
        with self._lock:
            if self._closed.is_set() or ttl_s <= 0:
                self._deadline = None
                self.motors.stop()
                return
            self._deadline = self.clock() + ttl_s
            self.motors.command(v, w)

    def stop(self) -> None:
        """Stop at once."""
        with self._lock:
            self._deadline = None
            self.motors.stop()

    def odometry(self) -> tuple[float, float]:
        """The base's measured ``(v, w)`` since the last call."""
        return self.motors.odometry()

    @property
    def driving(self) -> bool:
        """Whether a command is in force (its time-to-live has not run out)."""
        with self._lock:
            return self._deadline is not None

    def close(self) -> None:
        """Stop the base and the guard thread. Safe to call twice."""
        self._closed.set()
        self.stop()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)

    def _guard(self) -> None:
        while not self._closed.wait(self.poll_s):
            late: float | None = None
            with self._lock:
                if self._deadline is not None:
                    now = self.clock()
                    if now >= self._deadline:
                        late = now - self._deadline
                        self._deadline = None
                        self.motors.stop()
            if late is not None and self.on_expire is not None:
                self.on_expire(late)
