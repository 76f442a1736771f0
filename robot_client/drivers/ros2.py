"""The ``ros2`` driver: a ROS 2 robot's own topics, over DDS, without a ROS 2 install.

It speaks ROS 2's wire types through CycloneDDS (:mod:`.ros2_dds`) on the robot's domain:

* camera: ``sensor_msgs/msg/CompressedImage`` (JPEG or PNG) or ``sensor_msgs/msg/Image``
  (``bgr8``, ``rgb8``, ``mono8``, ``bgra8``, ``rgba8``, ``yuv422``, ``yuv422_yuy2``);
* odometry: ``nav_msgs/msg/Odometry``, from the differences of its *pose*, not its twist: a
  best-effort reader may drop messages, and the pose of the next one still carries all the
  motion (an average of twists would miss the dropped ones); the mean is over the robot's
  own stamps, so late or bunched delivery does not change it;
* depth (optional): ``sensor_msgs/msg/LaserScan``, its rays within the server's depth field of
  view resampled left to right (:func:`.ros2_convert.scan_to_profile`);
* motors: ``geometry_msgs/msg/Twist`` (or ``TwistStamped``) on ``cmd_vel``, repeated at
  ``--ros2-cmd-rate`` while a command is in force, as a teleop node does (bases that stop on a
  quiet ``cmd_vel`` keep going), a zero twist at :meth:`Ros2Motors.stop`;
* clock: this computer's monotonic clock.

CycloneDDS is imported inside :func:`open_robot`; the conversions (topic names, images,
scans, odometry) live in :mod:`.ros2_convert` and need NumPy and OpenCV only.
"""

from __future__ import annotations

import argparse
import math
import os
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from robot_client.drivers import DriverError
from robot_client.drivers.base import Image, RobotIO
from robot_client.drivers.clock import WallClock
from robot_client.drivers.ros2_convert import (
    DEPTH_FOV_DEG,
    DEPTH_RAYS,
    PoseOdometry,
    dds_topic,
    decode_compressed,
    decode_raw,
    ros_name_of,
    ros_topic,
    ros_type_name,
    scan_to_profile,
)

if TYPE_CHECKING:
    from robot_client.drivers.ros2_dds import DdsNode


def _topic_arg(value: str) -> str:
    try:
        return ros_topic(value)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _stamp(header: Any) -> float:
    """A message's stamp in seconds, or this computer's clock for an unstamped message."""
    seconds = float(header.stamp.seconds())
    return seconds if seconds > 0 else time.monotonic()


# -- devices -------------------------------------------------------------------------------------


def _topic_hint(node: DdsNode, topic: str, expected: str, option: str) -> str:
    """What to do about a topic that stays silent: what is published there, or elsewhere."""
    published = node.publications()
    dds = dds_topic(topic)
    here = sorted({kind for name, kind in published if name == dds})
    if here:
        kinds = ", ".join(ros_type_name(k) for k in here)
        return f"{topic} is published as {kinds}, not {expected}" + (
            ": pass --ros2-camera-type raw or compressed to match" if option == "camera" else ""
        )
    ros = sorted(
        f"{ros_name_of(name)} ({ros_type_name(kind)})"
        for name, kind in published
        if ros_name_of(name) is not None
    )
    where = f"domain {node.domain_id}" + (f", interface {node.interface}" if node.interface else "")
    if not ros:
        return (
            f"no ROS 2 topic at all is published on {where}: is the robot on, on the same "
            "network, with the same ROS_DOMAIN_ID (--ros2-domain)? `ros2 topic list -t` on the "
            "robot lists its topics"
        )
    return (
        f"nobody publishes {topic}; published on {where}: {', '.join(ros[:20])}"
        + (" ..." if len(ros) > 20 else "")
        + f". Pass the right one with --ros2-{option}-topic"
    )


class _Latest:
    """An event set whenever a sample of one topic arrives (the reader keeps the newest)."""

    def __init__(self) -> None:
        self.event = threading.Event()

    def on_data(self, _reader: Any) -> None:
        self.event.set()


FRAME_WAIT_S = 1.0
"""Longest wait for each frame after the first, seconds: a camera stream that stalls makes
:meth:`Ros2Camera.read` fail soon (the agent stands and says so) rather than hold its loop."""


class Ros2Camera:
    """The robot's camera topic: :meth:`read` returns the newest frame that it has not
    returned before, waiting up to ``timeout_s`` for the first one (discovery takes a moment)
    and :data:`FRAME_WAIT_S` for each next one.

    Raises (from :meth:`read`):
        DriverError: no frame in that time (says what is published instead), or a frame
            that cannot be decoded.
    """

    def __init__(self, node: DdsNode, topic: str, *, raw: bool, timeout_s: float) -> None:
        from robot_client.drivers import ros2_dds as m

        self.node = node
        self.topic = topic
        self.raw = raw
        self.struct: type[Any] = m.Image if raw else m.CompressedImage
        self.first_timeout_s = timeout_s
        self.timeout_s = timeout_s
        self._latest = _Latest()
        self._reader: Any = node.reader(
            dds_topic(topic), self.struct, depth=1, on_data=self._latest.on_data
        )
        self._closed = False
        self.frames = 0
        """Frames returned so far."""

    def read(self) -> Image | None:
        if self._closed:
            return None
        deadline = time.monotonic() + self.timeout_s
        while True:
            # a publisher that went away leaves an invalid sample (no data): skip it
            samples = [s for s in self._reader.take(N=1) if isinstance(s, self.struct)]
            if samples:
                self.frames += 1
                self.timeout_s = min(self.first_timeout_s, FRAME_WAIT_S)
                return self._decode(samples[-1])
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not self._latest.event.wait(remaining):
                raise DriverError(self._silent())
            self._latest.event.clear()

    def _decode(self, msg: Any) -> Image:
        try:
            if self.raw:
                data = bytes(msg.data)
                return decode_raw(msg.encoding, msg.height, msg.width, msg.step, data)
            return decode_compressed(msg.format, bytes(msg.data))
        except ValueError as exc:
            raise DriverError(f"camera topic {self.topic}: {exc}") from None

    def _silent(self) -> str:
        from robot_client.drivers.ros2_dds import type_label

        expected = type_label(self.struct)
        return (
            f"no {expected} on {self.topic} (DDS topic {dds_topic(self.topic)}) for "
            f"{self.timeout_s:g} s: " + _topic_hint(self.node, self.topic, expected, "camera")
        )

    def close(self) -> None:
        self._closed = True


class Ros2Depth:
    """The robot's ``LaserScan`` topic as the server's depth profile (:func:`scan_to_profile`);
    the newest scan, or the last one while it is younger than ``timeout_s``."""

    def __init__(
        self,
        node: DdsNode,
        topic: str,
        *,
        timeout_s: float,
        n_rays: int = DEPTH_RAYS,
        fov_deg: float = DEPTH_FOV_DEG,
        yaw_rad: float = 0.0,
    ) -> None:
        from robot_client.drivers import ros2_dds as m

        self.node = node
        self.topic = topic
        self.timeout_s = timeout_s
        self.n_rays = n_rays
        self.fov_deg = fov_deg
        self.yaw_rad = yaw_rad
        self._latest = _Latest()
        self._struct = m.LaserScan
        self._reader: Any = node.reader(
            dds_topic(topic), m.LaserScan, depth=1, on_data=self._latest.on_data
        )
        self._profile: npt.NDArray[np.float32] | None = None
        self._at = -math.inf

    def wait(self) -> None:
        """Block until a scan has come (at most ``timeout_s``)."""
        if self._profile is None and not self._latest.event.wait(self.timeout_s):
            raise DriverError(self._silent())
        self.profile()

    def profile(self) -> npt.NDArray[np.float32]:
        samples = [s for s in self._reader.take(N=1) if isinstance(s, self._struct)]
        now = time.monotonic()
        if samples:
            scan = samples[-1]
            self._profile = scan_to_profile(
                scan.ranges,
                angle_min=scan.angle_min,
                angle_increment=scan.angle_increment,
                range_min=scan.range_min,
                range_max=scan.range_max,
                n_rays=self.n_rays,
                fov_deg=self.fov_deg,
                yaw_rad=self.yaw_rad,
            )
            self._at = now
        if self._profile is None or now - self._at > self.timeout_s:
            raise DriverError(self._silent())
        return self._profile.copy()

    def _silent(self) -> str:
        return (
            f"no sensor_msgs/msg/LaserScan on {self.topic} for {self.timeout_s:g} s: "
            + _topic_hint(self.node, self.topic, "sensor_msgs/msg/LaserScan", "scan")
            + " (or leave the scan out: --ros2-scan-topic none)"
        )


class Ros2Motors:
    """``cmd_vel`` out, ``Odometry`` in (see the module docstring).

    Args:
        node: the participant.
        cmd_topic, odom_topic: ROS 2 topic names.
        stamped: publish ``TwistStamped`` instead of ``Twist``.
        rate_hz: how often a command in force is published again (0: once).
    """

    def __init__(
        self,
        node: DdsNode,
        *,
        cmd_topic: str,
        odom_topic: str,
        stamped: bool = False,
        rate_hz: float = 10.0,
    ) -> None:
        from robot_client.drivers import ros2_dds as m

        self.node = node
        self.cmd_topic = cmd_topic
        self.odom_topic = odom_topic
        self.stamped = stamped
        self.rate_hz = rate_hz
        self._m = m
        self.odom = PoseOdometry()
        self._odom_event = threading.Event()
        self._odom_reader: Any = node.reader(
            dds_topic(odom_topic), m.Odometry, depth=50, on_data=self._on_odom
        )
        self._writer: Any = node.writer(
            dds_topic(cmd_topic), m.TwistStamped if stamped else m.Twist
        )
        self._lock = threading.Lock()
        self._command = (0.0, 0.0)
        self._closed = threading.Event()
        self.published = 0
        """Twists published so far."""
        self._thread: threading.Thread | None = None
        if rate_hz > 0:
            self._thread = threading.Thread(target=self._repeat, name="ros2-cmd", daemon=True)
            self._thread.start()

    def _on_odom(self, reader: Any) -> None:
        for msg in reader.take(N=50):
            if not isinstance(msg, self._m.Odometry):
                continue  # an invalid sample (a publisher went away)
            pose = msg.pose.pose
            self.odom.add(
                _stamp(msg.header), pose.position.x, pose.position.y, pose.orientation.yaw()
            )
        self._odom_event.set()

    def wait(self, timeout_s: float) -> None:
        """Block until an odometry message has come (at most ``timeout_s``)."""
        if self.odom.count == 0 and not self._odom_event.wait(timeout_s):
            raise DriverError(
                f"no nav_msgs/msg/Odometry on {self.odom_topic} for {timeout_s:g} s: "
                + _topic_hint(self.node, self.odom_topic, "nav_msgs/msg/Odometry", "odom")
            )

    def _publish(self, v: float, w: float) -> None:
        m = self._m
        twist = m.Twist(linear=m.Vector3(x=float(v)), angular=m.Vector3(z=float(w)))
        if self.stamped:
            header = m.Header(stamp=m.Time.from_seconds(time.time()))
            self._writer.write(m.TwistStamped(header=header, twist=twist))
        else:
            self._writer.write(twist)
        self.published += 1

    def command(self, v: float, w: float) -> None:
        with self._lock:
            if self._closed.is_set():
                return
            self._command = (float(v), float(w))
            self._publish(v, w)

    def odometry(self) -> tuple[float, float]:
        return self.odom.mean()

    def stop(self) -> None:
        with self._lock:
            self._command = (0.0, 0.0)
            if not self._closed.is_set():
                self._publish(0.0, 0.0)

    def _repeat(self) -> None:
        while not self._closed.wait(1.0 / self.rate_hz):
            with self._lock:
                if self._command != (0.0, 0.0) and not self._closed.is_set():
                    self._publish(*self._command)

    def close(self) -> None:
        """Stop the base and the repeating thread. Safe to call twice."""
        self.stop()
        self._closed.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)


# -- the driver ----------------------------------------------------------------------------------


def _default_domain() -> int:
    try:
        return int(os.environ.get("ROS_DOMAIN_ID", "0") or 0)
    except ValueError:
        return 0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``--ros2-*`` options (see docs/robot.md, "ROS 2 robots")."""
    g = parser.add_argument_group(
        "ros2 driver (--driver ros2): a ROS 2 robot's topics over DDS, no ROS 2 install needed"
    )
    g.add_argument(
        "--ros2-domain",
        type=int,
        default=_default_domain(),
        help="ROS 2 domain id, 0-232 (default: $ROS_DOMAIN_ID, else 0)",
    )
    g.add_argument(
        "--ros2-interface",
        default="",
        metavar="NAME",
        help="network interface DDS uses (wlan0, eth0; lo: this machine only); default: "
        "CycloneDDS's choice, or the configuration $CYCLONEDDS_URI names",
    )
    g.add_argument(
        "--ros2-camera-topic",
        type=_topic_arg,
        default="/camera/image_raw/compressed",
        metavar="TOPIC",
        help="camera topic (default %(default)s)",
    )
    g.add_argument(
        "--ros2-camera-type",
        choices=("auto", "compressed", "raw"),
        default="auto",
        help="sensor_msgs/msg/CompressedImage or Image; auto: compressed when the topic ends in "
        "/compressed (default)",
    )
    g.add_argument(
        "--ros2-odom-topic",
        type=_topic_arg,
        default="/odom",
        metavar="TOPIC",
        help="nav_msgs/msg/Odometry topic (default %(default)s)",
    )
    g.add_argument(
        "--ros2-scan-topic",
        default="/scan",
        metavar="TOPIC",
        help="sensor_msgs/msg/LaserScan topic for the depth profile, or 'none' (default "
        "%(default)s)",
    )
    g.add_argument(
        "--ros2-scan-yaw",
        type=float,
        default=0.0,
        metavar="DEG",
        help="heading of the scan frame's x axis on the robot, degrees counter-clockwise "
        "(default 0: it looks forward)",
    )
    g.add_argument(
        "--ros2-cmd-topic",
        type=_topic_arg,
        default="/cmd_vel",
        metavar="TOPIC",
        help="velocity command topic (default %(default)s)",
    )
    g.add_argument(
        "--ros2-cmd-type",
        choices=("twist", "twist-stamped"),
        default="twist",
        help="geometry_msgs/msg/Twist, or TwistStamped (ros2_control's diff-drive controller "
        "from ROS 2 Jazzy on); default twist",
    )
    g.add_argument(
        "--ros2-cmd-rate",
        type=float,
        default=10.0,
        metavar="HZ",
        help="publish a command in force again this often (default 10 Hz; 0: once)",
    )
    g.add_argument(
        "--ros2-timeout",
        type=float,
        default=5.0,
        metavar="S",
        help="wait this long for each topic's first message (default 5 s); each next frame: "
        "at most 1 s",
    )


def open_robot(args: argparse.Namespace) -> RobotIO:
    """The ROS 2 robot's camera, base (``cmd_vel`` + odometry) and scan, each topic's first
    message received.

    Raises:
        DriverError: CycloneDDS missing or unable to start, a bad option, or a topic that
            stays silent for ``--ros2-timeout`` seconds (the message says what is published).
    """
    try:
        from robot_client.drivers.ros2_dds import DdsNode, DomainConflict
    except ImportError as exc:
        raise DriverError(
            f"the ros2 driver needs CycloneDDS's Python binding ({exc}): pip install "
            "'teachrepeat[ros2]' (docs/robot.md, 'Install on the robot')"
        ) from None
    if not 0 <= args.ros2_domain <= 232:
        raise DriverError(f"--ros2-domain {args.ros2_domain}: ROS 2 domain ids run from 0 to 232")
    if args.ros2_timeout <= 0 or args.ros2_cmd_rate < 0:
        raise DriverError("--ros2-timeout must be positive and --ros2-cmd-rate at least 0")
    scan_topic = None
    if args.ros2_scan_topic.lower() != "none":
        try:
            scan_topic = ros_topic(args.ros2_scan_topic)
        except ValueError as exc:
            raise DriverError(f"--ros2-scan-topic: {exc}") from None
    camera_topic = args.ros2_camera_topic
    raw = args.ros2_camera_type == "raw" or (
        args.ros2_camera_type == "auto" and not camera_topic.endswith("/compressed")
    )
    try:
        node = DdsNode(args.ros2_domain, interface=args.ros2_interface)
    except DomainConflict as exc:
        raise DriverError(str(exc)) from None
    except Exception as exc:  # CycloneDDS's own errors (no such interface, bad configuration)
        raise DriverError(
            f"CycloneDDS could not join domain {args.ros2_domain}"
            + (f" on interface {args.ros2_interface!r}" if args.ros2_interface else "")
            + f": {exc}. Check --ros2-interface (`ip -brief address` lists them) and "
            "$CYCLONEDDS_URI"
        ) from None
    closers: list[Callable[[], None]] = [node.close]
    try:
        camera = Ros2Camera(node, camera_topic, raw=raw, timeout_s=args.ros2_timeout)
        motors = Ros2Motors(
            node,
            cmd_topic=args.ros2_cmd_topic,
            odom_topic=args.ros2_odom_topic,
            stamped=args.ros2_cmd_type == "twist-stamped",
            rate_hz=args.ros2_cmd_rate,
        )
        closers.append(motors.close)
        depth = None
        if scan_topic is not None:
            depth = Ros2Depth(
                node,
                scan_topic,
                timeout_s=args.ros2_timeout,
                yaw_rad=math.radians(args.ros2_scan_yaw),
            )
        closers.append(camera.close)
        first = camera.read()  # raises what to fix when nothing comes
        motors.wait(args.ros2_timeout)
        if depth is not None:
            depth.wait()
    except BaseException:
        for close in reversed(closers):
            close()
        raise
    shape = (0, 0) if first is None else first.shape[:2]
    print(
        f"ros2 driver: domain {args.ros2_domain}"
        + (f" on {args.ros2_interface}" if args.ros2_interface else "")
        + f"; camera {camera_topic} ({'Image' if raw else 'CompressedImage'}, "
        f"{shape[1]}x{shape[0]}), odometry {args.ros2_odom_topic} (pose "
        f"differences), depth {scan_topic or 'none'}, commands {args.ros2_cmd_topic} "
        f"({'TwistStamped' if motors.stamped else 'Twist'})",
        flush=True,
    )
    return RobotIO(camera=camera, motors=motors, clock=WallClock(), depth=depth, closers=closers)
