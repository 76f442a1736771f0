"""Visual homing: where the target image's features lie relative to the current frame.

Used by navigation (001 section 7.2): while following an edge, the robot steers so that the
features of the next taught image move to where it sees them now; the mean horizontal
displacement of the matched features becomes an angular velocity. No features -> ``None``, and
the caller replays the motion command recorded with the target image.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
import numpy.typing as npt

from server.vision.features import (
    FeatureParams,
    ImageFeatures,
    descriptor_distances,
    extract_corners,
)


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


def match_features(
    current: ImageFeatures,
    target: ImageFeatures,
    *,
    params: HomingParams = HomingParams(),
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """Matched keypoints ``(src, dst)``, each ``(n, 2)`` pixels at the working size: ``src`` in
    ``current``, ``dst`` in ``target``. Mutual nearest neighbours that pass the ratio test,
    the distance limit and the vertical-consistency check, strongest corners of ``current``
    first."""
    if current.descriptor != target.descriptor:
        raise ValueError(
            f"cannot match {current.descriptor} against {target.descriptor} features; "
            "extract both with the same FeatureParams"
        )
    empty = np.zeros((0, 2), np.float32)
    if current.n_keypoints == 0 or target.n_keypoints == 0:
        return empty, empty
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
    height = current.size[1]
    src = current.keypoints[keep].astype(np.float32)
    dst = target.keypoints[fwd[keep]].astype(np.float32)
    dy_ok = np.abs(dst[:, 1] - src[:, 1]) <= params.max_dy * height
    return src[dy_ok], dst[dy_ok]


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
    src, dst = match_features(current, target, params=params)
    if len(src) < params.min_matches:
        return None
    width = current.size[0]
    dx = float(np.mean(dst[:, 0] - src[:, 0]))
    return HomingResult(
        offset=float(np.clip(dx / width, -1.0, 1.0)), n_matches=len(src), offset_px=dx
    )


@dataclass(frozen=True)
class ScaleParams:
    """How :func:`homing_scale` fits a similarity transform to the matches.

    Attributes:
        hypotheses_from (24): hypotheses are the transforms through every pair of the first
            this many matches (the strongest corners of the current frame): at most 276.
        min_separation_px (12): a pair closer than this in the current frame gives no hypothesis
            (its scale would be noise).
        inlier_px (3.0): a match agrees with a transform when it lands within this many pixels.
        max_rotation (0.15 rad): hypotheses that roll the image more than this are rejected
            (the camera does not roll).
        scale_range ((0.4, 2.5)): hypotheses with a scale outside this range are rejected.
    """

    hypotheses_from: int = 24
    min_separation_px: float = 12.0
    inlier_px: float = 3.0
    max_rotation: float = 0.15
    scale_range: tuple[float, float] = (0.4, 2.5)


@dataclass(frozen=True)
class ScaleResult:
    """A similarity transform ``target ~ scale * R(rotation) * current + shift`` between views.

    Attributes:
        scale: how much larger the target image shows the matched scene (> 1: the target was
            taken nearer to what the camera sees, i.e. further forward along the view).
        rotation: image roll of the fit, radians.
        inliers: matches within ``ScaleParams.inlier_px`` of the fit.
        n_matches: matches the fit was chosen from.
        offset: mean horizontal displacement ``x_target - x_current`` of the inliers over the
            image width (as :attr:`HomingResult.offset`).
    """

    scale: float
    rotation: float
    inliers: int
    n_matches: int
    offset: float


def homing_scale(
    current: ImageFeatures,
    target: ImageFeatures,
    *,
    params: HomingParams = HomingParams(),
    fit: ScaleParams = ScaleParams(),
) -> ScaleResult | None:
    """Scale between ``current`` and ``target``: how far forward or back of the target's
    viewpoint the camera stands, as seen from the size of what both see.

    Deterministic consensus fit: every pair among the first ``fit.hypotheses_from`` matches
    defines a similarity transform (points as complex numbers: ``q = a p + b``); the one that
    most matches agree with wins and is refitted on its inliers by least squares. ``None``
    when fewer than ``params.min_matches`` matches or no acceptable hypothesis.
    """
    src, dst = match_features(current, target, params=params)
    n = len(src)
    if n < max(params.min_matches, 2):
        return None
    p = src[:, 0].astype(np.float64) + 1j * src[:, 1]
    q = dst[:, 0].astype(np.float64) + 1j * dst[:, 1]
    i, j = np.triu_indices(min(n, fit.hypotheses_from), k=1)
    dp = p[j] - p[i]
    ok = np.abs(dp) >= fit.min_separation_px
    i, j, dp = i[ok], j[ok], dp[ok]
    if len(i) == 0:
        return None
    a = (q[j] - q[i]) / dp
    scale, roll = np.abs(a), np.abs(np.angle(a))
    ok = (roll <= fit.max_rotation) & (scale >= fit.scale_range[0]) & (scale <= fit.scale_range[1])
    if not ok.any():
        return None
    a, b = a[ok], (q[i] - a * p[i])[ok]
    # (hypotheses, matches) residuals, pixels
    agree = np.abs(a[:, None] * p[None, :] + b[:, None] - q[None, :]) <= fit.inlier_px
    best = int(np.argmax(agree.sum(axis=1)))
    inl = agree[best]
    if inl.sum() >= 2:  # least-squares similarity on the inliers
        pc, qc = p[inl] - p[inl].mean(), q[inl] - q[inl].mean()
        a_best = complex(np.vdot(pc, qc) / max(float(np.vdot(pc, pc).real), 1e-9))
    else:
        a_best = complex(a[best])
    width = current.size[0]
    dx = float(np.mean(dst[inl, 0] - src[inl, 0])) if inl.any() else 0.0
    return ScaleResult(
        scale=float(abs(a_best)),
        rotation=float(np.angle(a_best)),
        inliers=int(inl.sum()),
        n_matches=n,
        offset=float(np.clip(dx / width, -1.0, 1.0)),
    )


@dataclass(frozen=True, eq=False)
class _Consensus:
    """One pair's matches and its winning hypothesis, before the least-squares refit:
    ``p``, ``q`` the ``(n,)`` matched points (current, target) as complex pixels, ``dx`` their
    horizontal displacements ``(n,)`` float32 px, ``inl`` the winner's inliers ``(n,)`` bool,
    ``a`` its transform, ``width`` the current image's width (px)."""

    p: npt.NDArray[np.complex128]
    q: npt.NDArray[np.complex128]
    dx: npt.NDArray[np.float32]
    inl: npt.NDArray[np.bool_]
    a: complex
    width: int

    @property
    def inliers(self) -> int:
        return int(self.inl.sum())

    def result(self) -> ScaleResult:
        """The refit on the inliers, as :func:`homing_scale` makes it."""
        p, q, inl = self.p, self.q, self.inl
        if inl.sum() >= 2:  # least-squares similarity on the inliers
            pc, qc = p[inl] - p[inl].mean(), q[inl] - q[inl].mean()
            a_best = complex(np.vdot(pc, qc) / max(float(np.vdot(pc, pc).real), 1e-9))
        else:
            a_best = self.a
        dx = float(np.mean(self.dx[inl])) if inl.any() else 0.0
        return ScaleResult(
            scale=float(abs(a_best)),
            rotation=float(np.angle(a_best)),
            inliers=int(inl.sum()),
            n_matches=len(p),
            offset=float(np.clip(dx / self.width, -1.0, 1.0)),
        )


def _consensus(
    pairs: Sequence[tuple[ImageFeatures, ImageFeatures]], params: HomingParams, fit: ScaleParams
) -> list[_Consensus | None]:
    """:func:`homing_scale`'s matching and consensus for every ``(current, target)`` pair in
    one pass over arrays padded to the largest pair (``(pairs, rows, columns)``), with the
    same numbers as pair by pair: the distances are each pair's own
    :func:`~server.vision.features.descriptor_distances`, the padding is ``inf`` (never
    nearest, never second nearest of a real row) and masked out, and every later step is
    element-wise or a comparison. ``None`` where :func:`homing_scale` gives ``None``."""
    out: list[_Consensus | None] = [None] * len(pairs)
    live: list[int] = []
    dists: list[npt.NDArray[np.float32]] = []
    for k, (current, target) in enumerate(pairs):
        if current.descriptor != target.descriptor:
            raise ValueError(
                f"cannot match {current.descriptor} against {target.descriptor} features; "
                "extract both with the same FeatureParams"
            )
        if current.n_keypoints and target.n_keypoints:
            live.append(k)
            dists.append(
                descriptor_distances(
                    current.descriptors, target.descriptors, current.descriptor, params.features
                )
            )
    if not live:
        return out
    n_rows = max(d.shape[0] for d in dists)
    n_cols = max(d.shape[1] for d in dists)
    dist = np.full((len(live), n_rows, n_cols), np.inf, np.float32)
    src = np.zeros((len(live), n_rows, 2), np.float32)
    dst_all = np.zeros((len(live), n_cols, 2), np.float32)
    for row, (k, d) in enumerate(zip(live, dists, strict=True)):
        current, target = pairs[k]
        dist[row, : d.shape[0], : d.shape[1]] = d
        src[row, : d.shape[0]] = current.keypoints
        dst_all[row, : d.shape[1]] = target.keypoints
    real = np.arange(n_rows)[None, :] < np.array([pairs[k][0].n_keypoints for k in live])[:, None]
    # mutual nearest neighbours, distance limit, ratio test (as match_features)
    fwd = dist.argmin(axis=2)
    back = np.ascontiguousarray(dist.transpose(0, 2, 1)).argmin(axis=2)
    nearest = np.take_along_axis(dist, fwd[..., None], axis=2)
    keep = real & (np.take_along_axis(back, fwd, axis=1) == np.arange(n_rows)[None, :])
    keep &= nearest[..., 0] <= params.max_distance
    if n_cols >= 2:  # a pair with one column: inf second nearest, the test passes (as skipped)
        np.put_along_axis(dist, fwd[..., None], np.inf, axis=2)  # the second nearest is left
        second = dist.min(axis=2)
        keep &= nearest[..., 0] < params.ratio * np.maximum(second, 1e-9)
    dst = np.take_along_axis(dst_all, fwd[..., None], axis=1)
    limit = np.array([params.max_dy * pairs[k][0].size[1] for k in live], np.float32)
    keep &= np.abs(dst[..., 1] - src[..., 1]) <= limit[:, None]
    n = keep.sum(axis=1)
    if int(n.max()) < max(params.min_matches, 2):
        return out
    # the accepted matches first, in row order (strongest corners of the current frame first)
    order = np.argsort(~keep, axis=1, kind="stable")[:, : int(n.max())]
    src = np.take_along_axis(src, order[..., None], axis=1)
    dst = np.take_along_axis(dst, order[..., None], axis=1)
    matched = np.arange(order.shape[1])[None, :] < n[:, None]
    p = src[..., 0].astype(np.float64) + 1j * src[..., 1]
    q = dst[..., 0].astype(np.float64) + 1j * dst[..., 1]
    # every pair of the first hypotheses_from matches (as homing_scale)
    h = np.minimum(n, fit.hypotheses_from)
    i, j = _pairs(min(int(h.max()), fit.hypotheses_from))
    dp = p[:, j] - p[:, i]
    ok = (j[None, :] < h[:, None]) & (np.abs(dp) >= fit.min_separation_px)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (q[:, j] - q[:, i]) / np.where(ok, dp, 1.0)
    scale, roll = np.abs(a), np.abs(np.angle(a))
    ok &= (roll <= fit.max_rotation) & (scale >= fit.scale_range[0]) & (scale <= fit.scale_range[1])
    b = q[:, i] - a * p[:, i]
    # (pairs, hypotheses, matches) residuals, pixels
    agree = np.abs(a[..., None] * p[:, None, :] + b[..., None] - q[:, None, :]) <= fit.inlier_px
    agree &= matched[:, None, :]
    votes = np.where(ok, agree.sum(axis=2), -1)
    best = votes.argmax(axis=1)
    for row, k in enumerate(live):
        m = int(n[row])
        if m < max(params.min_matches, 2) or not ok[row].any():
            continue
        out[k] = _Consensus(
            p=p[row, :m],
            q=q[row, :m],
            dx=dst[row, :m, 0] - src[row, :m, 0],
            inl=agree[row, best[row], :m],
            a=complex(a[row, best[row]]),
            width=int(pairs[k][0].size[0]),
        )
    return out


@functools.cache
def _pairs(n: int) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """``np.triu_indices(n, k=1)``: every pair ``i < j`` of ``n`` matches, row by row."""
    i, j = np.triu_indices(n, k=1)
    i.flags.writeable = j.flags.writeable = False
    return i, j


def homing_scales(
    pairs: Sequence[tuple[ImageFeatures, ImageFeatures]],
    *,
    params: HomingParams = HomingParams(),
    fit: ScaleParams = ScaleParams(),
) -> list[ScaleResult | None]:
    """``[homing_scale(current, target) for current, target in pairs]``, the same results
    made in one vectorised pass (:func:`_consensus`): docking fits a frame's five zoom levels
    against a taught image at once. :func:`homing_scale` keeps its own code for one pair:
    through the padded arrays one pair takes 0.28 ms against 0.22 (corridor frames), and
    it is the naive reference the tests hold this pass to."""
    return [None if c is None else c.result() for c in _consensus(pairs, params, fit)]


def _best_zoom(
    pairs: Sequence[tuple[ImageFeatures, ImageFeatures]],
    factors: Sequence[float],
    params: HomingParams,
    fit: ScaleParams,
) -> ScaleResult | None:
    """Of the pairs (one per zoom ``factors``), the fit with the most inliers (the first on a
    tie), its scale multiplied by its factor; only that one is refitted. ``None``: none fits."""
    best: tuple[_Consensus, float] | None = None
    for c, factor in zip(_consensus(pairs, params, fit), factors, strict=True):
        if c is not None and (best is None or c.inliers > best[0].inliers):
            best = (c, factor)
    if best is None:
        return None
    result = best[0].result()
    return result if best[1] == 1.0 else replace(result, scale=result.scale * best[1])


def zoom_image(image: npt.NDArray[np.uint8], factor: float) -> npt.NDArray[np.uint8]:
    """``image`` as a camera would see it from nearer (``factor`` > 1: the centre
    ``1 / factor`` of the frame enlarged to the full size) or from further back (``factor`` < 1:
    the frame shrunk about its centre, the rim filled by repeating the edge pixels, which
    makes no corners). Same shape and dtype as ``image``."""
    if not (np.isfinite(factor) and factor > 0):
        raise ValueError(f"zoom factor must be finite and > 0, got {factor}")
    h, w = image.shape[:2]
    m = np.array(
        [[factor, 0.0, (1 - factor) * w / 2], [0.0, factor, (1 - factor) * h / 2]], np.float32
    )
    interp = cv2.INTER_LINEAR if factor >= 1 else cv2.INTER_AREA
    out = cv2.warpAffine(image, m, (w, h), flags=interp, borderMode=cv2.BORDER_REPLICATE)
    return np.asarray(out, np.uint8)


@dataclass(frozen=True, eq=False)
class ZoomLevel:
    """The current frame's features as seen through a zoom: ``features`` were extracted from
    :func:`zoom_image` of the frame by ``factor`` (1 = the frame itself)."""

    factor: float
    features: ImageFeatures


def _factors(zooms: Sequence[float]) -> list[float]:
    """The zoom factors of ``zooms`` in level order: ``z`` then ``1 / z`` for each."""
    return [f for z in zooms for f in (float(z), 1.0 / float(z)) if f != 1.0]


def zoom_levels(
    image: npt.NDArray[np.uint8],
    features: ImageFeatures,
    zooms: Sequence[float],
    params: FeatureParams,
) -> tuple[ZoomLevel, ...]:
    """The frame itself (``features``) and, for every ``z`` in ``zooms``, the frame zoomed in by
    ``z`` and out by ``1 / z``: ``1 + 2 len(zooms)`` levels. The zoomed levels carry corners
    and descriptors only (:func:`extract_corners`): homing reads nothing else."""
    levels = [ZoomLevel(1.0, features)]
    for f in _factors(zooms):
        levels.append(ZoomLevel(f, extract_corners(zoom_image(image, f), params)))
    return tuple(levels)


def homing_scale_zoomed(
    levels: Sequence[ZoomLevel],
    target: ImageFeatures,
    *,
    params: HomingParams = HomingParams(),
    fit: ScaleParams = ScaleParams(),
) -> ScaleResult | None:
    """:func:`homing_scale` over several zooms of the current frame: the level with the most
    inliers wins and its scale is multiplied by the level's factor.

    The corner descriptors are not scale invariant: a view whose scene is 1.5 times larger than
    in the target matches few of its corners at zoom 1, and the fit then rests on whatever
    far-away scene matched at scale ~1. Zooming the frame brings the near scene back in range.
    In the simulated home (robot put 0.4 and 0.8 m off four places, 72 headings each, best of
    the three top-ranked spin images), the displacement along the view read from the fits
    ``r (1 / scale - 1)`` (``r``: depth straight ahead) against the true one had a regression
    slope of 0.33 / 0.48 / 0.51 at zoom 1 for views 0-1.5 / 1.5-2.5 / 2.5-4 m deep, and
    0.40 / 0.58 / 0.63 with zooms 1.3 and 1.69 in and out.

    Returns ``None`` when no level fits.
    """
    pairs = [(level.features, target) for level in levels]
    return _best_zoom(pairs, [level.factor for level in levels], params, fit)


def taught_zoom_levels(
    image: npt.NDArray[np.uint8],
    features: ImageFeatures,
    zooms: Sequence[float],
    params: FeatureParams,
) -> tuple[ZoomLevel, ...]:
    """A taught image's counterparts of the frame's :func:`zoom_levels`, made once per taught
    image instead of once per frame: the level of factor ``f`` holds the taught image zoomed by
    ``1 / f`` (the frame zoomed in by ``f`` matched against the taught image is, up to the
    resampling, the frame matched against the taught image zoomed out by ``f``), in the same
    order as :func:`zoom_levels`, the first being ``features`` itself (factor 1).

    A taught image zoomed out (``f`` > 1) shows its whole view inside the central ``1 / f`` of
    the image, the rim filled by repeated edge pixels: its corners are taken only inside that
    view (a corner near its edge has a descriptor that reads some of the rim, as the frame
    zoomed out by :func:`zoom_levels` has; keeping corners ``params.border`` px in from the
    view's edge cost a third of the inliers on rendered scenes seen 1.7 times nearer).
    Corners and descriptors only (:func:`extract_corners`)."""
    w, h = params.width, params.height
    levels = [ZoomLevel(1.0, features)]
    for f in _factors(zooms):
        g = 1.0 / f
        region = None
        if g < 1.0:  # the view shrunk about the centre; the rim around it is no view
            x0, y0 = w / 2 * (1 - g), h / 2 * (1 - g)
            region = (
                int(np.ceil(x0)),
                int(np.ceil(y0)),
                int(np.floor(w - x0)),
                int(np.floor(h - y0)),
            )
        zoomed = extract_corners(zoom_image(image, g), params, region=region)
        levels.append(ZoomLevel(f, zoomed))
    return tuple(levels)


def _as_frame_zoom(
    current: ImageFeatures, target: ImageFeatures, factor: float, params: FeatureParams
) -> tuple[ImageFeatures, ImageFeatures]:
    """The frame's corners and a taught level's (taught image zoomed by ``1 / factor``) with
    their keypoints moved to where the frame zoomed in by ``factor`` and the taught image
    itself show them: both scaled by ``factor`` about the image centre, so that
    :func:`homing_scale` reads pixels, thresholds and offsets as it does on the frame's zoom
    level. Of the frame's corners, those the zoomed frame shows (``params.border`` px inside
    the image once scaled) are kept, the strongest ``params.n_features`` of them."""
    w, h = current.size
    centre = np.array([w / 2, h / 2], np.float32)
    f = np.float32(factor)
    moved = (current.keypoints - centre) * f + centre
    b = params.border
    keep = np.flatnonzero(
        (moved[:, 0] >= b) & (moved[:, 0] <= w - b) & (moved[:, 1] >= b) & (moved[:, 1] <= h - b)
    )[: params.n_features]
    frame = replace(
        current,
        keypoints=np.ascontiguousarray(moved[keep]),
        descriptors=np.ascontiguousarray(current.descriptors[keep]),
    )
    taught = replace(target, keypoints=(target.keypoints - centre) * f + centre)
    return frame, taught


def homing_scale_taught_zoomed(
    current: ImageFeatures,
    levels: Sequence[ZoomLevel],
    *,
    params: HomingParams = HomingParams(),
    fit: ScaleParams = ScaleParams(),
) -> ScaleResult | None:
    """:func:`homing_scale_zoomed` with the zooms on the taught side: ``levels`` from
    :func:`taught_zoom_levels` (the first, factor 1, is the taught image's own features),
    ``current`` the frame's own features.

    Docking uses it with ``NavigationParams.dock_taught_zooms`` ``"look"`` (the default) only
    to look for a view; creeping and the verdicts read the frame's zooms. Read for the verdicts
    too (the removed ``"both"``) it saved as much CPU but docked less closely (the
    parameter's documentation has the figures).
    ``teachrepeat bench dock-views`` (apartment and studio, every place, 8 headings, the robot
    0.8 and 0.4 m behind and 0.4 m past the taught spot, 370 views): the taught image zoomed
    out, for the frame zoomed in, found fewer inliers (11.4 against 15.8 at 0.8 m behind) and
    read "short" less often (39 % of the views against 55 %); the taught image zoomed in, for
    the frame zoomed out, found more (27.9 against 21.4 at 0.4 m past) and read "past" more
    often (76 % against 64 %).

    The result means what :func:`homing_scale_zoomed`'s does: scale, rotation, inliers and
    offset of the level with the most inliers (the first on a tie, levels in the order of
    :func:`zoom_levels`), read in the zoomed frame's pixels, the scale multiplied by the
    level's factor. A taught level gives the same fit as the frame zoomed by its factor would
    on corners that moved exactly with the zoom (tests/unit/vision/
    test_vision_homing_taught_zoom.py); on real images the corners differ.

    Returns ``None`` when no level fits.
    """
    if not levels or levels[0].factor != 1.0:
        raise ValueError("the first taught level must be the taught image itself (factor 1)")
    target = levels[0].features
    taught = {lv.factor: lv.features for lv in levels}
    # the order of zoom_levels: 1, then by distance from 1 on a log scale, in before out
    order = sorted(taught, key=lambda f: (round(abs(float(np.log(f))), 9), f < 1.0))
    pairs = [
        (current, target)
        if factor == 1.0
        else _as_frame_zoom(current, taught[factor], factor, params.features)
        for factor in order
    ]
    return _best_zoom(pairs, order, params, fit)
