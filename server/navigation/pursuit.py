"""A path tracker: regulated pure pursuit on a taught path (after Nav2's Regulated Pure Pursuit).

Given the robot's pose relative to a taught path (in the path's frame, as the path tracking
filter estimates it: :mod:`server.navigation.tracking`) and where along the path it is, steer
toward the point ``lookahead_m`` further along: the curvature that reaches it is
``2 y / d^2`` (``y`` its sideways distance in the robot's frame, ``d`` its distance). Speed is
cut on tight curves, near obstacles, and close to the end of the route; a look-ahead point far
to the side or behind is turned to on the spot first. A robot beside the path steers back onto
it, so a disturbance (an obstacle avoided, a turn) leaves no lasting offset.

Pure: NumPy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from server.navigation.geometry import EdgePath, wrap

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class PursuitParams:
    """Path tracking settings; metres, m/s, rad/s.

    Attributes:
        lookahead_m (0.5), lookahead_per_m (0.5): the point steered at lies ``lookahead_m``
            along the path from the robot's nearest point, plus ``lookahead_per_m`` times the
            robot's distance from the path (a robot 2 m off it comes back at 53 degrees rather
            than square on).
        speed (0.3): forward speed on a straight path with nothing near.
        min_v (0.08): the slowest forward speed while tracking (below it the robot stands).
        max_w (1.0): largest turn rate.
        turn_in_place_rad (0.8): a look-ahead point further off the robot's heading than this
            is turned to on the spot first (at ``max_w``, slowing as it comes into line).
        curve_radius_m (0.8): on a curve tighter than this the speed is cut in proportion
            (regulated pure pursuit's curvature heuristic).
        slow_range_m (0.6), stop_range_m (0.25): the nearest depth reading below
            ``slow_range_m`` cuts the speed in proportion down to ``min_v`` at
            ``stop_range_m`` (obstacle avoidance itself still blends in afterwards).
        end_slow_m (0.6): within this of the route's end the speed falls in proportion, to
            ``min_v`` at the end.
    """

    lookahead_m: float = 0.5
    lookahead_per_m: float = 0.5
    speed: float = 0.3
    min_v: float = 0.08
    max_w: float = 1.0
    turn_in_place_rad: float = 0.8
    curve_radius_m: float = 0.8
    slow_range_m: float = 0.6
    stop_range_m: float = 0.25
    end_slow_m: float = 0.6

    def __post_init__(self) -> None:
        if not 0 < self.min_v <= self.speed:
            raise ValueError("need 0 < min_v <= speed")
        if self.lookahead_m <= 0 or self.max_w <= 0:
            raise ValueError("lookahead_m and max_w must be positive")


def lookahead_s(s: float, lateral: float, params: PursuitParams) -> float:
    """Metres along the path of the point steered at: ``lookahead_m + lookahead_per_m *
    |lateral|`` beyond ``s`` (not clamped)."""
    return s + params.lookahead_m + params.lookahead_per_m * abs(lateral)


def lookahead_point(path: EdgePath, s: float, lateral: float, params: PursuitParams) -> FloatArray:
    """``(2,)`` the point steered at, in the path's frame: :func:`lookahead_s` (clamped to
    the path's end)."""
    return path.point_at(lookahead_s(s, lateral, params))


def pursue(
    pose: npt.ArrayLike,
    target: npt.ArrayLike,
    *,
    params: PursuitParams,
    remaining_m: float = math.inf,
    nearest_m: float = math.inf,
) -> tuple[float, float]:
    """``(v, w)`` toward ``target`` ``(2,)`` from ``pose`` ``(3,)`` (one frame).

    Args:
        remaining_m: metres of the route left after the robot's nearest point (slows near
            the end).
        nearest_m: the nearest depth reading ahead (slows near obstacles); ``inf`` without.
    """
    x, y, th = (float(a) for a in np.asarray(pose, dtype=np.float64))
    tx, ty = (float(a) for a in np.asarray(target, dtype=np.float64))
    dx, dy = tx - x, ty - y
    c, s = math.cos(th), math.sin(th)
    fwd, left = c * dx + s * dy, -s * dx + c * dy
    d2 = fwd * fwd + left * left
    p = params
    if d2 < 1e-6:
        return 0.0, 0.0
    alpha = math.atan2(left, fwd)
    if abs(alpha) > p.turn_in_place_rad:
        w = math.copysign(p.max_w, alpha) * min(1.0, abs(alpha) / (2 * p.turn_in_place_rad) + 0.5)
        return 0.0, float(np.clip(w, -p.max_w, p.max_w))
    curvature = 2.0 * left / d2
    v = p.speed
    radius = 1.0 / abs(curvature) if curvature != 0 else math.inf
    if radius < p.curve_radius_m:
        v *= radius / p.curve_radius_m
    if nearest_m < p.slow_range_m:
        span = p.slow_range_m - p.stop_range_m
        v *= float(np.clip((nearest_m - p.stop_range_m) / span, 0.0, 1.0))
    if remaining_m < p.end_slow_m:
        v *= max(remaining_m, 0.0) / p.end_slow_m
    v = max(v, p.min_v)
    w = v * curvature
    if abs(w) > p.max_w:  # too tight at this speed: slow down to keep the curve
        v *= p.max_w / abs(w)
        w = math.copysign(p.max_w, w)
    return float(v), float(w)


def steer_to(heading_error: float, params: PursuitParams) -> float:
    """``w`` (rad/s) that brings the heading round by ``heading_error`` (rad, target minus
    current): proportional (gain 2 per second), within ``params.max_w``."""
    return float(np.clip(2.0 * heading_error, -params.max_w, params.max_w))


def turn_to(heading_error: float, params: PursuitParams) -> tuple[float, float]:
    """``(0, w)``: turn on the spot to remove ``heading_error`` (rad, target minus current),
    slowing as it comes into line (:func:`steer_to`, at least 0.15 rad/s)."""
    w = steer_to(heading_error, params)
    if 0 < abs(w) < 0.15:
        w = math.copysign(0.15, w)
    return 0.0, w


def heading_error(pose: npt.ArrayLike, heading: float) -> float:
    """``heading`` minus the pose's heading, wrapped (rad)."""
    return float(wrap(heading - float(np.asarray(pose)[2])))
