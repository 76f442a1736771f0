"""The robot stops within its commands' time-to-live when its server disappears mid-drive.

A real server process; the robot agent in a thread driving a wall-clock robot (hardware we do
not have: a fixed frame and motors that keep what they are told, behind the driver
Protocols, guarded by the agent's motor watchdog), driven by teleop. The server is killed
(its sockets close: the agent's next request fails at once) or frozen (nothing answers and
nothing closes, as with a hung server or a dead link: the watchdog stops the wheels at the
command's deadline). Measured from the signal to the wheels' stop.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from server.bench.teleop import stop_when_gone

TTL_S = 0.3
"""The time-to-live of every command answered outside navigation (ControlParams.ttl_s)."""


@pytest.mark.parametrize("kind", ["kill", "stop"])
def test_killing_or_freezing_the_server_mid_drive_stops_the_robot_within_the_ttl(
    tmp_path: Path, kind: str
) -> None:
    found = stop_when_gone(kind, db=tmp_path / "gone.sqlite")
    print(f"{kind}: stopped {found['stop_s'] * 1000:.0f} ms after the signal")
    assert 0.0 < found["stop_s"] <= TTL_S, found
    if kind == "stop":
        # stopped by the watchdog at the deadline, while the request still waited
        assert found["stop_s"] >= 0.05, found
