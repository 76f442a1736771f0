"""Where the robot stands relative to a taught image, from two depth profiles (2D scan matching).

A depth profile is a fan of ranges in the floor's plane (``(n_rays,)`` metres, leftmost ray
first, spanning ``fov_deg`` evenly). The profile taught with an image and the one the robot
sees now, both turned into points in their robot's frame (``x`` forward, ``y`` left), are
aligned by point-to-line ICP: every current point is pulled onto the line through its nearest
taught point (the wall or the furniture face it lies on), and the 2D rigid motion that does so
best is the pose of the current robot in the taught robot's frame: metres and radians, with no
scale to guess (which two camera views cannot give). Along a featureless corridor the fit
cannot tell how far along: its covariance says so, and the path tracker then trusts it across
the corridor only.

Pure: NumPy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class ScanParams:
    """How two depth profiles are aligned.

    Attributes:
        max_range_m (3.9): rays longer than this (or not finite) saw nothing and are dropped.
        min_points (6): fewer points on either side, or fewer pairs agreeing, -> no fit.
        iterations (15): ICP iterations at most.
        start_pair_m (0.5), end_pair_m (0.08): a current point pairs with its nearest taught
            point only within this distance, shrinking from the first to the last iteration.
        surface_gap_m (0.4): neighbouring taught points further apart than this lie on
            different surfaces (no line through them).
        sigma_m (0.02): the least standard deviation of a point's distance to its line (the
            ranges' noise and the surfaces' roughness).
    """

    max_range_m: float = 3.9
    min_points: int = 6
    iterations: int = 15
    start_pair_m: float = 0.5
    end_pair_m: float = 0.08
    surface_gap_m: float = 0.4
    sigma_m: float = 0.02


@dataclass(frozen=True)
class ScanFit:
    """The current robot's pose in the taught robot's frame, as the profiles say.

    Attributes:
        pose: ``(3,)`` x forward, y left (m), heading (rad).
        cov: ``(3, 3)`` its covariance (large along directions the scene cannot tell).
        pairs: points that agree with the fit.
        rms_m: their root-mean-square distance to their lines.
    """

    pose: FloatArray
    cov: FloatArray
    pairs: int
    rms_m: float


def profile_points(
    ranges: npt.ArrayLike, fov_deg: float, params: ScanParams = ScanParams()
) -> FloatArray:
    """``(m, 2)`` the points a profile saw (in its robot's frame), leftmost first."""
    r = np.asarray(ranges, dtype=np.float64)
    n = len(r)
    if n == 0:
        return np.zeros((0, 2))
    half = math.radians(fov_deg) / 2
    angles = np.linspace(half, -half, n) if n > 1 else np.zeros(1)
    ok = np.isfinite(r) & (r > 0.05) & (r < params.max_range_m)
    return np.stack([r[ok] * np.cos(angles[ok]), r[ok] * np.sin(angles[ok])], axis=1)


def surface_normals(
    points: FloatArray, params: ScanParams = ScanParams()
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """``(m, 2)`` unit normals of the surface at each point (from its neighbours) and which
    points have one (their neighbours lie on the same surface)."""
    m = len(points)
    normals = np.zeros((m, 2))
    if m < 3:
        return normals, np.zeros(m, dtype=bool)
    d = np.empty_like(points)
    d[1:-1] = points[2:] - points[:-2]
    d[0], d[-1] = points[1] - points[0], points[-1] - points[-2]
    step = np.linalg.norm(np.diff(points, axis=0), axis=1)
    gap = np.empty(m)
    gap[1:-1] = np.maximum(step[:-1], step[1:])
    gap[0], gap[-1] = step[0], step[-1]
    length = np.linalg.norm(d, axis=1)
    ok = (length > 1e-9) & (gap < params.surface_gap_m)
    normals[ok] = np.stack([-d[ok, 1], d[ok, 0]], axis=1) / length[ok, None]
    return normals, ok


def match_profiles(
    taught: npt.ArrayLike,
    current: npt.ArrayLike,
    guess: npt.ArrayLike,
    *,
    fov_deg: float,
    params: ScanParams = ScanParams(),
) -> ScanFit | None:
    """Align the ``current`` profile with the ``taught`` one, starting from ``guess`` (the
    current robot's pose in the taught robot's frame, ``(3,)``); ``None`` when too few points
    agree."""
    T = profile_points(taught, fov_deg, params)
    C = profile_points(current, fov_deg, params)
    if len(T) < params.min_points or len(C) < params.min_points:
        return None
    N, has_normal = surface_normals(T, params)
    pose = np.asarray(guess, dtype=np.float64).copy()
    H = np.eye(3)
    r = np.zeros(0)
    used = 0
    for it in range(params.iterations):
        c, s = math.cos(pose[2]), math.sin(pose[2])
        world = C @ np.array([[c, s], [-s, c]]) + pose[:2]
        dist = np.linalg.norm(world[:, None, :] - T[None, :, :], axis=2)
        j = dist.argmin(axis=1)
        near = dist[np.arange(len(C)), j]
        frac = it / max(params.iterations - 1, 1)
        limit = params.start_pair_m * (params.end_pair_m / params.start_pair_m) ** frac
        use = (near < limit) & has_normal[j]
        used = int(use.sum())
        if used < params.min_points:
            return None
        n, p, q = N[j[use]], world[use], T[j[use]]
        r = np.einsum("ij,ij->i", p - q, n)
        rel = p - pose[:2]
        J = np.stack([n[:, 0], n[:, 1], rel[:, 0] * n[:, 1] - rel[:, 1] * n[:, 0]], axis=1)
        H = J.T @ J + 1e-9 * np.eye(3)
        step = -np.linalg.solve(H, J.T @ r)
        pose += step
        if np.linalg.norm(step[:2]) < 1e-4 and abs(step[2]) < 1e-4:
            break
    rms = float(np.sqrt(np.mean(r**2))) if len(r) else math.inf
    sigma2 = max(rms, params.sigma_m) ** 2
    cov = sigma2 * np.linalg.inv(H)
    pose[2] = math.atan2(math.sin(pose[2]), math.cos(pose[2]))
    return ScanFit(pose=pose, cov=0.5 * (cov + cov.T), pairs=used, rms_m=rms)


def match_profiles_robust(
    taught: npt.ArrayLike,
    current: npt.ArrayLike,
    guess: npt.ArrayLike,
    *,
    fov_deg: float,
    params: ScanParams = ScanParams(),
    lateral_m: tuple[float, ...] = (0.0, 0.5, -0.5, 1.0, -1.0),
    turns_rad: tuple[float, ...] = (0.0, 0.25, -0.25),
) -> ScanFit | None:
    """:func:`match_profiles` from several starts around ``guess`` (shifted sideways by
    ``lateral_m`` and turned by ``turns_rad``): the fit with the smallest residual (a
    fraction of a pair counts against few pairs). For a guess that may be far off (joining a
    path); one start suffices while the estimate is good."""
    base = np.asarray(guess, dtype=np.float64)
    c, s = math.cos(base[2]), math.sin(base[2])
    best: tuple[float, ScanFit] | None = None
    for dy in lateral_m:
        for dth in turns_rad:
            start = base + np.array([-s * dy, c * dy, dth])
            fit = match_profiles(taught, current, start, fov_deg=fov_deg, params=params)
            if fit is None:
                continue
            score = fit.rms_m + 0.5 / fit.pairs
            if best is None or score < best[0]:
                best = (score, fit)
    return None if best is None else best[1]
