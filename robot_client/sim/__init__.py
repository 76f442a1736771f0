"""A simulated home and a simulated camera robot for demos, tests and benchmarks.

* :mod:`.floorplan` - the home as data (rooms, doors, furniture, pictures, named places).
* :mod:`.textures` - photographic textures from installed packages (gimp-data, scikit-image).
* :mod:`.world` - MuJoCo rendering (CPU, OSMesa), depth rays and collisions: :class:`SimWorld`.
* :mod:`.robot` - :class:`SimulatedRobot`, implementing the driver Protocols.
* :mod:`.paths` - shortest paths on the plan and a scripted guide that drives along them.
* :mod:`.route` - the teaching route from the plan; :mod:`.plancheck` - every problem of a plan.

MuJoCo is imported only when a :class:`SimWorld` is created (after ``MUJOCO_GL=osmesa`` is set).
The names below are imported on first use (PEP 562), so that ``robot_client.sim.floorplan``
(the standard library only) can be imported where the simulator's dependencies are not
installed: a robot's slim install lists the ``sim`` driver's options (its plan conditions).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from robot_client.sim.floorplan import (
        CONDITIONS,
        Door,
        FloorPlan,
        Furniture,
        Picture,
        Place,
        PlanError,
        Room,
        Wall,
        load_plan,
    )
    from robot_client.sim.paths import (
        FollowParams,
        NoPathError,
        Step,
        drive_to,
        follow,
        path_length,
        shortest_path,
        spin,
        turn_to,
    )
    from robot_client.sim.robot import RobotParams, SimulatedRobot
    from robot_client.sim.world import CameraParams, PlanGeometry, Pose, SimWorld

_SOURCES = {
    "robot_client.sim.floorplan": (
        "CONDITIONS",
        "Door",
        "FloorPlan",
        "Furniture",
        "Picture",
        "Place",
        "PlanError",
        "Room",
        "Wall",
        "load_plan",
    ),
    "robot_client.sim.paths": (
        "FollowParams",
        "NoPathError",
        "Step",
        "drive_to",
        "follow",
        "path_length",
        "shortest_path",
        "spin",
        "turn_to",
    ),
    "robot_client.sim.robot": ("RobotParams", "SimulatedRobot"),
    "robot_client.sim.world": ("CameraParams", "PlanGeometry", "Pose", "SimWorld"),
}
_MODULE_OF = {name: module for module, names in _SOURCES.items() for name in names}


def __getattr__(name: str) -> Any:
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module 'robot_client.sim' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)


__all__ = [
    "CONDITIONS",
    "CameraParams",
    "Door",
    "FloorPlan",
    "FollowParams",
    "Furniture",
    "NoPathError",
    "Picture",
    "Place",
    "PlanError",
    "PlanGeometry",
    "Pose",
    "RobotParams",
    "Room",
    "SimWorld",
    "SimulatedRobot",
    "Step",
    "Wall",
    "drive_to",
    "follow",
    "load_plan",
    "path_length",
    "shortest_path",
    "spin",
    "turn_to",
]
