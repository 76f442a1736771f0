"""The clock of a robot that lives in real time: this computer's monotonic clock."""

from __future__ import annotations

import time


class WallClock:
    """``Clock`` on hardware: ``now()`` is ``time.monotonic()``, ``sleep`` really sleeps."""

    def now(self) -> float:
        """Seconds since an arbitrary origin, monotonic."""
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        """Block for ``seconds`` (nothing for zero or less)."""
        if seconds > 0:
            time.sleep(seconds)
