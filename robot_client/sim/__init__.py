"""A simulated home and a simulated camera robot for demos, tests and benchmarks.

* :mod:`.floorplan` - the home as data (rooms, doors, furniture, pictures, named places).
* :mod:`.textures` - photographic textures from installed packages (gimp-data, scikit-image).
* :mod:`.world` - MuJoCo rendering (CPU, OSMesa), depth rays and collisions: :class:`SimWorld`.
* :mod:`.robot` - :class:`SimulatedRobot`, implementing the driver Protocols.
* :mod:`.paths` - shortest paths on the plan and a scripted guide that drives along them.
* :mod:`.route` - the teaching route from the plan; :mod:`.plancheck` - every problem of a plan.

MuJoCo is imported only when a :class:`SimWorld` is created (after ``MUJOCO_GL=osmesa`` is set).
"""

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
