"""Robot drivers: cameras, motors, depth sensors and clocks behind small Protocols.

:mod:`.base` holds the Protocols (``Camera``, ``Motors``, ``DepthSensor``, ``Clock``) and
``RobotIO``, one robot's devices together. A driver is a module named in :data:`DRIVERS` that
provides two functions:

* ``add_arguments(parser: argparse.ArgumentParser) -> None``: its own options, every one
  prefixed with the driver's name (``--ros2-domain``, ``--pi-camera``), with defaults, so that
  one ``teachrepeat robot run`` parser holds every driver's;
* ``open_robot(args: argparse.Namespace) -> RobotIO``: the robot's devices, opened; a clear
  error (``DriverError``) saying what to fix when they cannot be.

A driver module imports its hardware library (CycloneDDS, gpiozero, MuJoCo) inside
``open_robot``, never at import time, so every driver's options can be listed on any machine.
"""

from __future__ import annotations

DRIVERS: dict[str, str] = {
    "ros2": "robot_client.drivers.ros2",
    "pi": "robot_client.drivers.pi",
    "sim": "robot_client.drivers.sim",
}
"""Driver name (``--driver NAME``) -> the module that provides it."""


class DriverError(RuntimeError):
    """A robot's devices cannot be opened: the message says what to fix."""
