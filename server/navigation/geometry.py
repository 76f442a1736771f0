"""The taught paths as geometry: every taught image's pose on its edge, from odometry.

While teaching, the robot reports the motion it executed with every frame (``v`` m/s, ``w``
rad/s: its odometry since the frame before). Dead-reckoning those motions along an edge gives
every image of the edge a pose relative to the edge's first image (``x`` forward, ``y`` left,
``theta`` counter-clockwise, metres and radians): the edge's *frame*. Nothing here comes from a
simulator's truth; drift accumulates along an edge, but a path tracker only ever uses the poses
near where the robot is (VT&R's pose relative to the nearest taught vertex).

Poses are ``(..., 3)`` float64 arrays ``(x, y, theta)``. Pure: NumPy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import numpy.typing as npt

from server.domain import Edge, TourGraph

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def wrap(angle: npt.ArrayLike) -> FloatArray:
    """Angles wrapped to ``[-pi, pi)``."""
    a = np.asarray(angle, dtype=np.float64)
    out: FloatArray = (a + np.pi) % (2 * np.pi) - np.pi
    return out


def compose(a: npt.ArrayLike, b: npt.ArrayLike) -> FloatArray:
    """``a (+) b``: pose ``b`` (relative to ``a``) in the frame ``a`` is given in."""
    pa, pb = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    c, s = np.cos(pa[..., 2]), np.sin(pa[..., 2])
    x = pa[..., 0] + c * pb[..., 0] - s * pb[..., 1]
    y = pa[..., 1] + s * pb[..., 0] + c * pb[..., 1]
    return np.stack([x, y, wrap(pa[..., 2] + pb[..., 2])], axis=-1)


def inverse(a: npt.ArrayLike) -> FloatArray:
    """``(-) a``: the pose of the frame ``a`` is given in, relative to ``a``."""
    pa = np.asarray(a, dtype=np.float64)
    c, s = np.cos(pa[..., 2]), np.sin(pa[..., 2])
    x = -c * pa[..., 0] - s * pa[..., 1]
    y = s * pa[..., 0] - c * pa[..., 1]
    return np.stack([x, y, wrap(-pa[..., 2])], axis=-1)


def relative(a: npt.ArrayLike, b: npt.ArrayLike) -> FloatArray:
    """``(-) a (+) b``: pose ``b`` seen from pose ``a`` (both in one frame)."""
    return compose(inverse(a), b)


def dead_reckon(timestamps: npt.ArrayLike, v: npt.ArrayLike, w: npt.ArrayLike) -> FloatArray:
    """``(n, 3)`` poses of ``n`` frames relative to the first, from their odometry.

    Frame ``k``'s motion ``(v[k], w[k])`` is the robot's mean speed over the interval that
    ends at ``timestamps[k]`` (what a robot's odometry reports with a frame); frame 0's is
    before the path and is not used. Each interval is integrated as an arc (exact for constant
    speeds); an interval with a missing or backward timestamp adds nothing.
    """
    t = np.asarray(timestamps, dtype=np.float64)
    n = len(t)
    if n == 0:
        return np.zeros((0, 3))
    dt = np.concatenate([[0.0], np.clip(np.diff(t), 0.0, None)])
    dt = np.where(np.isfinite(dt), dt, 0.0)
    vv = np.nan_to_num(np.asarray(v, dtype=np.float64)) * dt
    ww = np.nan_to_num(np.asarray(w, dtype=np.float64)) * dt
    vv[0] = ww[0] = 0.0
    theta = np.cumsum(ww)
    before = theta - ww
    # chord of an arc of length vv turning by ww: vv * sinc(ww / 2), along the mid heading
    chord = vv * np.sinc(ww / (2 * np.pi))
    mid = before + ww / 2
    x = np.cumsum(chord * np.cos(mid))
    y = np.cumsum(chord * np.sin(mid))
    return np.stack([x, y, wrap(theta)], axis=1)


STAND_M = 0.02
"""Images taught within this many metres along of each other stand at one spot (a turn on
the spot there), m."""


@dataclass(frozen=True)
class EdgePath:
    """One taught edge as a path: its images' poses in the edge's frame.

    Attributes:
        poses: ``(n, 3)`` every image's pose relative to the edge's first image.
        along: ``(n,)`` metres of the path (the poses' positions joined) up to each image.
    """

    poses: FloatArray
    along: FloatArray

    @classmethod
    def of(cls, edge: Edge) -> EdgePath:
        """The path of ``edge``, dead-reckoned from its taught odometry."""
        poses = dead_reckon(edge.timestamps, edge.v, edge.w)
        steps = np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1)
        return cls(poses, np.concatenate([[0.0], np.cumsum(steps)]))

    @property
    def n_images(self) -> int:
        return len(self.poses)

    @property
    def length(self) -> float:
        """Metres from the first image to the last."""
        return float(self.along[-1]) if len(self.along) else 0.0

    @cached_property
    def polyline(self) -> tuple[FloatArray, FloatArray, IntArray]:
        """The path without its standing-still stretches: ``(m, 2)`` positions at least 1 cm
        apart, their ``(m,)`` metres along, and for each the image it was taken from."""
        keep = [0]
        for k in range(1, self.n_images):
            if self.along[k] - self.along[keep[-1]] >= 0.01:
                keep.append(k)
        idx = np.asarray(keep, dtype=np.int64)
        return self.poses[idx, :2], self.along[idx], idx

    def image_at(self, s: float, heading: float | None = None) -> int:
        """The image taught nearest ``s`` metres along: the first of a standing-still
        stretch (where the robot got there), or with ``heading`` (radians, the edge's frame)
        the image of that stretch taught facing nearest it (where the teacher turned on the
        spot, as at a place before setting off: the first image faced the way before the
        turn)."""
        k = int(np.searchsorted(self.along, s, side="left"))
        k = min(max(k, 0), self.n_images - 1)
        if k > 0 and abs(self.along[k - 1] - s) <= abs(self.along[k] - s):
            k -= 1
        while k > 0 and self.along[k - 1] == self.along[k]:
            k -= 1
        if heading is None:
            return k
        stretch = self.stretch(k)
        off = np.abs(wrap(self.poses[stretch, 2] - heading))
        return int(stretch[int(np.argmin(off))])

    def stretch(self, k: int) -> IntArray:
        """``(m,)`` the images taught standing at image ``k``'s spot: within ``STAND_M``
        along of it (``k`` among them), in order."""
        a = float(self.along[k])
        lo = int(np.searchsorted(self.along, a - STAND_M, side="right"))
        hi = int(np.searchsorted(self.along, a + STAND_M, side="left"))
        return np.arange(lo, hi, dtype=np.int64)

    def point_at(self, s: float) -> FloatArray:
        """``(2,)`` the position ``s`` metres along (clamped to the path's ends)."""
        pts, along, _ = self.polyline
        if len(pts) == 1:
            return pts[0].copy()
        s = float(np.clip(s, 0.0, along[-1]))
        k = min(int(np.searchsorted(along, s, side="right")) - 1, len(pts) - 2)
        span = along[k + 1] - along[k]
        f = 0.0 if span <= 0 else (s - along[k]) / span
        out: FloatArray = pts[k] + f * (pts[k + 1] - pts[k])
        return out

    def heading_at(self, s: float) -> float:
        """The path's direction ``s`` metres along (of the stretch there), radians; the
        taught heading where the path has no length."""
        pts, along, _ = self.polyline
        if len(pts) < 2:
            return float(self.poses[-1, 2]) if self.n_images else 0.0
        k = min(max(int(np.searchsorted(along, s, side="right")) - 1, 0), len(pts) - 2)
        d = pts[k + 1] - pts[k]
        return math.atan2(float(d[1]), float(d[0]))

    def project(self, xy: npt.ArrayLike) -> tuple[float, float]:
        """Where position ``xy`` (in the edge's frame) lies against the path: ``(s, lateral)``,
        metres along the path of its nearest point and metres to the left of the path there
        (negative: to the right). Beyond either end, ``s`` is clamped and ``lateral`` is the
        signed distance to the line through the end."""
        p = np.asarray(xy, dtype=np.float64)
        pts, along, _ = self.polyline
        if len(pts) == 1:
            d = p - pts[0]
            th = float(self.poses[0, 2])
            return 0.0, float(-math.sin(th) * d[0] + math.cos(th) * d[1])
        a, b = pts[:-1], pts[1:]
        ab = b - a
        ab2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12)
        f = np.clip(np.einsum("ij,ij->i", p - a, ab) / ab2, 0.0, 1.0)
        near = a + f[:, None] * ab
        d2 = np.einsum("ij,ij->i", p - near, p - near)
        k = int(np.argmin(d2))
        s = float(along[k] + f[k] * (along[k + 1] - along[k]))
        cross = float(ab[k, 0] * (p[1] - a[k, 1]) - ab[k, 1] * (p[0] - a[k, 0]))
        dist = math.sqrt(float(d2[k]))
        if dist < 1e-9:
            return s, 0.0
        return s, math.copysign(dist, cross)


@dataclass(frozen=True)
class TaughtPaths:
    """Every edge of a tour as an :class:`EdgePath` (index = edge index)."""

    edges: tuple[EdgePath, ...]

    @classmethod
    def of(cls, graph: TourGraph) -> TaughtPaths:
        return cls(tuple(EdgePath.of(e) for e in graph.edges))

    def __getitem__(self, edge: int) -> EdgePath:
        return self.edges[edge]

    def __len__(self) -> int:
        return len(self.edges)
