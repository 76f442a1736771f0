"""Where the camera stands relative to a taught image: planar two-view geometry.

A robot on a flat floor turns only about the vertical axis and moves only in the floor's plane,
so the relative pose between the current frame and a taught image has three degrees of freedom:
the heading difference and a translation in the plane. The features both views see fix the
heading and the *direction* of the translation (the bearing, from the taught camera, of the line
through the two camera centres); its length is unknown to two views (the scale), and comes from
elsewhere (the taught odometry, other taught images, a depth sensor: see
:mod:`server.navigation.tracking`).

The model. Camera coordinates: ``x`` right, ``y`` down, ``z`` forward; normalised image
coordinates ``p = ((u - cx) / f, (v - cy) / f, 1)``. A scene point ``X_c`` in the current
camera's frame is ``X_t = R X_c + t`` in the taught camera's, with ``R`` a rotation about ``y``
by ``yaw`` and ``t = (t_x, 0, t_z)``: ``t`` is where the current camera stands in the taught
camera's frame. The essential matrix ``E = [t]x R`` then has four non-zero entries,

    E = [[0, a, 0], [b, 0, c], [0, d, 0]],  a = -t_z, d = t_x,
    b - i c = (t_z + i t_x) exp(-i yaw),

and each match gives one linear equation ``a x_t y_c + b y_t x_c + c y_t + d y_c = 0``: three
matches fix ``E`` up to scale (a 3-point linear solver, run by RANSAC over many samples at once),
and least squares over the inliers refines it. Points on the horizon (``y = 0``) say nothing
about ``E``: the floor and the ceiling, furniture and pictures do.

When the camera has barely moved (the translation is small against the scene's depth), the
matches are explained by the rotation alone and the bearing is noise: :func:`relative_pose`
says so (``parallax_px``), and the heading then comes from the rotation-only fit.

Pure: NumPy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class CameraModel:
    """A pinhole camera at the working size (no distortion).

    Attributes:
        hfov_deg: horizontal field of view, degrees (the simulated robot's camera: 60 degrees
            vertical at 4:3, 75.2 horizontal; a typical USB web-cam: 60-78).
        width, height: the working size in pixels the keypoints refer to.
        pitch_deg: how far the camera looks up from level, degrees (the simulated robot's: 5;
            the floor-plane model needs it: a pitched camera turning about the vertical axis
            does not turn about its own).
    """

    hfov_deg: float = 75.18
    width: int = 320
    height: int = 240
    pitch_deg: float = 5.0

    def __post_init__(self) -> None:
        if not 10.0 <= self.hfov_deg <= 170.0:
            raise ValueError(f"hfov_deg {self.hfov_deg} is not a field of view in [10, 170]")

    @property
    def focal_px(self) -> float:
        """Focal length in pixels."""
        return (self.width / 2) / math.tan(math.radians(self.hfov_deg) / 2)

    def normalised(self, uv: npt.ArrayLike) -> FloatArray:
        """``(n, 2)`` pixel coordinates -> ``(n, 2)`` normalised coordinates of a level camera
        at the same spot (the rays turned down by the pitch, then divided by their forward
        component): what a camera looking straight ahead would see."""
        pts = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        centre = np.array([(self.width - 1) / 2, (self.height - 1) / 2])
        xy = (pts - centre) / self.focal_px
        if self.pitch_deg == 0:
            return xy
        p = math.radians(self.pitch_deg)
        c, s = math.cos(p), math.sin(p)
        y = c * xy[:, 1] - s
        z = s * xy[:, 1] + c
        return np.stack([xy[:, 0] / z, y / z], axis=1)


@dataclass(frozen=True)
class RelPoseParams:
    """How :func:`relative_pose` fits the planar model.

    Attributes:
        samples (200): RANSAC samples of three matches (drawn with a fixed seed: the same
            matches give the same fit).
        inlier_px (2.0): a match agrees with a model when its Sampson distance is within this
            many pixels.
        min_inliers (8): fewer inliers than this -> no estimate.
        min_parallax_px (2.0): below this median parallax (the matches' displacement left once
            the rotation is taken out) the translation's direction is not measured.
        max_yaw (0.9 rad): fits that turn the camera more than this are rejected (the taught
            image and the frame would share little of the scene).
    """

    samples: int = 200
    inlier_px: float = 2.0
    min_inliers: int = 8
    min_parallax_px: float = 2.0
    max_yaw: float = 0.9


@dataclass(frozen=True)
class RelativePose:
    """The current camera relative to a taught image's camera, on a flat floor.

    Attributes:
        yaw: rad, the current heading minus the taught heading (counter-clockwise, seen from
            above, positive: the current camera looks further left).
        bearing: rad, the direction of the current camera's centre from the taught camera's,
            in the taught camera's floor frame (0: straight ahead of it, positive: to its
            left), defined modulo pi (two views cannot tell ahead from behind); ``None`` when
            the parallax is too small to say.
        inliers: matches the fit agrees with. n_matches: matches it was chosen from.
        parallax_px: median displacement of the inliers once the rotation is taken out, pixels
            at the working size: how much the camera has moved, against the scene's depth.
        yaw_sigma: rad, the heading's standard error from the inliers' scatter.
        bearing_sigma: rad, the bearing's standard error (``None`` with ``bearing``).
    """

    yaw: float
    bearing: float | None
    inliers: int
    n_matches: int
    parallax_px: float
    yaw_sigma: float
    bearing_sigma: float | None


def rotate_points(p: FloatArray, angle: float) -> FloatArray:
    """Normalised points ``p`` ``(n, 2)`` as a camera at the same spot turned ``angle`` to the
    right (clockwise seen from above) sees them: ``p' ~ R p``, ``R`` the rotation about the
    vertical axis of :func:`relative_pose`'s model."""
    c, s = math.cos(angle), math.sin(angle)
    x, y = p[:, 0], p[:, 1]
    z = -s * x + c
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.stack([(c * x + s) / z, y / z], axis=1)


def _solve(rows: FloatArray) -> FloatArray:
    """Null vectors of ``(..., m, 4)`` row stacks (the right singular vector of the smallest
    singular value): ``(..., 4)``, unit norm."""
    _, _, vt = np.linalg.svd(rows)
    out: FloatArray = vt[..., -1, :]
    return out


def _rows(pc: FloatArray, pt: FloatArray) -> FloatArray:
    """``(n, 4)`` equation rows ``[x_t y_c, y_t x_c, y_t, y_c]``."""
    return np.stack([pt[:, 0] * pc[:, 1], pt[:, 1] * pc[:, 0], pt[:, 1], pc[:, 1]], axis=-1)


def _sampson(e: FloatArray, pc: FloatArray, pt: FloatArray) -> FloatArray:
    """Sampson distances ``(k, n)`` (normalised units) of ``n`` matches to ``k`` models
    ``e`` ``(k, 4)``."""
    a, b, c, d = (e[:, i : i + 1] for i in range(4))
    xc, yc = pc[None, :, 0], pc[None, :, 1]
    xt, yt = pt[None, :, 0], pt[None, :, 1]
    r = a * xt * yc + b * yt * xc + c * yt + d * yc
    g = (a * yc) ** 2 + (b * xc + c) ** 2 + (b * yt) ** 2 + (a * xt + d) ** 2
    dist: FloatArray = np.abs(r) / np.sqrt(np.maximum(g, 1e-18))
    return dist


def _planar(e: FloatArray) -> FloatArray:
    """The planar motions nearest to linear solutions ``e`` ``(k, 4)``: each split into its
    rotation and translation (:func:`_decompose`, vectorised) and put back together, so that
    ``a^2 + d^2 = b^2 + c^2`` holds (a linear solution need not be a motion at all)."""
    a, b, c, d = e[:, 0], e[:, 1], e[:, 2], e[:, 3]
    t = (-a) + 1j * d  # t_z + i t_x
    bc = b - 1j * c
    with np.errstate(divide="ignore", invalid="ignore"):
        rot = bc / t
        rot = rot / np.abs(rot)  # exp(-i angle)
    rot = np.where(np.isfinite(rot), rot, 1.0 + 0j)
    # the translation best agreeing with both halves: t and bc / rot
    tt = 0.5 * (t + bc / rot)
    bc_new = tt * rot
    out = np.stack([-tt.real, bc_new.real, -bc_new.imag, tt.imag], axis=1)
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    planar: FloatArray = out / np.maximum(norm, 1e-18)
    return planar


def _decompose(e: FloatArray) -> tuple[float, float, float]:
    """``(angle, t_x, t_z)`` of a model ``(a, b, c, d)``: ``angle`` the rotation ``R`` turns
    the current camera's rays by (the taught heading minus the current one), ``t`` unit
    length, its sign arbitrary."""
    a, b, c, d = (float(x) for x in e)
    tx, tz = d, -a
    n = math.hypot(tx, tz)
    m = math.hypot(b, c)
    if n < 1e-12 or m < 1e-12:
        return 0.0, 0.0, 0.0
    # b - i c = (t_z + i t_x) exp(-i yaw)
    ratio = complex(b, -c) / complex(tz, tx)
    yaw = -math.atan2(ratio.imag, ratio.real)
    return yaw, tx / n, tz / n


def rotation_fit(pc: FloatArray, pt: FloatArray, inlier: float) -> tuple[float, FloatArray]:
    """The rotation angle (as :func:`rotate_points` takes it) that best explains the matches
    by a pure rotation (median of the per-match angles ``atan(x_t) - atan(x_c)``, refined on
    the matches within ``inlier``), and the ``(n,)`` residual displacements (normalised units)
    once it is taken out."""
    per_match = np.arctan(pt[:, 0]) - np.arctan(pc[:, 0])
    angle = float(np.median(per_match))
    residual = np.linalg.norm(rotate_points(pc, angle) - pt, axis=1)
    close = residual <= max(inlier, float(np.median(residual)))
    if np.any(close):
        angle = float(np.median(per_match[close]))
        residual = np.linalg.norm(rotate_points(pc, angle) - pt, axis=1)
    return angle, residual


def relative_pose(
    current_px: npt.ArrayLike,
    taught_px: npt.ArrayLike,
    camera: CameraModel = CameraModel(),
    params: RelPoseParams = RelPoseParams(),
) -> RelativePose | None:
    """The planar relative pose of the current camera from matched keypoints.

    Args:
        current_px, taught_px: ``(n, 2)`` matched keypoints in pixels at the working size, in
            the current frame and in the taught image (row ``i`` of one matches row ``i`` of
            the other).
        camera: the camera both were taken with.
        params: the fit's settings.

    Returns:
        The pose, or ``None`` when fewer than ``params.min_inliers`` matches agree with any
        model (or the best one turns more than ``params.max_yaw``).
    """
    pc = camera.normalised(current_px)
    pt = camera.normalised(taught_px)
    n = len(pc)
    if n < max(params.min_inliers, 3) or len(pt) != n:
        return None
    f = camera.focal_px
    tol = params.inlier_px / f
    rows = _rows(pc, pt)
    rng = np.random.default_rng(n)
    picks = np.argsort(rng.random((params.samples, n)), axis=1)[:, :3]
    models = _planar(_solve(rows[picks]))  # (samples, 4), each a planar motion
    agree = _sampson(models, pc, pt) <= tol
    best = int(np.argmax(agree.sum(axis=1)))
    inl = agree[best]
    if inl.sum() < params.min_inliers:
        return None
    # least squares on the inliers, then once more on the refit's inliers
    for _ in range(2):
        model = _planar(_solve(rows[inl])[None, :])[0]
        refit = _sampson(model[None, :], pc, pt)[0] <= tol
        if refit.sum() < params.min_inliers:
            break
        inl = refit
    angle, tx, tz = _decompose(model)
    yaw = -angle
    if abs(yaw) > params.max_yaw:
        return None
    # the parallax: what is left of the inliers' displacement once the rotation is out
    rotated = rotate_points(pc[inl], angle)
    parallax = float(np.median(np.linalg.norm(rotated - pt[inl], axis=1))) * f
    k = int(inl.sum())
    # the heading's scatter: per-match angles about the fit (translation shifts them too, so
    # this is an upper bound on the error when the camera moved)
    angles = np.arctan(pt[inl, 0]) - np.arctan(rotated[:, 0]) if k else np.zeros(1)
    spread = float(np.sqrt(np.mean(angles**2)))
    yaw_sigma = max(spread, params.inlier_px / f) / math.sqrt(max(k - 2, 1)) + 0.2 / f
    bearing = bearing_sigma = None
    if parallax >= params.min_parallax_px:
        # t is where the current camera stands in the taught camera's frame (x right, z
        # forward): on the floor, forward = t_z and left = -t_x
        bearing = _wrap_half(math.atan2(-tx, tz))
        bearing_sigma = (params.inlier_px / parallax) / math.sqrt(max(k - 3, 1)) + 0.02
    return RelativePose(
        yaw=float(yaw),
        bearing=bearing,
        inliers=k,
        n_matches=n,
        parallax_px=parallax,
        yaw_sigma=float(yaw_sigma),
        bearing_sigma=bearing_sigma,
    )


def _wrap_half(angle: float) -> float:
    """``angle`` modulo pi, in ``(-pi/2, pi/2]``."""
    out = (angle + math.pi / 2) % math.pi - math.pi / 2
    return math.pi / 2 if out == -math.pi / 2 else out
