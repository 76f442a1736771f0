"""ROS 2's wire types, topic QoS and DDS domains, spoken through CycloneDDS without ROS.

A ROS 2 node is a DDS participant: a topic ``/cmd_vel`` of type ``geometry_msgs/msg/Twist`` is
the DDS topic ``rt/cmd_vel`` of the DDS type ``geometry_msgs::msg::dds_::Twist_``, serialised
as plain CDR (XCDR1) with the fields in the order of the ``.msg`` file. The structs below
declare exactly those types (their nested ``std_msgs/Header``, ``builtin_interfaces/Time``,
``geometry_msgs/Vector3`` ... included), so a ROS 2 node on the same domain reads what this
module writes and the other way round.

This module imports CycloneDDS at import time: the drivers import it inside ``open_robot``
(:mod:`robot_client.drivers.ros2`), never at their own import time.

QoS, as ROS 2's profiles set it (``rclcpp::SensorDataQoS``, ``rclcpp::QoS(10)``):

* readers are best effort, keep last N, volatile: a best-effort reader matches best-effort
  *and* reliable writers, volatile and transient-local ones, so it reads any ROS 2 publisher;
* the ``cmd_vel`` writer is reliable, keep last 10, volatile: ROS 2's default, which every
  ``cmd_vel`` subscriber accepts (a best-effort writer would not match a reliable reader);
* writers announce XCDR1 (what ROS 2 middlewares send), readers accept XCDR1 and XCDR2.
"""

# no "from __future__ import annotations": CycloneDDS reads the fields' types at run time

import math
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TypeVar
from xml.sax.saxutils import quoteattr

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
from cyclonedds.core import Listener, Policy, Qos
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, float32, float64, int32, sequence, uint8, uint32
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from robot_client.drivers.ros2_convert import ros_type_name

if TYPE_CHECKING:  # what the fields hold, for mypy; CycloneDDS reads the IDL types below
    Covariance = list[float]
    Octets = list[int]
    Floats = list[float]
else:
    Covariance = array[float64, 36]
    """``float64[36]``"""
    Octets = sequence[uint8]
    """``uint8[]``"""
    Floats = sequence[float32]
    """``float32[]``"""

# -- builtin_interfaces, std_msgs, geometry_msgs -------------------------------------------------


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    """``builtin_interfaces/msg/Time``: seconds and nanoseconds since the epoch (ROS time)."""

    sec: int32 = 0
    nanosec: uint32 = 0

    @classmethod
    def from_seconds(cls, seconds: float) -> "Time":
        """The stamp of ``seconds`` (Unix time, as ROS 2 nodes stamp by default)."""
        whole = math.floor(seconds)
        return cls(sec=int(whole), nanosec=min(int((seconds - whole) * 1e9), 999_999_999))

    def seconds(self) -> float:
        """The stamp as seconds."""
        return self.sec + self.nanosec * 1e-9


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    """``std_msgs/msg/Header``."""

    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    """``geometry_msgs/msg/Vector3``."""

    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    """``geometry_msgs/msg/Twist``: ``linear.x`` m/s forward, ``angular.z`` rad/s to the left."""

    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass
class TwistStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TwistStamped_"):
    """``geometry_msgs/msg/TwistStamped`` (what ``ros2_control``'s diff-drive controller takes
    on ``cmd_vel`` from ROS 2 Jazzy on)."""

    header: Header = field(default_factory=Header)
    twist: Twist = field(default_factory=Twist)


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    """``geometry_msgs/msg/Point``."""

    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    """``geometry_msgs/msg/Quaternion`` (the identity by default, as in ROS 2)."""

    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0

    @classmethod
    def from_yaw(cls, yaw: float) -> "Quaternion":
        """A rotation of ``yaw`` radians about z."""
        return cls(z=math.sin(yaw / 2), w=math.cos(yaw / 2))

    def yaw(self) -> float:
        """The heading about z, radians in ``(-pi, pi]`` (roll and pitch ignored)."""
        return math.atan2(
            2.0 * (self.w * self.z + self.x * self.y), 1.0 - 2.0 * (self.y**2 + self.z**2)
        )


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    """``geometry_msgs/msg/Pose``."""

    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


def _zeros36() -> list[float]:
    return [0.0] * 36


@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    """``geometry_msgs/msg/PoseWithCovariance``: ``float64[36]`` row-major covariance."""

    pose: Pose = field(default_factory=Pose)
    covariance: Covariance = field(default_factory=_zeros36)


@dataclass
class TwistWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    """``geometry_msgs/msg/TwistWithCovariance``."""

    twist: Twist = field(default_factory=Twist)
    covariance: Covariance = field(default_factory=_zeros36)


# -- nav_msgs, sensor_msgs -----------------------------------------------------------------------


@dataclass
class Odometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    """``nav_msgs/msg/Odometry``: the pose in ``header.frame_id`` (``odom``), the twist in
    ``child_frame_id`` (``base_link``)."""

    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)
    twist: TwistWithCovariance = field(default_factory=TwistWithCovariance)


@dataclass
class CompressedImage(IdlStruct, typename="sensor_msgs::msg::dds_::CompressedImage_"):
    """``sensor_msgs/msg/CompressedImage``: ``format`` (``jpeg``, ``png``, or image_transport's
    ``"bgr8; jpeg compressed bgr8"``) and the encoded bytes."""

    header: Header = field(default_factory=Header)
    format: str = ""
    data: Octets = field(default_factory=list)


@dataclass
class Image(IdlStruct, typename="sensor_msgs::msg::dds_::Image_"):
    """``sensor_msgs/msg/Image``: ``height`` rows of ``step`` bytes in ``encoding``."""

    header: Header = field(default_factory=Header)
    height: uint32 = 0
    width: uint32 = 0
    encoding: str = ""
    is_bigendian: uint8 = 0
    step: uint32 = 0
    data: Octets = field(default_factory=list)


@dataclass
class LaserScan(IdlStruct, typename="sensor_msgs::msg::dds_::LaserScan_"):
    """``sensor_msgs/msg/LaserScan``: ray ``i`` at ``angle_min + i * angle_increment`` radians
    (counter-clockwise from the scan frame's x axis), ``ranges`` in metres."""

    header: Header = field(default_factory=Header)
    angle_min: float32 = 0.0
    angle_max: float32 = 0.0
    angle_increment: float32 = 0.0
    time_increment: float32 = 0.0
    scan_time: float32 = 0.0
    range_min: float32 = 0.0
    range_max: float32 = 0.0
    ranges: Floats = field(default_factory=list)
    intensities: Floats = field(default_factory=list)


def type_label(struct: type[IdlStruct]) -> str:
    """``struct``'s ROS 2 name, for messages: ``sensor_msgs/msg/CompressedImage``."""
    return ros_type_name(struct.__idl_typename__.replace(".", "::"))


# -- QoS -----------------------------------------------------------------------------------------

_ANY_CDR = Policy.DataRepresentation(use_cdrv0_representation=True, use_xcdrv2_representation=True)
_XCDR1 = Policy.DataRepresentation(use_cdrv0_representation=True)


def reader_qos(depth: int = 1) -> Qos:
    """What our readers ask for: best effort, keep the last ``depth``, volatile (matches every
    ROS 2 publisher: sensor-data and default profiles, volatile or transient local)."""
    return Qos(
        Policy.Reliability.BestEffort,
        Policy.History.KeepLast(depth),
        Policy.Durability.Volatile,
        _ANY_CDR,
    )


def command_qos(*, reader: bool = False) -> Qos:
    """ROS 2's default profile, for ``cmd_vel``: reliable, keep last 10, volatile (a
    ``reader``'s accepts XCDR1 and XCDR2)."""
    return Qos(
        Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100)),
        Policy.History.KeepLast(10),
        Policy.Durability.Volatile,
        _ANY_CDR if reader else _XCDR1,
    )


def sensor_qos(depth: int = 5) -> Qos:
    """ROS 2's sensor-data profile (``rclcpp::SensorDataQoS``): best effort, keep last 5,
    volatile; what camera and laser drivers publish with."""
    return Qos(
        Policy.Reliability.BestEffort,
        Policy.History.KeepLast(depth),
        Policy.Durability.Volatile,
        _XCDR1,
    )


# -- domains and participants --------------------------------------------------------------------

LOOPBACK_NAMES = ("lo", "loopback", "127.0.0.1")
"""``--ros2-interface`` values that mean: this machine only."""

_LOOPBACK_CONFIG = (
    '<CycloneDDS><Domain id="any"><General>'
    '<Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>'
    "<AllowMulticast>false</AllowMulticast></General>"
    "<Discovery><ParticipantIndex>auto</ParticipantIndex>"
    "<MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>"
    '<Peers><Peer address="127.0.0.1"/></Peers></Discovery>'
    "</Domain></CycloneDDS>"
)


def cyclonedds_config(interface: str) -> str | None:
    """The CycloneDDS configuration for ``interface``.

    ``""``: none of ours (CycloneDDS's defaults, or the file ``CYCLONEDDS_URI`` names);
    ``lo``: loopback only, with unicast discovery between the processes of this machine
    (participant indices, no multicast), as ROS 2 sets CycloneDDS up for
    ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``; any other name: that network interface only.
    """
    if not interface:
        return None
    if interface in LOOPBACK_NAMES:
        return _LOOPBACK_CONFIG
    return (
        '<CycloneDDS><Domain id="any"><General><Interfaces>'
        f"<NetworkInterface name={quoteattr(interface)}/>"
        "</Interfaces></General></Domain></CycloneDDS>"
    )


class DomainConflict(RuntimeError):
    """A domain is already open in this process with another network configuration."""


_domains_lock = threading.Lock()
_domains: dict[int, tuple[str | None, Domain | None, int]] = {}
"""domain id -> (configuration, the Domain we created or None, participants open)."""


def _acquire_domain(domain_id: int, config: str | None) -> None:
    with _domains_lock:
        if domain_id in _domains:
            held, domain, count = _domains[domain_id]
            if held != config:
                raise DomainConflict(
                    f"DDS domain {domain_id} is already open in this process with another "
                    "network configuration: give both the same --ros2-interface"
                )
            _domains[domain_id] = (held, domain, count + 1)
            return
        domain = Domain(domain_id, config) if config is not None else None
        _domains[domain_id] = (config, domain, 1)


def _release_domain(domain_id: int) -> None:
    with _domains_lock:
        config, domain, count = _domains[domain_id]
        if count > 1:
            _domains[domain_id] = (config, domain, count - 1)
            return
        del _domains[domain_id]
    if domain is not None:
        domain.__del__()  # the C domain goes now, not whenever Python collects it


S = TypeVar("S", bound=IdlStruct)


class DdsNode:
    """One DDS participant on ``domain_id``: the readers and writers of one ROS 2 "node".

    Args:
        domain_id: ROS 2's domain id (``ROS_DOMAIN_ID``), 0 to 232.
        interface: see :func:`cyclonedds_config`.

    Raises:
        DomainConflict: the domain is open in this process with another configuration.
        cyclonedds.core.DDSException: CycloneDDS could not start (e.g. no such interface).
    """

    def __init__(self, domain_id: int, *, interface: str = "") -> None:
        if not 0 <= domain_id <= 232:
            raise ValueError(f"ROS 2 domain ids run from 0 to 232, not {domain_id}")
        self.domain_id = domain_id
        self.interface = interface
        _acquire_domain(domain_id, cyclonedds_config(interface))
        try:
            self.participant = DomainParticipant(domain_id)
        except Exception:
            _release_domain(domain_id)
            raise
        self._topics: dict[str, Topic[Any]] = {}
        self._closed = False

    def _topic(self, name: str, struct: type[S]) -> Topic[S]:
        if name not in self._topics:
            self._topics[name] = Topic(self.participant, name, struct)
        return self._topics[name]

    def reader(
        self,
        name: str,
        struct: type[S],
        *,
        depth: int = 1,
        on_data: Any = None,
        qos: Qos | None = None,
    ) -> DataReader[S]:
        """A reader of DDS topic ``name`` (``rt/...``), best effort unless ``qos`` says
        otherwise; ``on_data(reader)`` is called from CycloneDDS's thread when samples arrive.
        Keep the reader: CycloneDDS deletes it when Python collects it."""
        listener = Listener(on_data_available=on_data) if on_data is not None else None
        return DataReader(
            self.participant,
            self._topic(name, struct),
            qos=qos or reader_qos(depth),
            listener=listener,
        )

    def writer(self, name: str, struct: type[S], *, qos: Qos | None = None) -> DataWriter[S]:
        """A writer of DDS topic ``name`` (reliable unless ``qos`` says otherwise)."""
        return DataWriter(self.participant, self._topic(name, struct), qos=qos or command_qos())

    def publications(self, wait_s: float = 0.5) -> list[tuple[str, str]]:
        """``(DDS topic, DDS type)`` of every publication other participants announced on the
        domain, waiting up to ``wait_s`` for discovery; for error messages."""
        reader = BuiltinDataReader(self.participant, BuiltinTopicDcpsPublication)
        own = self.participant.guid
        seen: set[tuple[str, str]] = set()
        deadline = time.monotonic() + wait_s
        while True:
            for sample in reader.read(N=1000):
                key = getattr(sample, "participant_key", None)
                name, kind = getattr(sample, "topic_name", None), getattr(sample, "type_name", None)
                if name and kind and key != own:
                    seen.add((name, kind))
            if time.monotonic() >= deadline:
                break
            time.sleep(0.05)
        reader.__del__()
        return sorted(seen)

    def close(self) -> None:
        """Delete the participant and everything it holds (its listeners have returned when
        this returns). Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        self._topics.clear()
        self.participant.__del__()
        _release_domain(self.domain_id)
