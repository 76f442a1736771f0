"""ROS 2 messages as the driver contract wants them: pure conversions, NumPy and OpenCV only.

Topic names (``/cmd_vel`` <-> DDS ``rt/cmd_vel``), images (``CompressedImage`` and raw
``Image`` encodings -> BGR), laser scans -> the server's depth profile, odometry poses -> the
mean ``(v, w)`` between readings. :mod:`robot_client.drivers.ros2` wires them to CycloneDDS.
"""

from __future__ import annotations

import math
import re
import threading
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from robot_client.drivers.base import Image
from server.schemas import MAX_ANGULAR_SPEED, MAX_LINEAR_SPEED

DEPTH_FOV_DEG = 90.0
"""Field of view of the server's depth profile (``MotionParams.depth_fov_deg``), degrees."""
DEPTH_RAYS = 31
"""Rays of the profile made from a scan: as many as the simulated robot's (``CameraParams``)."""

_NAME_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


# -- names ---------------------------------------------------------------------------------------


def ros_topic(name: str) -> str:
    """A ROS 2 topic name, checked and made absolute: ``cmd_vel`` -> ``/cmd_vel``.

    Raises:
        ValueError: not a ROS 2 topic name (empty, ``//``, a trailing ``/``, a token that
            starts with a digit or holds other characters than letters, digits and ``_``).
    """
    text = name.strip()
    tokens = text.lstrip("/").split("/")
    if not text or text.endswith("/") or not all(_NAME_TOKEN.fullmatch(tok) for tok in tokens):
        raise ValueError(
            f"{name!r} is not a ROS 2 topic name: tokens of letters, digits and _ (not "
            "starting with a digit) joined by /, such as /camera/image_raw/compressed"
        )
    return "/" + "/".join(tokens)


def dds_topic(name: str) -> str:
    """The DDS topic of ROS 2 topic ``name``: ``/cmd_vel`` -> ``rt/cmd_vel`` (ROS 2's
    ``rt`` prefix for topics)."""
    return "rt" + ros_topic(name)


def ros_name_of(dds_name: str) -> str | None:
    """The ROS 2 topic of DDS topic ``dds_name``, or ``None`` for DDS topics that are not
    ROS 2 topics (services, ROS 2's own discovery topic)."""
    return dds_name[2:] if dds_name.startswith("rt/") else None


def ros_type_name(dds_type: str) -> str:
    """A DDS type name as ROS 2 tools print it: ``sensor_msgs::msg::dds_::Image_`` ->
    ``sensor_msgs/msg/Image`` (other names unchanged)."""
    parts = dds_type.split("::")
    if len(parts) == 4 and parts[2] == "dds_" and parts[3].endswith("_"):
        return f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"
    return dds_type


# -- camera --------------------------------------------------------------------------------------

RAW_ENCODINGS = ("bgr8", "rgb8", "mono8", "bgra8", "rgba8", "yuv422", "yuv422_yuy2")
"""``sensor_msgs/msg/Image`` encodings :func:`decode_raw` reads."""

_CHANNELS = {"bgr8": 3, "rgb8": 3, "mono8": 1, "bgra8": 4, "rgba8": 4, "yuv422": 2}
_CHANNELS["yuv422_yuy2"] = 2
_TO_BGR = {
    "rgb8": cv2.COLOR_RGB2BGR,
    "mono8": cv2.COLOR_GRAY2BGR,
    "bgra8": cv2.COLOR_BGRA2BGR,
    "rgba8": cv2.COLOR_RGBA2BGR,
    "yuv422": cv2.COLOR_YUV2BGR_UYVY,
    "yuv422_yuy2": cv2.COLOR_YUV2BGR_YUY2,
}


def decode_compressed(fmt: str, data: bytes) -> Image:
    """A ``sensor_msgs/msg/CompressedImage`` as ``(H, W, 3)`` uint8 BGR.

    Raises:
        ValueError: a depth image (``compressedDepth``), or bytes OpenCV cannot decode.
    """
    if "compressedDepth" in fmt:
        raise ValueError(
            f"the camera topic carries depth images (format {fmt!r}): give a colour topic"
        )
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(
            f"cannot decode a CompressedImage of format {fmt!r} ({len(data)} bytes): "
            "JPEG and PNG colour images only"
        )
    return np.asarray(image, dtype=np.uint8)


def decode_raw(encoding: str, height: int, width: int, step: int, data: bytes) -> Image:
    """A ``sensor_msgs/msg/Image`` as ``(H, W, 3)`` uint8 BGR (rows of ``step`` bytes; any
    padding past ``width`` pixels is dropped).

    Raises:
        ValueError: an encoding outside :data:`RAW_ENCODINGS`, or fewer bytes than the size says.
    """
    channels = _CHANNELS.get(encoding)
    if channels is None:
        raise ValueError(
            f"unsupported Image encoding {encoding!r}: publish one of "
            f"{', '.join(RAW_ENCODINGS)} or use a CompressedImage topic"
        )
    if height <= 0 or width <= 0 or step < width * channels or len(data) < step * height:
        raise ValueError(
            f"an Image of {width}x{height} {encoding} needs rows of at least "
            f"{width * channels} bytes and {step * height} bytes in all: got step {step} and "
            f"{len(data)} bytes"
        )
    rows = np.frombuffer(data, np.uint8, count=step * height).reshape(height, step)
    pixels = rows[:, : width * channels].reshape(height, width, channels)
    if encoding == "bgr8":
        return np.array(pixels, dtype=np.uint8)
    return np.asarray(cv2.cvtColor(pixels, _TO_BGR[encoding]), dtype=np.uint8)


# -- depth ---------------------------------------------------------------------------------------


def scan_to_profile(
    ranges: npt.ArrayLike,
    *,
    angle_min: float,
    angle_increment: float,
    range_min: float,
    range_max: float,
    n_rays: int = DEPTH_RAYS,
    fov_deg: float = DEPTH_FOV_DEG,
    yaw_rad: float = 0.0,
) -> npt.NDArray[np.float32]:
    """A ``sensor_msgs/msg/LaserScan`` as the server's depth profile.

    The profile's ``n_rays`` bearings span ``fov_deg`` evenly, leftmost (``+fov/2``) first,
    as :func:`server.motion.ray_angles` reads them. Each takes the nearest valid range among the
    scan's rays within half a profile ray of it (the nearest obstacle there, what avoidance
    needs), or else the scan ray nearest to it within one scan increment; a bearing the scan
    does not cover reads ``inf``. NaN, ``+inf`` and ranges outside
    ``[range_min, range_max]`` read ``inf``; ``-inf`` (REP 117: too close to measure) reads
    ``range_min``.

    Args:
        ranges: ``(n,)`` metres, ray ``i`` at ``angle_min + i * angle_increment`` radians
            counter-clockwise in the scan's frame.
        yaw_rad: the scan frame's heading on the robot (0 when its x axis looks forward).

    Returns:
        ``(n_rays,)`` float32 metres, left to right, ``inf`` where nothing was seen.
    """
    r = np.asarray(ranges, dtype=np.float64).ravel()
    out = np.full(n_rays, np.inf, dtype=np.float64)
    if r.size == 0 or n_rays <= 0:
        return out.astype(np.float32)
    angles = _wrap(angle_min + angle_increment * np.arange(r.size) + yaw_rad)
    valid = np.isfinite(r) & (r >= range_min) & (r <= range_max)
    clean = np.where(valid, r, np.inf)
    clean[np.isneginf(r)] = max(range_min, 0.0)
    half = math.radians(fov_deg) / 2
    targets = np.linspace(half, -half, n_rays) if n_rays > 1 else np.zeros(1)
    spacing = 2 * half / (n_rays - 1) if n_rays > 1 else 2 * half
    gap = np.abs(_wrap(angles[None, :] - targets[:, None]))  # (n_rays, n)
    within = gap <= spacing / 2 + 1e-9
    binned = np.where(within, clean[None, :], np.inf).min(axis=1)
    nearest = np.argmin(gap, axis=1)
    reach = abs(angle_increment) if r.size > 1 else spacing / 2
    fallback = np.where(gap[np.arange(n_rays), nearest] <= reach + 1e-9, clean[nearest], np.inf)
    out = np.where(within.any(axis=1), binned, fallback)
    return out.astype(np.float32)


def _wrap(angle: Any) -> Any:
    return np.arctan2(np.sin(angle), np.cos(angle))


# -- odometry ------------------------------------------------------------------------------------


class PoseOdometry:
    """The mean ``(v, w)`` between readings, from a stream of odometry poses.

    Each pose adds the step from the one before: its length along the mean heading (negative
    backwards) and its wrapped change of heading. A step that would mean more than the wire's
    limits (``server.schemas.MAX_LINEAR_SPEED`` / ``MAX_ANGULAR_SPEED``: an odometry reset, a
    jump) is left out. Thread-safe: poses come from CycloneDDS's thread.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._last: tuple[float, float, float, float] | None = None  # t, x, y, yaw
        self._t0: float | None = None
        self._dist = 0.0
        self._turn = 0.0
        self.count = 0
        """Poses received."""

    def add(self, stamp_s: float, x: float, y: float, yaw: float) -> None:
        """One pose at ``stamp_s`` seconds: ``(x, y)`` metres, ``yaw`` radians."""
        with self._lock:
            self.count += 1
            last = self._last
            self._last = (stamp_s, x, y, yaw)
            if last is None or self._t0 is None:
                self._t0 = stamp_s
                return
            dt = stamp_s - last[0]
            dyaw = float(_wrap(yaw - last[3]))
            mid = last[3] + dyaw / 2
            step = (x - last[1]) * math.cos(mid) + (y - last[2]) * math.sin(mid)
            if dt <= 0:
                if dt < 0:  # the stamps went back (a restarted publisher): start again here
                    self._t0 = stamp_s
                return
            if abs(step) / dt > MAX_LINEAR_SPEED or abs(dyaw) / dt > MAX_ANGULAR_SPEED:
                return
            self._dist += step
            self._turn += dyaw

    def mean(self) -> tuple[float, float]:
        """``(v, w)`` m/s and rad/s from the last reading's pose to the newest one; ``(0, 0)``
        when no pose came since."""
        with self._lock:
            if self._last is None or self._t0 is None:
                return 0.0, 0.0
            elapsed = self._last[0] - self._t0
            dist, turn = self._dist, self._turn
            self._dist = self._turn = 0.0
            self._t0 = self._last[0]
        if elapsed <= 0:
            return 0.0, 0.0
        return dist / elapsed, turn / elapsed
