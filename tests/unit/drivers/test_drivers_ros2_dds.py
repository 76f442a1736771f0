"""ROS 2's wire types and QoS through CycloneDDS: type names, field order, bytes on the wire.

The message definitions below are ROS 2's ``.msg`` files (common_interfaces, rcl_interfaces);
an independent little CDR encoder turns a message into the bytes a ROS 2 node sends, and
CycloneDDS's serialisation of our structs must give exactly those bytes.
"""

from __future__ import annotations

import dataclasses
import struct
from typing import Any
from xml.etree import ElementTree

import pytest
from cyclonedds.core import Policy

from robot_client.drivers import ros2_dds as m

MSG = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Twist": "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular",
    "geometry_msgs/TwistStamped": "std_msgs/Header header\ngeometry_msgs/Twist twist",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Quaternion": "float64 x\nfloat64 y\nfloat64 z\nfloat64 w",
    "geometry_msgs/Pose": "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation",
    "geometry_msgs/PoseWithCovariance": "geometry_msgs/Pose pose\nfloat64[36] covariance",
    "geometry_msgs/TwistWithCovariance": "geometry_msgs/Twist twist\nfloat64[36] covariance",
    "nav_msgs/Odometry": "std_msgs/Header header\nstring child_frame_id\n"
    "geometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist",
    "sensor_msgs/CompressedImage": "std_msgs/Header header\nstring format\nuint8[] data",
    "sensor_msgs/Image": "std_msgs/Header header\nuint32 height\nuint32 width\n"
    "string encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data",
    "sensor_msgs/LaserScan": "std_msgs/Header header\nfloat32 angle_min\nfloat32 angle_max\n"
    "float32 angle_increment\nfloat32 time_increment\nfloat32 scan_time\n"
    "float32 range_min\nfloat32 range_max\nfloat32[] ranges\nfloat32[] intensities",
}
"""ROS 2 message definitions (comments and constants left out)."""

STRUCTS = {
    "builtin_interfaces/Time": m.Time,
    "std_msgs/Header": m.Header,
    "geometry_msgs/Vector3": m.Vector3,
    "geometry_msgs/Twist": m.Twist,
    "geometry_msgs/TwistStamped": m.TwistStamped,
    "geometry_msgs/Point": m.Point,
    "geometry_msgs/Quaternion": m.Quaternion,
    "geometry_msgs/Pose": m.Pose,
    "geometry_msgs/PoseWithCovariance": m.PoseWithCovariance,
    "geometry_msgs/TwistWithCovariance": m.TwistWithCovariance,
    "nav_msgs/Odometry": m.Odometry,
    "sensor_msgs/CompressedImage": m.CompressedImage,
    "sensor_msgs/Image": m.Image,
    "sensor_msgs/LaserScan": m.LaserScan,
}

PRIMITIVES = {
    "int32": "i",
    "uint32": "I",
    "uint8": "B",
    "float32": "f",
    "float64": "d",
}


def fields(msg: str) -> list[tuple[str, str]]:
    return [tuple(line.split()) for line in MSG[msg].splitlines()]  # type: ignore[misc]


@pytest.mark.parametrize("msg", sorted(MSG))
def test_dds_type_names_are_ros2s(msg: str) -> None:
    package, name = msg.split("/")
    assert STRUCTS[msg].__idl_typename__ == f"{package}::msg::dds_::{name}_"
    assert m.type_label(STRUCTS[msg]) == f"{package}/msg/{name}"


@pytest.mark.parametrize("msg", sorted(MSG))
def test_fields_come_in_the_order_of_the_msg_file(msg: str) -> None:
    ours = [f.name for f in dataclasses.fields(STRUCTS[msg])]
    assert ours == [name for _, name in fields(msg)]


class Cdr:
    """Plain CDR (XCDR1), little endian, as ROS 2 middlewares put it on the wire: every
    primitive aligned to its size from the start of the payload."""

    def __init__(self) -> None:
        self.out = bytearray()

    def align(self, n: int) -> None:
        self.out += bytes(-len(self.out) % n)

    def put(self, code: str, value: Any) -> None:
        size = struct.calcsize(code)
        self.align(size)
        self.out += struct.pack("<" + code, value)

    def string(self, text: str) -> None:
        data = text.encode() + b"\0"
        self.put("I", len(data))
        self.out += data

    def value(self, kind: str, value: Any) -> None:
        if kind.endswith("]"):
            inner, count = kind[:-1].split("[")
            if not count:
                self.put("I", len(value))
            for item in value:
                self.value(inner, item)
        elif kind == "string":
            self.string(value)
        elif kind in PRIMITIVES:
            self.put(PRIMITIVES[kind], value)
        else:
            for sub, name in fields(kind):
                self.value(sub, value[name])


def sample(msg: str, seed: int) -> dict[str, Any]:
    """A message of type ``msg`` with a distinct value in every field."""
    out: dict[str, Any] = {}
    for i, (kind, name) in enumerate(fields(msg)):
        k = seed * 10 + i + 1
        if kind in MSG:
            out[name] = sample(kind, k)
        elif kind == "string":
            out[name] = f"s{k}" * (k % 4)
        elif kind == "uint8[]":
            out[name] = [(k * j) % 256 for j in range(k % 7 + 1)]
        elif kind == "float32[]":
            out[name] = [k + 0.5 * j for j in range(k % 5)]
        elif kind == "float64[36]":
            out[name] = [k + 0.25 * j for j in range(36)]
        elif kind.startswith("float"):
            out[name] = k + 0.5
        else:
            out[name] = k % 200
    return out


def build(msg: str, values: dict[str, Any]) -> Any:
    struct_type = STRUCTS[msg]
    kwargs = {}
    for kind, name in fields(msg):
        kwargs[name] = build(kind, values[name]) if kind in MSG else values[name]
    return struct_type(**kwargs)


@pytest.mark.parametrize("msg", sorted(MSG))
def test_the_bytes_on_the_wire_are_what_a_ros2_node_sends_and_reads(msg: str) -> None:
    values = sample(msg, 3)
    cdr = Cdr()
    cdr.value(msg, values)
    expected = b"\x00\x01\x00\x00" + bytes(cdr.out)  # CDR_LE encapsulation, then the payload
    ours = build(msg, values)
    wire = ours.serialize()
    assert wire[: len(expected)] == expected and len(wire) - len(expected) < 4  # padding only
    assert STRUCTS[msg].deserialize(expected) == ours


def test_stamps_and_headings_convert_both_ways() -> None:
    stamp = m.Time.from_seconds(1700000000.25)
    assert (stamp.sec, stamp.nanosec) == (1700000000, 250000000)
    assert stamp.seconds() == pytest.approx(1700000000.25)
    for yaw in (0.0, 1.0, -2.5, 3.1):
        assert m.Quaternion.from_yaw(yaw).yaw() == pytest.approx(yaw)
    assert m.Quaternion().w == 1.0  # the identity, as ROS 2's default


def test_readers_are_best_effort_and_the_command_writer_reliable_as_ros2_sets_them() -> None:
    reader = m.reader_qos()
    assert Policy.Reliability.BestEffort in reader and Policy.History.KeepLast(1) in reader
    assert Policy.Durability.Volatile in reader
    command = m.command_qos()
    assert any(isinstance(p, Policy.Reliability.Reliable) for p in command)
    assert Policy.History.KeepLast(10) in command and Policy.Durability.Volatile in command
    assert Policy.DataRepresentation(use_cdrv0_representation=True) in command  # XCDR1 only
    sensors = m.sensor_qos()
    assert Policy.Reliability.BestEffort in sensors and Policy.History.KeepLast(5) in sensors


def test_loopback_keeps_dds_on_this_machine_and_an_interface_is_named() -> None:
    loop = m.cyclonedds_config("lo")
    assert loop is not None and m.cyclonedds_config("loopback") == loop
    assert 'address="127.0.0.1"' in loop and "<AllowMulticast>false</AllowMulticast>" in loop
    assert '<Peer address="127.0.0.1"/>' in loop
    assert m.cyclonedds_config("") is None  # CycloneDDS's own defaults, or $CYCLONEDDS_URI
    odd = 'wlan0"/><x'
    wlan = m.cyclonedds_config(odd)  # quoted, never spliced into the XML
    assert wlan is not None
    interfaces = ElementTree.fromstring(wlan).findall(".//NetworkInterface")
    assert [i.get("name") for i in interfaces] == [odd]


def test_one_domain_one_configuration_per_process() -> None:
    first = m.DdsNode(231, interface="lo")
    try:
        second = m.DdsNode(231, interface="lo")  # the same configuration: shared
        second.close()
        with pytest.raises(m.DomainConflict, match="give both the same --ros2-interface"):
            m.DdsNode(231, interface="")
    finally:
        first.close()
    m.DdsNode(231, interface="").close()  # the domain went with its last participant
    with pytest.raises(ValueError, match="from 0 to 232"):
        m.DdsNode(233)
