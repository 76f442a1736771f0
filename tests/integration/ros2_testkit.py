"""ROS 2's ``geometry_msgs/msg/Twist`` declared as a plain CycloneDDS program would (as rclpy's
generated types are), independently of :mod:`robot_client.drivers.ros2_dds`: a reader of these
checks that what the driver writes is ROS 2's type on the wire.

No ``from __future__ import annotations`` here: CycloneDDS reads the fields' types at run time.
"""

from dataclasses import dataclass, field

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import float64


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64
    y: float64
    z: float64


@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3 = field(default_factory=lambda: Vector3(0.0, 0.0, 0.0))
    angular: Vector3 = field(default_factory=lambda: Vector3(0.0, 0.0, 0.0))
