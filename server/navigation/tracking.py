"""Where the robot is relative to the taught path: a small Kalman filter in an edge's frame.

The state is the robot's pose ``(x, y, theta)`` in the frame of the edge it is tracking (the
edge's first taught image, :mod:`server.navigation.geometry`) with its ``(3, 3)`` covariance.
Between frames it is carried by the robot's odometry (:func:`predict`); every frame the camera
corrects it against taught images near where it is (:func:`update_heading`: the heading from the
features' rotation; :func:`update_bearing`: the direction of the robot from a taught camera,
:mod:`server.vision.relpose`). Bearings from taught cameras at different places along the path
fix the robot's offset from the path in metres (the odometry between the taught images gives
the scale). A measurement whose innovation the filter finds implausible (its squared
Mahalanobis distance beyond ``gate``) is not used.

Pure functions over arrays (the filterpy shape): ``predict(mean, cov, ...) -> (mean, cov)``,
``update_*(mean, cov, ...) -> Update``. NumPy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from server.navigation.geometry import wrap

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class OdometryNoise:
    """How uncertain the odometry is, per frame: standard deviations that grow with the motion.

    Attributes:
        along (0.08): metres per metre driven, along the motion.
        across (0.03): metres per metre driven, across it.
        turn (0.08): radians per radian turned.
        turn_per_m (0.03): radians per metre driven (wheel slip, uneven floors).
        floor_m (0.005), floor_rad (0.003): added every frame, also standing still (the
            estimate never grows surer than its measurements can make it).
    """

    along: float = 0.08
    across: float = 0.03
    turn: float = 0.08
    turn_per_m: float = 0.03
    floor_m: float = 0.005
    floor_rad: float = 0.003


def move(pose: npt.ArrayLike, v: float, w: float, dt: float) -> FloatArray:
    """``pose`` after driving ``v`` m/s and turning ``w`` rad/s for ``dt`` s (an exact arc)."""
    x, y, th = (float(a) for a in np.asarray(pose, dtype=np.float64))
    d, a = v * dt, w * dt
    chord = d * (math.sin(a / 2) / (a / 2) if abs(a) > 1e-9 else 1.0)
    mid = th + a / 2
    return np.array([x + chord * math.cos(mid), y + chord * math.sin(mid), float(wrap(th + a))])


def predict(
    mean: npt.ArrayLike,
    cov: npt.ArrayLike,
    v: float,
    w: float,
    dt: float,
    noise: OdometryNoise = OdometryNoise(),
) -> tuple[FloatArray, FloatArray]:
    """The pose ``(3,)`` and covariance ``(3, 3)`` carried by one odometry reading (``v``
    m/s, ``w`` rad/s for ``dt`` s)."""
    m = np.asarray(mean, dtype=np.float64)
    P = np.asarray(cov, dtype=np.float64)
    out = move(m, v, w, dt)
    d, a = abs(v * dt), abs(w * dt)
    mid = float(m[2]) + w * dt / 2
    c, s = math.cos(mid), math.sin(mid)
    # Jacobian of the motion w.r.t. the pose (the chord turns with the heading)
    F = np.eye(3)
    F[0, 2] = -(out[1] - m[1])
    F[1, 2] = out[0] - m[0]
    sa = noise.along * d + noise.floor_m
    sc = noise.across * d + noise.floor_m
    st = noise.turn * a + noise.turn_per_m * d + noise.floor_rad
    R = np.array([[c, -s], [s, c]])
    Q = np.zeros((3, 3))
    Q[:2, :2] = R @ np.diag([sa**2, sc**2]) @ R.T
    Q[2, 2] = st**2
    P2 = F @ P @ F.T + Q
    return out, 0.5 * (P2 + P2.T)


@dataclass(frozen=True)
class Update:
    """A measurement's effect: the corrected ``mean`` and ``cov``, the innovation (radians),
    its squared Mahalanobis distance ``nis``, and whether it was ``used`` (within the gate)."""

    mean: FloatArray
    cov: FloatArray
    innovation: float
    nis: float
    used: bool


def _scalar_update(
    m: FloatArray, P: FloatArray, H: FloatArray, innovation: float, sigma: float, gate: float
) -> Update:
    S = float(H @ P @ H) + sigma**2
    nis = innovation**2 / S
    if not math.isfinite(nis) or nis > gate:
        return Update(m, P, innovation, nis, False)
    K = (P @ H) / S
    mean = m + K * innovation
    mean[2] = float(wrap(mean[2]))
    I_KH = np.eye(3) - np.outer(K, H)
    cov = I_KH @ P @ I_KH.T + np.outer(K, K) * sigma**2  # Joseph form
    return Update(mean, 0.5 * (cov + cov.T), innovation, nis, True)


def update_heading(
    mean: npt.ArrayLike,
    cov: npt.ArrayLike,
    heading: float,
    sigma: float,
    *,
    gate: float = 9.0,
) -> Update:
    """Correct with a measured heading (radians, in the edge's frame; ``sigma`` its standard
    deviation)."""
    m = np.asarray(mean, dtype=np.float64).copy()
    P = np.asarray(cov, dtype=np.float64)
    H = np.array([0.0, 0.0, 1.0])
    return _scalar_update(m, P, H, float(wrap(heading - m[2])), sigma, gate)


def bearing_of(mean: npt.ArrayLike, taught: npt.ArrayLike) -> tuple[float, float, FloatArray]:
    """The direction of position ``mean[:2]`` from taught pose ``taught`` (radians, in the
    taught camera's frame, 0 ahead, positive left, modulo pi in ``[-pi/2, pi/2)``), its distance
    (m) and the ``(3,)`` Jacobian of the direction w.r.t. the pose."""
    m = np.asarray(mean, dtype=np.float64)
    t = np.asarray(taught, dtype=np.float64)
    c, s = math.cos(t[2]), math.sin(t[2])
    dx, dy = float(m[0] - t[0]), float(m[1] - t[1])
    fwd, left = c * dx + s * dy, -s * dx + c * dy
    r2 = fwd * fwd + left * left
    angle = math.atan2(left, fwd)
    half = (angle + math.pi / 2) % math.pi - math.pi / 2
    if r2 < 1e-12:
        return half, 0.0, np.zeros(3)
    # d(angle)/d(x, y): (fwd * d(left) - left * d(fwd)) / r^2
    H = np.array([(-fwd * s - left * c) / r2, (fwd * c - left * s) / r2, 0.0])
    return half, math.sqrt(r2), H


def update_bearing(
    mean: npt.ArrayLike,
    cov: npt.ArrayLike,
    taught: npt.ArrayLike,
    bearing: float,
    sigma: float,
    *,
    gate: float = 9.0,
    min_range_m: float = 0.15,
) -> Update:
    """Correct with the measured direction of the robot from taught pose ``taught`` (radians,
    modulo pi, as :func:`bearing_of` gives it; ``sigma`` its standard deviation). Not used
    (``used`` False) when the robot is predicted within ``min_range_m`` of the taught pose,
    where a direction says nothing."""
    m = np.asarray(mean, dtype=np.float64).copy()
    P = np.asarray(cov, dtype=np.float64)
    predicted, r, H = bearing_of(m, taught)
    innovation = (bearing - predicted + math.pi / 2) % math.pi - math.pi / 2
    if r < min_range_m:
        return Update(m, P, innovation, math.inf, False)
    return _scalar_update(m, P, H, innovation, sigma, gate)


def update_along(
    mean: npt.ArrayLike,
    cov: npt.ArrayLike,
    point: npt.ArrayLike,
    heading: float,
    sigma: float,
    *,
    gate: float = 9.0,
) -> Update:
    """Correct with a measured position along the path: the robot is level with ``point``
    ``(2,)`` on a path heading ``heading`` (rad) there, to within ``sigma`` metres along it
    (its offset across the path is not measured)."""
    m = np.asarray(mean, dtype=np.float64).copy()
    P = np.asarray(cov, dtype=np.float64)
    q = np.asarray(point, dtype=np.float64)
    H = np.array([math.cos(heading), math.sin(heading), 0.0])
    innovation = -float(H[:2] @ (m[:2] - q))
    return _scalar_update(m, P, H, innovation, sigma, gate)


def update_pose(
    mean: npt.ArrayLike,
    cov: npt.ArrayLike,
    pose: npt.ArrayLike,
    pose_cov: npt.ArrayLike,
    *,
    gate: float = 11.34,
) -> Update:
    """Correct with a measured pose ``(3,)`` and its covariance ``(3, 3)`` (a scan match).
    ``gate`` is on the squared Mahalanobis distance with three degrees of freedom (11.34: 99
    %); ``innovation`` reports the position part's length (m)."""
    m = np.asarray(mean, dtype=np.float64).copy()
    P = np.asarray(cov, dtype=np.float64)
    R = np.asarray(pose_cov, dtype=np.float64)
    y = np.asarray(pose, dtype=np.float64) - m
    y[2] = float(wrap(y[2]))
    S = P + R
    try:
        S_inv = np.linalg.inv(S)
    except np.linalg.LinAlgError:
        return Update(m, P, float(np.hypot(y[0], y[1])), math.inf, False)
    nis = float(y @ S_inv @ y)
    if not math.isfinite(nis) or nis > gate:
        return Update(m, P, float(np.hypot(y[0], y[1])), nis, False)
    K = P @ S_inv
    out = m + K @ y
    out[2] = float(wrap(out[2]))
    I_K = np.eye(3) - K
    P2 = I_K @ P @ I_K.T + K @ R @ K.T
    return Update(out, 0.5 * (P2 + P2.T), float(np.hypot(y[0], y[1])), nis, True)


def path_frame_cov(cov: npt.ArrayLike, heading: float) -> FloatArray:
    """``cov``'s position block turned into the path's frame at ``heading`` (along, left):
    ``(2, 2)``."""
    P = np.asarray(cov, dtype=np.float64)[:2, :2]
    c, s = math.cos(heading), math.sin(heading)
    R = np.array([[c, s], [-s, c]])
    out: FloatArray = R @ P @ R.T
    return out


def initial_cov(heading: float, along_m: float, lateral_m: float, heading_rad: float) -> FloatArray:
    """A starting covariance: standard deviations ``along_m`` along ``heading``, ``lateral_m``
    across it, and ``heading_rad`` in heading."""
    c, s = math.cos(heading), math.sin(heading)
    R = np.array([[c, -s], [s, c]])
    P = np.zeros((3, 3))
    P[:2, :2] = R @ np.diag([along_m**2, lateral_m**2]) @ R.T
    P[2, 2] = heading_rad**2
    return P
