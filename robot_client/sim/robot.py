"""A simulated differential-drive robot with one forward camera, living in a :class:`SimWorld`.

Kinematic: a commanded ``(v, w)`` is executed (with a little actuation noise) by integrating the
unicycle model in small sub-steps; a sub-step that would put the robot's disk into a wall or a
piece of furniture slides along it when it can and is dropped when it cannot, so the robot never
passes through anything. Time is simulated: :meth:`SimulatedRobot.sleep` advances it.

It implements the driver Protocols of :mod:`robot_client.drivers.base` (Camera, Motors,
DepthSensor, Clock), so the robot loop cannot tell it from hardware. ``pose`` is the ground truth,
for tests and benchmarks only; a navigation stack must not read it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from robot_client.sim.world import PlanGeometry, Pose, SimWorld


@dataclass(frozen=True)
class RobotParams:
    """The simulated base and its sensors.

    Attributes:
        radius_m: radius of the robot's disk footprint, metres.
        max_v: largest |linear velocity|, m/s. max_w: largest |angular velocity|, rad/s.
        actuation_noise: std of the fractional error between commanded and executed (v, w),
            drawn once per :meth:`SimulatedRobot.sleep` call.
        odom_noise_v, odom_noise_w: std of the fractional error of reported odometry.
        substep_s: integration step, seconds (keeps every step far shorter than a wall is thick).
        pixel_noise_std: std of Gaussian camera noise, grey levels (0 = clean frames).
        depth_noise_std_m: std of Gaussian range noise, metres.
    """

    radius_m: float = 0.18
    max_v: float = 0.5
    max_w: float = 1.5
    actuation_noise: float = 0.03
    odom_noise_v: float = 0.05
    odom_noise_w: float = 0.08
    substep_s: float = 0.02
    pixel_noise_std: float = 2.0
    depth_noise_std_m: float = 0.01


class SimulatedRobot:
    """A robot in a simulated home (Camera, Motors, DepthSensor and Clock in one object).

    Args:
        world: the home it lives in (not owned: :meth:`close` leaves it open). A
            :class:`PlanGeometry` gives a robot without camera or depth sensor (collisions
            only), for walking a route quickly.
        pose: starting ground-truth pose; must be collision-free.
        params: base and sensor parameters.
        seed: seeds every noise source; same seed + same calls -> same poses and frames.

    Raises:
        ValueError: ``pose`` overlaps a wall or furniture.
    """

    def __init__(
        self,
        world: SimWorld | PlanGeometry,
        pose: Pose,
        *,
        params: RobotParams = RobotParams(),
        seed: int = 0,
    ) -> None:
        self.world = world
        self.params = params
        self._rng = np.random.default_rng(seed)
        self._check_free(pose)
        self.pose: Pose = pose
        """Ground-truth pose (metres, radians); for tests and benchmarks only."""
        self.odometer: float = 0.0
        """Total distance actually driven, metres."""
        self.blocked_time: float = 0.0
        """Simulated seconds during which motion was stopped by an obstacle."""
        self._t = 0.0
        self._v = 0.0
        self._w = 0.0
        self._odom_dist = 0.0
        self._odom_turn = 0.0
        self._odom_t0 = 0.0
        self._closed = False

    # -- Camera ----------------------------------------------------------------------------------

    def read(self) -> npt.NDArray[np.uint8] | None:
        """The camera frame at the current pose: ``(H, W, 3)`` uint8 BGR; ``None`` after close."""
        if self._closed:
            return None
        frame = self._world().render(self.pose)
        std = self.params.pixel_noise_std
        if std > 0:
            noise = self._rng.standard_normal(size=frame.shape, dtype=np.float32)
            noisy = frame.astype(np.float32) + std * noise
            frame = np.clip(noisy, 0, 255).astype(np.uint8)
        return frame

    def _world(self) -> SimWorld:
        if not isinstance(self.world, SimWorld):
            raise RuntimeError("this robot has no camera or depth sensor: give it a SimWorld")
        return self.world

    def reseed(self, seed: int) -> None:
        """Restart every noise source from ``seed`` (the pose, clock and odometer carry on):
        a benchmark makes each trial's noise independent of how the trials before it went."""
        self._rng = np.random.default_rng(seed)

    def close(self) -> None:
        """Stop and release the camera. Safe to call twice. The world stays open."""
        self.stop()
        self._closed = True

    # -- Motors ----------------------------------------------------------------------------------

    def command(self, v: float, w: float) -> None:
        """Drive at ``v`` m/s and ``w`` rad/s (clipped to the limits) until the next command."""
        p = self.params
        self._v = float(np.clip(v, -p.max_v, p.max_v))
        self._w = float(np.clip(w, -p.max_w, p.max_w))

    def odometry(self) -> tuple[float, float]:
        """Measured mean ``(v, w)`` since the last call, m/s and rad/s, with multiplicative noise.

        A robot pushing against a wall reports (nearly) zero forward speed: wheels that cannot
        turn do not count distance.
        """
        elapsed = self._t - self._odom_t0
        dist, turn = self._odom_dist, self._odom_turn
        self._odom_dist = self._odom_turn = 0.0
        self._odom_t0 = self._t
        if elapsed <= 0:
            return 0.0, 0.0
        ev, ew = self._rng.normal(0.0, (self.params.odom_noise_v, self.params.odom_noise_w))
        return float(dist / elapsed * (1 + ev)), float(turn / elapsed * (1 + ew))

    def stop(self) -> None:
        """Stop at once."""
        self._v = self._w = 0.0

    # -- DepthSensor -----------------------------------------------------------------------------

    def profile(self) -> npt.NDArray[np.float32]:
        """``(n_rays,)`` float32 ranges in metres, leftmost first; ``inf`` beyond range."""
        ranges = self._world().depth_profile(self.pose)
        std = self.params.depth_noise_std_m
        if std > 0:
            finite = np.isfinite(ranges)
            noise = self._rng.normal(0.0, std, size=ranges.shape).astype(np.float32)
            ranges = np.where(finite, np.maximum(ranges + noise, 0.0), ranges).astype(np.float32)
        return ranges

    # -- Clock -----------------------------------------------------------------------------------

    def now(self) -> float:
        """Simulated seconds since the robot was created."""
        return self._t

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` of simulated time pass, executing the current command.

        Integrates the unicycle model in sub-steps of at most ``substep_s``; a sub-step that would
        collide slides along the obstacle (keeps the free axis of the motion) or is dropped.
        """
        if seconds <= 0:
            return
        p = self.params
        n = max(1, math.ceil(seconds / p.substep_s - 1e-9))
        h = seconds / n
        moving = self._v != 0.0 or self._w != 0.0
        if moving and p.actuation_noise > 0:
            ev, ew = (float(e) for e in self._rng.normal(0.0, p.actuation_noise, size=2))
        else:
            ev = ew = 0.0
        v, w = self._v * (1 + ev), self._w * (1 + ew)
        x, y, th = self.pose.x, self.pose.y, self.pose.theta
        for _ in range(n):
            if v != 0.0:
                if abs(w) < 1e-9:
                    nx, ny = x + v * h * math.cos(th), y + v * h * math.sin(th)
                else:
                    r = v / w
                    nx = x + r * (math.sin(th + w * h) - math.sin(th))
                    ny = y - r * (math.cos(th + w * h) - math.cos(th))
                nx, ny = self._resolve(x, y, nx, ny)
                dx, dy = nx - x, ny - y
                step = math.hypot(dx, dy)
                if step < 0.5 * abs(v) * h:
                    self.blocked_time += h
                self.odometer += step
                self._odom_dist += dx * math.cos(th) + dy * math.sin(th)
                x, y = nx, ny
            th += w * h
            self._odom_turn += w * h
        self.pose = Pose(x, y, _wrap(th))
        self._t += seconds

    def _resolve(self, x: float, y: float, nx: float, ny: float) -> tuple[float, float]:
        """Where a sub-step from ``(x, y)`` towards ``(nx, ny)`` really ends (slide or stay)."""
        r = self.params.radius_m
        world = self.world
        if not world.collides(nx, ny, r):
            return nx, ny
        options = [(nx, y), (x, ny)]
        options.sort(key=lambda q: -abs(q[0] - x) - abs(q[1] - y))
        for qx, qy in options:
            if (qx, qy) != (x, y) and not world.collides(qx, qy, r):
                return qx, qy
        return x, y

    # -- simulation only -------------------------------------------------------------------------

    def teleport(self, pose: Pose) -> None:
        """Carry the robot elsewhere ("kidnapping"): motors stop, odometry does not notice.

        Raises:
            ValueError: ``pose`` overlaps a wall or furniture.
        """
        self._check_free(pose)
        self.stop()
        self.pose = pose

    def _check_free(self, pose: Pose) -> None:
        if self.world.collides(pose.x, pose.y, self.params.radius_m):
            raise ValueError(
                f"pose ({pose.x:.2f}, {pose.y:.2f}) overlaps a wall or furniture for a robot of "
                f"radius {self.params.radius_m} m; pick a free pose (SimWorld.free_random_pose)"
            )


def _wrap(angle: float) -> float:
    """``angle`` wrapped to ``(-pi, pi]``."""
    return math.atan2(math.sin(angle), math.cos(angle))
