"""From a decided action to wheel velocities (001 Sections 7.1-7.3). Pure: NumPy only.

* Navigate: visual homing. The horizontal displacement of features matched between the current
  frame and the target image steers the robot; it moves forward at a constant speed. With no
  matches it replays the motion recorded with the target image.
* RotateAndFindEdge: spin in place.
* Explore: head for open space (the longest range of the depth profile), or creep and turn
  when there is no depth sensor.
* DoNothing: stand still.
* Obstacle avoidance is blended into every moving command with a weight that grows as the
  nearest obstacle gets close, until it dominates.

Conventions: ``v`` m/s forward positive, ``w`` rad/s counter-clockwise (left) positive; depth
profiles are ``(n_rays,)`` ranges in metres from the leftmost ray to the rightmost.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class MotionParams:
    """Motion settings; speeds in m/s and rad/s, distances in metres.

    * ``cruise_v`` (0.25): forward speed along an edge when the taught speed is unknown.
    * ``follow_taught_speed`` (True): drive at the speed recorded with the target image
      (clipped to ``[min_v, max_v]``) so the belief advances as it did when taught.
    * ``homing_gain`` (1.5): rad/s per unit of normalised horizontal offset (offset 1 = the
      features are a whole image width away).
    * ``max_w`` (1.0): largest turn rate.
    * ``spin_w`` (0.5): turn rate of RotateAndFindEdge.
    * ``explore_v`` (0.15), ``explore_gain`` (1.0 rad/s per rad): Explore speed and steering.
    * ``avoid_start_m`` (0.55): obstacles nearer than this start to steer the robot away.
    * ``avoid_full_m`` (0.25): at this range avoidance has full weight and forward motion stops.
    * ``open_m`` (2.0): ranges are counted up to this far when avoidance picks the more open
      side (the side with the larger mean range, so a door beside the wall ahead wins).
    * ``avoid_switch_m`` (0.3): avoidance keeps turning the way it chose while obstacles stay
      near, unless the other side's mean range is larger by this much (see :func:`avoid_side`).
    * ``depth_fov_deg`` (90): field of view the depth rays span (evenly, left to right).
    * ``dock_v`` (0.12): speed of the last creep onto a place when the view says the robot
      stopped short of it or went past it (``NavigationParams.dock``).
    * ``backoff_v`` (0.1) and ``backoff_s`` (1.5 s): a robot that has driven against
      something it cannot see (``NavigationParams.bump_s``) backs off at this speed for this
      long, turning at ``spin_w`` toward the more open side (:func:`open_side`).
    * ``ttl_s`` (0.6): how long a command stays valid without a newer one.
    * ``found_similarity`` (0.5) and ``found_offset`` (0.06): RotateAndFindEdge has found its
      edge when the frame's similarity to the edge's departure image is at least the former
      and the homing offset to it at most the latter (about 5 degrees); the robot then drives
      onto the edge.
    * ``toward_matches`` (8) and ``toward_offset`` (0.25): while spinning, the turn slows and
      aims at the sought view only when its homing estimate rests on at least this many matches
      and is at most this far off (weaker estimates flip sign from frame to frame).
    * ``lost_similarity`` (0.25) and ``lost_steps`` (5): a robot driving onto an edge gives up
      and spins again after this many frames whose best match on the edge is below the former.
    * ``find_turns`` (1.25) and ``unstick_s`` (4 s): when RotateAndFindEdge has turned this many
      times without finding its edge, the start of the edge is not in sight from here; the
      robot explores toward open space for ``unstick_s`` and then looks again (001 7.1).
    * ``escape_turn_s`` (6 s), ``escape_aim_rad`` (0.2) and ``escape_go_s`` (2 s): an escape,
      after backing off, turns on the spot (at ``spin_w``) until the most open direction of the
      depth profile is within ``escape_aim_rad`` of straight ahead and at least
      ``avoid_start_m`` away, for at most ``escape_turn_s``, then explores that way for
      ``escape_go_s``.
    """

    cruise_v: float = 0.25
    follow_taught_speed: bool = True
    min_v: float = 0.1
    max_v: float = 0.4
    homing_gain: float = 1.5
    max_w: float = 1.0
    spin_w: float = 0.5
    explore_v: float = 0.15
    explore_gain: float = 1.0
    avoid_start_m: float = 0.55
    avoid_full_m: float = 0.25
    open_m: float = 2.0
    avoid_switch_m: float = 0.3
    depth_fov_deg: float = 90.0
    dock_v: float = 0.12
    backoff_v: float = 0.1
    backoff_s: float = 1.5
    ttl_s: float = 0.6
    found_similarity: float = 0.5
    found_offset: float = 0.06
    toward_matches: int = 8
    toward_offset: float = 0.25
    lost_similarity: float = 0.25
    lost_steps: int = 5
    find_turns: float = 1.25
    unstick_s: float = 4.0
    escape_turn_s: float = 6.0
    escape_aim_rad: float = 0.2
    escape_go_s: float = 2.0

    def __post_init__(self) -> None:
        if not 0 < self.avoid_full_m < self.avoid_start_m:
            raise ValueError("need 0 < avoid_full_m < avoid_start_m")
        if self.max_w <= 0 or self.spin_w <= 0 or self.ttl_s <= 0:
            raise ValueError("max_w, spin_w and ttl_s must be positive")


def ray_angles(n_rays: int, fov_deg: float) -> FloatArray:
    """``(n_rays,)`` ray bearings in radians, left (positive) to right (negative)."""
    half = math.radians(fov_deg) / 2
    if n_rays == 1:
        return np.zeros(1)
    return np.linspace(half, -half, n_rays)


def navigate_command(
    offset: float | None, *, taught_v: float, taught_w: float, params: MotionParams
) -> tuple[float, float]:
    """Visual homing along an edge: the taught motion plus a correction.

    The motion recorded with the current image (``taught_v``, ``taught_w``) is replayed as a
    feedforward term, so taught turns are repeated; ``offset`` (normalised horizontal
    displacement of the target image's features, target minus current: positive = they lie to
    the right, see :func:`server.vision.homing.homing_offset`) adds ``homing_gain * offset``
    to the turn rate. With no features matched (``offset`` None) the taught motion alone is
    replayed (001 Section 7.2).
    """
    if params.follow_taught_speed:
        # replay the taught motion (turns on the spot included) as the feedforward term
        v = float(np.clip(taught_v, 0.0, params.max_v))
        if 0 < v < params.min_v:
            v = params.min_v
    else:
        v = params.cruise_v
    w = taught_w
    if offset is not None:
        w = taught_w + params.homing_gain * offset
    return v, float(np.clip(w, -params.max_w, params.max_w))


def rotate_command(params: MotionParams, *, toward: float | None = None) -> tuple[float, float]:
    """Spin in place: counter-clockwise, or toward the sought view when its homing offset
    ``toward`` is known (slowing down as it comes into line)."""
    if toward is None:
        return 0.0, params.spin_w
    w = params.homing_gain * toward
    return 0.0, float(np.clip(w, -params.spin_w, params.spin_w))


def _ranges(depth: npt.ArrayLike | None) -> FloatArray | None:
    """The depth profile as ``(n_rays,)`` metres, a ray that saw nothing (inf, nan) as far
    away; ``None`` without a depth sensor or with an empty profile."""
    if depth is None or len(np.atleast_1d(depth)) == 0:
        return None
    ranges = np.asarray(depth, dtype=np.float64)
    return np.where(np.isfinite(ranges), ranges, 1e3)


def _smooth(ranges: FloatArray) -> FloatArray:
    """Ranges averaged over an eighth of the rays: a single long ray through a gap does not win
    over a wide open side."""
    k = max(1, len(ranges) // 8)
    return np.convolve(ranges, np.ones(k) / k, mode="same")


def open_heading(depth: npt.ArrayLike | None, params: MotionParams) -> tuple[float, float] | None:
    """Where to turn to face open space: ``(bearing, range)``, radians (left positive) and
    metres, of the most open direction with every ray counted up to ``open_m`` and smoothed
    over an eighth of the rays; of directions within 5 % of the most open, the one nearest
    straight ahead (in a wide open room: straight on). ``None`` without a profile."""
    ranges = _ranges(depth)
    if ranges is None:
        return None
    smooth = _smooth(np.minimum(ranges, params.open_m))
    angles = ray_angles(len(ranges), params.depth_fov_deg)
    near_best = smooth >= 0.95 * smooth.max()
    best = int(np.argmin(np.where(near_best, np.abs(angles), np.inf)))
    return float(angles[best]), float(smooth[best])


def explore_command(depth: npt.ArrayLike | None, params: MotionParams) -> tuple[float, float]:
    """Head for the most open direction of the depth profile; without one, creep and turn."""
    ranges = _ranges(depth)
    if ranges is None:
        return params.explore_v, params.spin_w / 2
    smooth = _smooth(ranges)
    bearing = float(ray_angles(len(ranges), params.depth_fov_deg)[int(np.argmax(smooth))])
    w = float(np.clip(params.explore_gain * bearing, -params.max_w, params.max_w))
    if smooth.max() < params.avoid_start_m:  # boxed in: turn on the spot
        return 0.0, params.spin_w
    return params.explore_v, w


def nearest_ahead(
    depth: npt.ArrayLike | None, params: MotionParams, half_angle_rad: float = 0.6
) -> float:
    """The nearest range (m) of the depth rays within ``half_angle_rad`` of straight ahead;
    ``inf`` without a depth profile (or nothing seen there)."""
    ranges = _ranges(depth)
    if ranges is None:
        return math.inf
    angles = ray_angles(len(ranges), params.depth_fov_deg)
    ahead = ranges[np.abs(angles) <= half_angle_rad]
    return float(ahead.min()) if len(ahead) else math.inf


def open_side(depth: npt.ArrayLike | None, params: MotionParams) -> int:
    """``+1`` when the left half of the depth profile is more open (mean range, each ray
    counted up to ``open_m``) than the right, else ``-1``; ``+1`` without a depth profile."""
    ranges = _ranges(depth)
    if ranges is None:
        return 1
    left, right = _openness(ranges, params, float(ranges.min()))
    return 1 if left >= right else -1


def _openness(ranges: FloatArray, params: MotionParams, empty: float) -> tuple[float, float]:
    """Mean range of the left and the right half of the profile, each ray counted up to
    ``open_m``; ``empty`` for a half without rays."""
    angles = ray_angles(len(ranges), params.depth_fov_deg)
    counted = np.minimum(ranges, params.open_m)
    left = float(counted[angles > 0].mean()) if np.any(angles > 0) else empty
    right = float(counted[angles < 0].mean()) if np.any(angles < 0) else empty
    return left, right


def avoid_side(depth: npt.ArrayLike | None, params: MotionParams, previous: int = 0) -> int:
    """Which way obstacle avoidance turns: ``+1`` left, ``-1`` right, ``0`` nothing within
    ``avoid_start_m``.

    The more open side (larger mean range, each ray counted up to ``open_m``: facing a wall
    beside a doorway, the doorway's side; the nearest range of each side would be the same
    wall on both). A side once chosen (``previous``) is kept while obstacles stay in range,
    unless the other side is more open by ``avoid_switch_m``: picking afresh every frame turns
    the robot toward whichever side is momentarily more open, which swings it back and forth
    facing the obstacle (the simulated robot sat for minutes in front of an armchair so).
    """
    ranges = _ranges(depth)
    if ranges is None:
        return 0
    nearest = float(ranges.min())
    if nearest >= params.avoid_start_m:
        return 0
    left, right = _openness(ranges, params, nearest)
    if previous > 0 and right - left <= params.avoid_switch_m:
        return 1
    if previous < 0 and left - right <= params.avoid_switch_m:
        return -1
    return 1 if left >= right else -1


def avoid_obstacles(
    v: float, w: float, depth: npt.ArrayLike | None, params: MotionParams, *, side: int = 0
) -> tuple[float, float]:
    """Blend obstacle avoidance into ``(v, w)`` with a weight that grows as obstacles close in.

    Weight 0 beyond ``avoid_start_m``, 1 at ``avoid_full_m`` and nearer. The avoidance command
    turns to ``side`` (``+1`` left, ``-1`` right; ``0``: :func:`avoid_side` with no memory)
    and does not move forward. Turning on the spot (``v`` <= 0) is left alone: a round robot
    cannot hit anything by turning, and blending would cancel the turn it needs to find its
    way out.
    """
    ranges = _ranges(depth)
    if ranges is None or v <= 0.0:
        return v, w
    nearest = float(ranges.min())
    span = params.avoid_start_m - params.avoid_full_m
    weight = float(np.clip((params.avoid_start_m - nearest) / span, 0.0, 1.0))
    if weight == 0.0:
        return v, w
    side = side or avoid_side(ranges, params)
    away = params.max_w if side > 0 else -params.max_w
    return (1.0 - weight) * v, (1.0 - weight) * w + weight * away
