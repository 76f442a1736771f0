"""Visual homing: where the target image's features lie relative to the current frame.

Used by navigation (001 section 7.2): while following an edge, the robot steers so that the
features of the next taught image move to where it sees them now; the mean horizontal
displacement of the matched features becomes an angular velocity. No features -> ``None``, and
the caller replays the motion command recorded with the target image.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from server.vision.features import FeatureParams, ImageFeatures, descriptor_distances


@dataclass(frozen=True)
class HomingParams:
    """Matching for homing.

    Attributes:
        min_matches: fewer accepted matches than this -> no estimate (``None``).
        max_distance: largest accepted normalised descriptor distance (see
            :func:`server.vision.features.descriptor_distances`).
        ratio: Lowe ratio test, best / second-best distance must be below this.
        max_dy: matches whose vertical displacement exceeds this fraction of the image height
            are rejected (the camera does not pitch much while driving).
        features: the extraction parameters (descriptor scale).
    """

    min_matches: int = 5
    max_distance: float = 0.6
    ratio: float = 0.9
    max_dy: float = 0.15
    features: FeatureParams = field(default_factory=FeatureParams)


@dataclass(frozen=True)
class HomingResult:
    """Homing estimate.

    Attributes:
        offset: mean horizontal displacement ``x_target - x_current`` of the matched features
            divided by the image width, clipped to [-1, 1]; positive = the target's features lie
            to the right of where the current frame sees them.
        n_matches: number of accepted matches the mean is taken over.
        offset_px: the same displacement in pixels at the working size.
    """

    offset: float
    n_matches: int
    offset_px: float


def homing_offset(
    current: ImageFeatures,
    target: ImageFeatures,
    *,
    params: HomingParams = HomingParams(),
) -> HomingResult | None:
    """Horizontal offset between ``current`` and ``target`` from mutual nearest-neighbour
    matches (ratio test, distance and vertical-consistency checks).

    Returns ``None`` when fewer than ``params.min_matches`` matches survive.
    """
    if current.descriptor != target.descriptor:
        raise ValueError(
            f"cannot match {current.descriptor} against {target.descriptor} features; "
            "extract both with the same FeatureParams"
        )
    if current.n_keypoints == 0 or target.n_keypoints == 0:
        return None
    dist = descriptor_distances(
        current.descriptors, target.descriptors, current.descriptor, params.features
    )
    fwd = dist.argmin(axis=1)
    back = dist.argmin(axis=0)
    rows = np.arange(len(fwd))
    keep = back[fwd] == rows
    keep &= dist[rows, fwd] <= params.max_distance
    if dist.shape[1] >= 2:
        part = np.partition(dist, 1, axis=1)
        keep &= part[:, 0] < params.ratio * np.maximum(part[:, 1], 1e-9)
    width, height = current.size
    src = current.keypoints[keep]
    dst = target.keypoints[fwd[keep]]
    dy_ok = np.abs(dst[:, 1] - src[:, 1]) <= params.max_dy * height
    src, dst = src[dy_ok], dst[dy_ok]
    if len(src) < params.min_matches:
        return None
    dx = float(np.mean(dst[:, 0] - src[:, 0]))
    return HomingResult(
        offset=float(np.clip(dx / width, -1.0, 1.0)), n_matches=len(src), offset_px=dx
    )
