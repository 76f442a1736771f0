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

    @property
    def score(self) -> float:
        """Lower is better: the residual, with a fraction of a pair counting against fits
        that rest on few points."""
        return self.rms_m + 0.5 / self.pairs


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
    fits = match_profiles_batch(
        taught,
        current,
        np.asarray(guess, dtype=np.float64)[None, :],
        fov_deg=fov_deg,
        params=params,
    )
    return fits[0]


def match_profiles_batch(
    taught: npt.ArrayLike,
    current: npt.ArrayLike,
    guesses: npt.ArrayLike,
    *,
    fov_deg: float,
    params: ScanParams = ScanParams(),
) -> list[ScanFit | None]:
    """:func:`match_profiles` from every start of ``guesses`` ``(S, 3)`` at once (the same
    iterations over ``(S, n, m)`` arrays): one fit per start, ``None`` where too few points
    agree."""
    T = profile_points(taught, fov_deg, params)
    C = profile_points(current, fov_deg, params)
    starts = np.atleast_2d(np.asarray(guesses, dtype=np.float64))
    S = len(starts)
    if len(T) < params.min_points or len(C) < params.min_points:
        return [None] * S
    N, has_normal = surface_normals(T, params)
    pose = starts.copy()
    alive = np.ones(S, dtype=bool)
    H = np.tile(np.eye(3), (S, 1, 1))
    r = np.zeros((S, len(C)))
    use = np.zeros((S, len(C)), dtype=bool)
    for it in range(params.iterations):
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        wx = c[:, None] * C[None, :, 0] - s[:, None] * C[None, :, 1] + pose[:, 0:1]
        wy = s[:, None] * C[None, :, 0] + c[:, None] * C[None, :, 1] + pose[:, 1:2]
        world = np.stack([wx, wy], axis=2)  # (S, n, 2)
        d2 = (wx[..., None] - T[:, 0]) ** 2 + (wy[..., None] - T[:, 1]) ** 2  # (S, n, m)
        j = d2.argmin(axis=2)
        near2 = np.take_along_axis(d2, j[..., None], axis=2)[..., 0]
        frac = it / max(params.iterations - 1, 1)
        limit = params.start_pair_m * (params.end_pair_m / params.start_pair_m) ** frac
        use = (near2 < limit * limit) & has_normal[j]
        alive &= use.sum(axis=1) >= params.min_points
        if not alive.any():
            return [None] * S
        n, q = N[j], T[j]  # (S, n, 2)
        r = np.where(use, np.einsum("snk,snk->sn", world - q, n), 0.0)
        rel = world - pose[:, None, :2]
        J = np.stack([n[..., 0], n[..., 1], rel[..., 0] * n[..., 1] - rel[..., 1] * n[..., 0]], 2)
        J = np.where(use[..., None], J, 0.0)
        H = np.einsum("sni,snj->sij", J, J) + 1e-9 * np.eye(3)
        g = np.einsum("sni,sn->si", J, r)
        step = -np.linalg.solve(H, g[..., None])[..., 0]
        step = np.where(alive[:, None], step, 0.0)
        pose += step
        if np.all((np.linalg.norm(step[:, :2], axis=1) < 1e-4) & (np.abs(step[:, 2]) < 1e-4)):
            break
    pairs = use.sum(axis=1)
    out: list[ScanFit | None] = []
    for k in range(S):
        if not alive[k] or pairs[k] < params.min_points:
            out.append(None)
            continue
        rms = float(np.sqrt(np.sum(r[k] ** 2) / pairs[k]))
        cov = max(rms, params.sigma_m) ** 2 * np.linalg.inv(H[k])
        p = pose[k].copy()
        p[2] = math.atan2(math.sin(p[2]), math.cos(p[2]))
        out.append(ScanFit(pose=p, cov=0.5 * (cov + cov.T), pairs=int(pairs[k]), rms_m=rms))
    return out


def match_profiles_robust(
    taught: npt.ArrayLike,
    current: npt.ArrayLike,
    guess: npt.ArrayLike,
    *,
    fov_deg: float,
    params: ScanParams = ScanParams(),
    lateral_m: tuple[float, ...] = (0.0, 0.5, -0.5, 1.0, -1.0),
    along_m: tuple[float, ...] = (0.0,),
    turns_rad: tuple[float, ...] = (0.0, 0.25, -0.25),
) -> ScanFit | None:
    """:func:`match_profiles` from several starts around ``guess`` (shifted sideways by
    ``lateral_m``, along by ``along_m`` and turned by ``turns_rad``), all at once
    (:func:`match_profiles_batch`): the fit with the smallest residual, a fraction of a pair
    counting against few pairs. For a guess that may be far off (joining a path, docking on a
    place); one start suffices while the estimate is good."""
    fits = match_profiles_starts(
        taught,
        current,
        guess,
        fov_deg=fov_deg,
        params=params,
        lateral_m=lateral_m,
        along_m=along_m,
        turns_rad=turns_rad,
    )
    return fits[0] if fits else None


def match_profiles_starts(
    taught: npt.ArrayLike,
    current: npt.ArrayLike,
    guess: npt.ArrayLike,
    *,
    fov_deg: float,
    params: ScanParams = ScanParams(),
    lateral_m: tuple[float, ...] = (0.0, 0.5, -0.5, 1.0, -1.0),
    along_m: tuple[float, ...] = (0.0,),
    turns_rad: tuple[float, ...] = (0.0, 0.25, -0.25),
) -> list[ScanFit]:
    """Every fit :func:`match_profiles_robust` finds from its starts, best first (the runners
    up say whether the best is the only good alignment)."""
    base = np.asarray(guess, dtype=np.float64)
    c, s = math.cos(base[2]), math.sin(base[2])
    starts = np.array(
        [
            base + np.array([c * dx - s * dy, s * dx + c * dy, dth])
            for dy in lateral_m
            for dx in along_m
            for dth in turns_rad
        ]
    )
    fits = [
        f
        for f in match_profiles_batch(taught, current, starts, fov_deg=fov_deg, params=params)
        if f is not None
    ]
    return sorted(fits, key=lambda f: f.score)
