"""The simulated robot as a ROS 2 robot on DDS: ``teachrepeat sim ros2-robot``.

:class:`SimRos2Robot` puts a :class:`~robot_client.sim.robot.SimulatedRobot` in a
:class:`~robot_client.sim.world.SimWorld` on a DDS domain, the way a ROS 2 base with a camera
and a laser shows itself, and advances the simulation in real time:

* ``/camera/image_raw/compressed`` (``sensor_msgs/msg/CompressedImage``, JPEG) and
  ``/camera/image_raw`` (``sensor_msgs/msg/Image``, ``bgr8``): its frames, each sent only while
  someone reads that topic (as image_transport does), sensor-data QoS;
* ``/odom`` (``nav_msgs/msg/Odometry``): dead reckoning from the robot's *reported* odometry
  (noisy, starting at the origin of its own ``odom`` frame), never its true pose; reliable;
* ``/scan`` (``sensor_msgs/msg/LaserScan``): its depth profile, sensor-data QoS;
* ``/cmd_vel`` (``geometry_msgs/msg/Twist``), obeyed until ``cmd_timeout_s`` passes without one
  (then it stops, as many bases do); read reliably, as ROS 2 nodes subscribe by default.

DDS stays on this machine by default (``interface="lo"``: loopback only, set by the code). The
simulator's truth, :attr:`SimRos2Robot.true_pose`, is for judges and tests only.

Use it from Python as a context manager::

    with SimRos2Robot(load_plan(path), domain_id=17) as sim:
        ...  # a driver on domain 17, interface lo, drives it; sim.true_pose judges it
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

from robot_client.sim.floorplan import FloorPlan
from robot_client.sim.robot import RobotParams, SimulatedRobot
from robot_client.sim.world import CameraParams, Pose, SimWorld


@dataclass(frozen=True)
class Ros2Topics:
    """ROS 2 topic names the simulated robot uses (the ``ros2`` driver's defaults)."""

    camera: str = "/camera/image_raw"
    """Raw ``Image`` topic; the ``CompressedImage`` one is this plus ``/compressed``."""
    odom: str = "/odom"
    scan: str = "/scan"
    cmd: str = "/cmd_vel"


@dataclass(frozen=True)
class SimRos2Params:
    """How the simulated ROS 2 robot runs.

    Attributes:
        camera_hz: frames per second published (10).
        odom_hz: odometry messages per second (20).
        scan_hz: scans per second (10).
        step_s: real-time step of the simulation, seconds (0.02).
        cmd_timeout_s: stop when no ``cmd_vel`` came for this long, seconds (0.5).
        jpeg_quality: of the compressed frames (90).
    """

    camera_hz: float = 10.0
    odom_hz: float = 20.0
    scan_hz: float = 10.0
    step_s: float = 0.02
    cmd_timeout_s: float = 0.5
    jpeg_quality: int = 90


_ROBOT = RobotParams()
_CAMERA = CameraParams()


class SimRos2Robot:
    """A simulated home's robot, published on a DDS domain as a ROS 2 robot.

    Args:
        plan: the home.
        start: starting true pose (default: the plan's first place).
        condition: ``same``, ``lighting`` or ``moved`` (:class:`SimWorld`).
        seed: noise seed of the robot.
        domain_id: ROS 2 domain id.
        interface: ``"lo"`` (default: this machine only), a network interface name, or ``""``
            for CycloneDDS's defaults.
        topics, params, robot, camera: topic names, rates, base and sensor parameters.

    :meth:`start` (or ``with``) builds the world and starts publishing in a thread of its own
    (MuJoCo renders in the thread that made its context); :meth:`stop` ends it.
    """

    def __init__(
        self,
        plan: FloorPlan,
        *,
        start: Pose | None = None,
        condition: str = "same",
        seed: int = 0,
        domain_id: int = 0,
        interface: str = "lo",
        topics: Ros2Topics = Ros2Topics(),
        params: SimRos2Params = SimRos2Params(),
        robot: RobotParams = _ROBOT,
        camera: CameraParams = _CAMERA,
    ) -> None:
        if start is None:
            first = plan.places[0]
            start = Pose(first.x, first.y, first.yaw)
        self.plan = plan
        self.condition = condition
        self.seed = seed
        self.domain_id = domain_id
        self.interface = interface
        self.topics = topics
        self.params = params
        self.robot_params = robot
        self.camera = camera
        self._lock = threading.Lock()
        self._pose = start
        self._teleport: Pose | None = None
        self._cmd: tuple[float, float, float] | None = None  # v, w, when (monotonic)
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None
        self.commands = 0
        """``cmd_vel`` messages received."""
        self.frames = 0
        """Camera frames published (either topic)."""
        self.scans = 0
        """Scans published."""
        self.odometry = 0
        """Odometry messages published."""

    # -- lifecycle ---------------------------------------------------------------------------------

    def start(self, *, timeout_s: float = 60.0) -> SimRos2Robot:
        """Build the world, join the domain and start publishing; return once it runs.

        Raises:
            RuntimeError: it did not start within ``timeout_s`` seconds.
            Exception: what building the world or joining the domain raised.
        """
        if self._thread is not None:
            raise RuntimeError("this simulated robot has already been started")
        self._thread = threading.Thread(target=self._run, name="sim-ros2-robot", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s):
            self.stop()
            raise RuntimeError(f"the simulated ROS 2 robot did not start in {timeout_s:g} s")
        if self._error is not None:
            self._thread.join()
            raise self._error
        return self

    def stop(self) -> None:
        """Stop publishing and release the world and the DDS participant. Safe to call twice."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=10.0)

    def __enter__(self) -> SimRos2Robot:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    @property
    def error(self) -> BaseException | None:
        """What stopped the simulation thread, if something did."""
        return self._error

    @property
    def running(self) -> bool:
        """Whether the simulation thread is running."""
        return self._thread is not None and self._thread.is_alive() and self._ready.is_set()

    # -- the judge's view --------------------------------------------------------------------------

    @property
    def true_pose(self) -> Pose:
        """The robot's true pose (metres, radians): for judges and tests only, never for the
        robot's own software."""
        with self._lock:
            return self._pose

    def teleport(self, pose: Pose) -> None:
        """Carry the robot to ``pose`` ("kidnapping"): its odometry does not notice. Takes
        effect at the next simulation step."""
        with self._lock:
            self._teleport = pose

    # -- the simulation thread ---------------------------------------------------------------------

    def _on_cmd(self, reader: Any) -> None:
        for msg in reader.take(N=10):
            if hasattr(msg, "linear"):
                with self._lock:
                    self._cmd = (float(msg.linear.x), float(msg.angular.z), time.monotonic())
                    self.commands += 1

    def _run(self) -> None:
        from robot_client.drivers import ros2_dds as m
        from robot_client.drivers.ros2_convert import dds_topic

        closers: list[Any] = []
        try:
            world = SimWorld(self.plan, condition=self.condition, camera=self.camera)
            closers.append(world.close)
            robot = SimulatedRobot(world, self._pose, params=self.robot_params, seed=self.seed)
            node = m.DdsNode(self.domain_id, interface=self.interface)
            closers.append(node.close)
            t = self.topics
            writers = {
                "raw": node.writer(dds_topic(t.camera), m.Image, qos=m.sensor_qos()),
                "jpeg": node.writer(
                    dds_topic(t.camera + "/compressed"), m.CompressedImage, qos=m.sensor_qos()
                ),
                "odom": node.writer(dds_topic(t.odom), m.Odometry, qos=m.command_qos()),
                "scan": node.writer(dds_topic(t.scan), m.LaserScan, qos=m.sensor_qos()),
            }
            # as a ROS 2 node subscribes by default: reliable, keep last 10
            cmd_reader = node.reader(
                dds_topic(t.cmd), m.Twist, on_data=self._on_cmd, qos=m.command_qos(reader=True)
            )
        except BaseException as exc:
            self._error = exc
            self._ready.set()
            for close in reversed(closers):
                close()
            return
        self._ready.set()
        try:
            _Loop(self, robot, writers, m).run()
        except BaseException as exc:
            self._error = exc
            raise
        finally:
            del cmd_reader  # held until here: CycloneDDS deletes a reader Python collects
            robot.close()
            for close in reversed(closers):
                close()


class _Loop:
    """The real-time loop of one :class:`SimRos2Robot` (its thread only)."""

    def __init__(self, sim: SimRos2Robot, robot: SimulatedRobot, writers: Any, m: Any) -> None:
        self.sim = sim
        self.robot = robot
        self.w = writers
        self.m = m
        self.epoch = time.time()  # stamps: the wall time the simulation started + its time
        self.odom = (0.0, 0.0, 0.0)  # dead-reckoned x, y, yaw in the robot's odom frame
        self.odom_t = 0.0

    def _stamp(self) -> Any:
        return self.m.Header(
            stamp=self.m.Time.from_seconds(self.epoch + self.robot.now()), frame_id=""
        )

    def run(self) -> None:
        sim, p = self.sim, self.sim.params
        last = time.monotonic()
        due = {"odom": last, "scan": last, "camera": last}
        period = {"odom": 1 / p.odom_hz, "scan": 1 / p.scan_hz, "camera": 1 / p.camera_hz}
        while not sim._stop.is_set():
            now = time.monotonic()
            with sim._lock:
                cmd = sim._cmd
                jump, sim._teleport = sim._teleport, None
            if jump is not None:
                self.robot.teleport(jump)
            fresh = cmd is not None and now - cmd[2] <= p.cmd_timeout_s
            self.robot.command(*(cmd[:2] if fresh and cmd is not None else (0.0, 0.0)))
            self.robot.sleep(max(0.0, now - last))
            last = now
            with sim._lock:
                sim._pose = self.robot.pose
            for what, publish in (
                ("odom", self._odometry),
                ("scan", self._scan),
                ("camera", self._camera),
            ):
                if now >= due[what]:
                    publish()
                    due[what] = max(due[what] + period[what], now)
            sim._stop.wait(max(0.0, last + p.step_s - time.monotonic()))

    def _odometry(self) -> None:
        m = self.m
        v, w = self.robot.odometry()
        dt = self.robot.now() - self.odom_t
        self.odom_t = self.robot.now()
        x, y, yaw = self.odom
        mid = yaw + w * dt / 2
        x, y = x + v * dt * math.cos(mid), y + v * dt * math.sin(mid)
        yaw = math.atan2(math.sin(yaw + w * dt), math.cos(yaw + w * dt))
        self.odom = (x, y, yaw)
        header = self._stamp()
        header.frame_id = "odom"
        msg = m.Odometry(
            header=header,
            child_frame_id="base_link",
            pose=m.PoseWithCovariance(
                pose=m.Pose(position=m.Point(x=x, y=y), orientation=m.Quaternion.from_yaw(yaw))
            ),
            twist=m.TwistWithCovariance(
                twist=m.Twist(linear=m.Vector3(x=v), angular=m.Vector3(z=w))
            ),
        )
        self.w["odom"].write(msg)
        self.sim.odometry += 1

    def _scan(self) -> None:
        m, cam = self.m, self.sim.camera
        profile = self.robot.profile()  # left to right; a scan runs counter-clockwise
        half = math.radians(cam.depth_fov_deg) / 2
        n = len(profile)
        header = self._stamp()
        header.frame_id = "base_scan"
        msg = m.LaserScan(
            header=header,
            angle_min=-half,
            angle_max=half,
            angle_increment=2 * half / (n - 1) if n > 1 else 0.0,
            time_increment=0.0,
            scan_time=1 / self.sim.params.scan_hz,
            range_min=0.05,
            range_max=cam.max_range_m,
            ranges=[float(r) for r in profile[::-1]],
            intensities=[],
        )
        self.w["scan"].write(msg)
        self.sim.scans += 1

    def _camera(self) -> None:
        from server.imaging import encode_jpeg

        m = self.m
        readers = {
            k: self.w[k].get_publication_matched_status().current_count for k in ("jpeg", "raw")
        }
        if not any(readers.values()):
            return
        frame = self.robot.read()
        if frame is None:
            return
        header = self._stamp()
        header.frame_id = "camera_optical_frame"
        if readers["jpeg"]:
            data = encode_jpeg(frame, self.sim.params.jpeg_quality)
            self.w["jpeg"].write(m.CompressedImage(header=header, format="jpeg", data=list(data)))
        if readers["raw"]:
            h, w = frame.shape[:2]
            self.w["raw"].write(
                m.Image(
                    header=header,
                    height=h,
                    width=w,
                    encoding="bgr8",
                    is_bigendian=0,
                    step=w * 3,
                    data=list(frame.tobytes()),
                )
            )
        self.sim.frames += 1


# -- the command ---------------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from robot_client.sim.check_plan import add_plan_argument
    from robot_client.sim.floorplan import CONDITIONS

    add_plan_argument(parser)
    parser.add_argument(
        "--start",
        default=None,
        metavar="PLACE",
        help="place the robot starts at (default: the plan's first place)",
    )
    parser.add_argument("--condition", choices=CONDITIONS, default="same")
    parser.add_argument("--seed", type=int, default=0, help="noise seed of the robot")
    parser.add_argument(
        "--ros2-domain", type=int, default=0, help="ROS 2 domain id, 0-232 (default 0)"
    )
    parser.add_argument(
        "--ros2-interface",
        default="lo",
        metavar="NAME",
        help="network interface for DDS (default lo: this machine only)",
    )
    parser.add_argument(
        "--seconds",
        type=float,
        default=None,
        help="stop after this long (default: run until Ctrl-C)",
    )


def run(args: argparse.Namespace) -> int:
    from robot_client.sim.check_plan import load_plans_or_exit

    plan = load_plans_or_exit([args.plan], "teachrepeat sim ros2-robot")[0]
    start = None
    if args.start is not None:
        try:
            place = plan.place(args.start)
        except KeyError as exc:
            print(f"teachrepeat sim ros2-robot: {exc.args[0]}", file=sys.stderr)
            return 2
        start = Pose(place.x, place.y, place.yaw)
    if not 0 <= args.ros2_domain <= 232:
        print("teachrepeat sim ros2-robot: --ros2-domain runs from 0 to 232", file=sys.stderr)
        return 2
    sim = SimRos2Robot(
        plan,
        start=start,
        condition=args.condition,
        seed=args.seed,
        domain_id=args.ros2_domain,
        interface=args.ros2_interface,
    )
    with sim:
        t = sim.topics
        where = Path(args.plan).name if args.plan else "the packaged apartment"
        print(
            f"simulated ROS 2 robot in {where} on domain {args.ros2_domain}"
            f" ({args.ros2_interface or 'default interfaces'}): publishing {t.camera}/compressed, "
            f"{t.camera}, {t.odom}, {t.scan}; obeying {t.cmd}. Ctrl-C ends it.",
            flush=True,
        )
        deadline = None if args.seconds is None else time.monotonic() + args.seconds
        while sim.running and (deadline is None or time.monotonic() < deadline):
            time.sleep(0.2)
    if sim.error is not None:
        print(f"teachrepeat sim ros2-robot: the simulation stopped: {sim.error}", file=sys.stderr)
        return 1
    return 0
