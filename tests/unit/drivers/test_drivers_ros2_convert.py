"""ROS 2 messages -> the driver contract: topic names, images, scans, odometry (no DDS)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from robot_client.drivers.ros2_convert import (
    RAW_ENCODINGS,
    PoseOdometry,
    dds_topic,
    decode_compressed,
    decode_raw,
    ros_name_of,
    ros_topic,
    ros_type_name,
    scan_to_profile,
)
from server.motion import MotionParams, ray_angles

# -- names ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "dds"),
    [
        ("/cmd_vel", "rt/cmd_vel"),
        ("cmd_vel", "rt/cmd_vel"),
        ("/camera/image_raw/compressed", "rt/camera/image_raw/compressed"),
        ("/tb4_2/oakd/rgb/preview/image_raw", "rt/tb4_2/oakd/rgb/preview/image_raw"),
    ],
)
def test_ros_topics_map_to_dds_topics_with_the_rt_prefix(name: str, dds: str) -> None:
    assert dds_topic(name) == dds
    assert ros_name_of(dds) == ros_topic(name)


@pytest.mark.parametrize("bad", ["", "/", "a//b", "/a/", "1abc", "/cmd-vel", "~/odom", "a b"])
def test_names_that_are_not_ros2_topic_names_are_refused_with_an_example(bad: str) -> None:
    with pytest.raises(ValueError, match=r"is not a ROS 2 topic name.*such as /camera"):
        ros_topic(bad)


def test_dds_names_read_as_ros2_prints_them() -> None:
    assert ros_type_name("sensor_msgs::msg::dds_::CompressedImage_") == (
        "sensor_msgs/msg/CompressedImage"
    )
    assert ros_type_name("DDS::ParticipantBuiltinTopicData") == "DDS::ParticipantBuiltinTopicData"
    assert ros_name_of("rq/add_two_intsRequest") is None  # a service, not a topic


# -- images --------------------------------------------------------------------------------------


def _image() -> np.ndarray:
    rng = np.random.default_rng(3)
    return rng.integers(0, 256, size=(6, 8, 3), dtype=np.uint8)


@pytest.mark.parametrize("encoding", RAW_ENCODINGS)
def test_every_raw_encoding_decodes_to_the_same_bgr_image(encoding: str) -> None:
    bgr = _image()
    as_sent = {
        "bgr8": bgr,
        "rgb8": bgr[:, :, ::-1],
        "mono8": cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY),
        "bgra8": cv2.cvtColor(bgr, cv2.COLOR_BGR2BGRA),
        "rgba8": cv2.cvtColor(bgr, cv2.COLOR_BGR2RGBA),
    }
    if encoding.startswith("yuv"):  # 4:2:2 halves the colour: compare with OpenCV's own round trip
        yuv = cv2.cvtColor(bgr, cv2.COLOR_BGR2YUV)
        y, u, v = yuv[:, :, 0], yuv[:, :, 1], yuv[:, :, 2]
        packed = np.empty((6, 8, 2), np.uint8)
        if encoding == "yuv422":  # UYVY
            packed[:, :, 1] = y
            packed[:, 0::2, 0], packed[:, 1::2, 0] = u[:, 0::2], v[:, 0::2]
        else:  # YUY2 (YUYV)
            packed[:, :, 0] = y
            packed[:, 0::2, 1], packed[:, 1::2, 1] = u[:, 0::2], v[:, 0::2]
        sent = packed
        code = cv2.COLOR_YUV2BGR_UYVY if encoding == "yuv422" else cv2.COLOR_YUV2BGR_YUY2
        expected = cv2.cvtColor(packed, code)
    else:
        sent = np.ascontiguousarray(as_sent[encoding])
        expected = cv2.cvtColor(sent, cv2.COLOR_GRAY2BGR) if encoding == "mono8" else bgr
    channels = 1 if sent.ndim == 2 else sent.shape[2]
    out = decode_raw(encoding, 6, 8, 8 * channels, sent.tobytes())
    assert out.shape == (6, 8, 3) and out.dtype == np.uint8
    np.testing.assert_array_equal(out, expected)


def test_row_padding_past_the_width_is_dropped() -> None:
    bgr = _image()
    padded = np.zeros((6, 8 * 3 + 8), np.uint8)
    padded[:, : 8 * 3] = bgr.reshape(6, -1)
    np.testing.assert_array_equal(decode_raw("bgr8", 6, 8, 32, padded.tobytes()), bgr)


def test_raw_images_that_cannot_be_read_say_why() -> None:
    with pytest.raises(ValueError, match=r"unsupported Image encoding '16UC1'.*bgr8"):
        decode_raw("16UC1", 6, 8, 16, bytes(96))
    with pytest.raises(ValueError, match=r"8x6 bgr8 needs rows of at least 24 bytes.*got step 24"):
        decode_raw("bgr8", 6, 8, 24, bytes(100))


def test_compressed_jpeg_and_png_decode_to_bgr() -> None:
    bgr = np.zeros((48, 64, 3), np.uint8)
    bgr[:, :32] = (255, 0, 0)  # blue left half
    for ext in (".jpg", ".png"):
        ok, data = cv2.imencode(ext, bgr)
        assert ok
        out = decode_compressed("rgb8; jpeg compressed bgr8", data.tobytes())
        assert out.shape == (48, 64, 3)
        assert out[24, 10, 0] > 200 and out[24, 10, 2] < 50  # still blue: BGR order


def test_compressed_images_that_cannot_be_read_say_why() -> None:
    with pytest.raises(ValueError, match=r"depth images.*give a colour topic"):
        decode_compressed("16UC1; compressedDepth png", b"\x89PNG")
    with pytest.raises(ValueError, match=r"format 'jpeg' \(5 bytes\): JPEG and PNG"):
        decode_compressed("jpeg", b"hello")


# -- scans ---------------------------------------------------------------------------------------

FOV = MotionParams().depth_fov_deg


def test_a_scan_on_the_profiles_bearings_reads_left_to_right() -> None:
    """A scan runs counter-clockwise (right to left); the profile is leftmost first, at
    exactly the bearings the server reads it with (server.motion.ray_angles)."""
    n = 31
    bearings = ray_angles(n, FOV)  # left (+) to right (-)
    scan_angles = bearings[::-1]  # what a scanner sends: increasing angles
    ranges = 1.0 + scan_angles  # something different at every bearing
    out = scan_to_profile(
        ranges,
        angle_min=float(scan_angles[0]),
        angle_increment=float(scan_angles[1] - scan_angles[0]),
        range_min=0.1,
        range_max=10.0,
        n_rays=n,
        fov_deg=FOV,
    )
    assert out.dtype == np.float32 and out.shape == (n,)
    np.testing.assert_allclose(out, 1.0 + bearings, rtol=1e-6)
    assert out[0] > out[-1]  # the left reads the larger angles


def test_a_full_turn_scan_keeps_the_nearest_range_within_each_ray() -> None:
    angles = np.radians(np.arange(-180, 180, 0.5))
    ranges = np.full(angles.size, 3.0)
    ranges[np.abs(np.degrees(angles) - 30) < 1.0] = 0.6  # a chair leg 30 degrees left
    ranges[np.abs(np.degrees(angles) - 150) < 5] = 0.2  # behind: outside the field of view
    out = scan_to_profile(
        ranges,
        angle_min=float(angles[0]),
        angle_increment=math.radians(0.5),
        range_min=0.1,
        range_max=12.0,
        n_rays=31,
        fov_deg=FOV,
    )
    leg = int(np.argmin(np.abs(np.degrees(ray_angles(31, FOV)) - 30)))
    assert out[leg] == pytest.approx(0.6)
    assert np.all(np.delete(out, leg) == pytest.approx(3.0))


def test_rays_without_a_valid_range_read_inf_and_too_close_reads_range_min() -> None:
    ranges = np.array([1.0, np.nan, np.inf, 0.01, 50.0, -np.inf, 2.0])
    angles = np.radians([-45, -30, -15, 0, 15, 30, 45])
    out = scan_to_profile(
        ranges,
        angle_min=float(angles[0]),
        angle_increment=math.radians(15),
        range_min=0.1,
        range_max=20.0,
        n_rays=7,
        fov_deg=FOV,
    )
    np.testing.assert_array_equal(
        out, np.array([2.0, 0.1, np.inf, np.inf, np.inf, np.inf, 1.0], np.float32)
    )


def test_bearings_the_scan_does_not_cover_read_inf_and_coarse_scans_fill_in() -> None:
    narrow = scan_to_profile(
        np.ones(41),
        angle_min=math.radians(-20),
        angle_increment=math.radians(1),
        range_min=0.1,
        range_max=5.0,
        n_rays=31,
        fov_deg=FOV,
    )
    covered = np.abs(np.degrees(ray_angles(31, FOV))) <= 20 + 1.5  # within half a profile ray
    assert np.all(narrow[covered] == 1.0) and np.all(np.isinf(narrow[~covered]))
    coarse = scan_to_profile(
        np.ones(19),
        angle_min=math.radians(-90),
        angle_increment=math.radians(10),
        range_min=0.1,
        range_max=5.0,
        n_rays=31,
        fov_deg=FOV,
    )
    assert np.all(coarse == 1.0)  # every profile ray within one scan step of a scan ray


def test_a_scanner_mounted_turned_is_turned_back_with_its_yaw() -> None:
    """A scanner whose x axis looks left sees straight ahead at -90 degrees."""
    angles = np.radians(np.arange(-180, 180, 1.0))
    ranges = np.where(np.abs(np.degrees(angles) + 90) < 2, 0.5, 4.0)
    out = scan_to_profile(
        ranges,
        angle_min=float(angles[0]),
        angle_increment=math.radians(1),
        range_min=0.1,
        range_max=8.0,
        n_rays=31,
        fov_deg=FOV,
        yaw_rad=math.pi / 2,
    )
    assert out[15] == pytest.approx(0.5) and out[0] == pytest.approx(4.0)


# -- odometry ------------------------------------------------------------------------------------


def test_the_mean_velocity_comes_from_pose_differences_over_the_robots_stamps() -> None:
    odom = PoseOdometry()
    radius = 0.3 / 0.5  # 1 s at 0.3 m/s turning 0.5 rad/s, from a heading of 2 rad
    for k in range(11):
        yaw = 2.0 + 0.05 * k
        x = 1.0 + radius * (math.sin(yaw) - math.sin(2.0))
        y = -2.0 - radius * (math.cos(yaw) - math.cos(2.0))
        odom.add(100.0 + 0.1 * k, x, y, yaw)
    v, w = odom.mean()
    assert v == pytest.approx(0.3, rel=1e-3) and w == pytest.approx(0.5, rel=1e-6)
    assert odom.mean() == (0.0, 0.0)  # nothing since


def test_dropped_messages_change_nothing_and_backwards_is_negative() -> None:
    every, some = PoseOdometry(), PoseOdometry()
    for k in range(21):
        t, x = 0.05 * k, -0.01 * k  # backwards along x (heading 0) at 0.2 m/s
        every.add(t, x, 0.0, 0.0)
        if k % 3 == 0 or k == 20:  # a best-effort reader lost two messages in three
            some.add(t, x, 0.0, 0.0)
    assert every.mean() == pytest.approx((-0.2, 0.0))
    assert some.mean() == pytest.approx((-0.2, 0.0))


def test_turning_across_pi_wraps_and_resets_and_jumps_are_left_out() -> None:
    odom = PoseOdometry()
    odom.add(0.0, 0.0, 0.0, math.pi - 0.05)
    odom.add(0.1, 0.0, 0.0, -math.pi + 0.05)  # +0.1 rad, across the wrap
    odom.add(0.2, 50.0, 0.0, -math.pi + 0.05)  # the odometry was reset: 500 m/s is no motion
    v, w = odom.mean()
    assert v == pytest.approx(0.0) and w == pytest.approx(0.5)
    odom.add(0.05, 50.0, 0.0, 0.0)  # stamps went back (a restarted publisher): starts again
    odom.add(0.15, 50.1, 0.0, 0.0)
    assert odom.mean()[0] == pytest.approx(1.0)
