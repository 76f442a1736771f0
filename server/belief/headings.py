"""A place's likelihood through the heading the robot faces there.

001 eq. 2 gives a place the best of its spin views' similarities, frame by frame. Turning
anywhere, some spin view of every place matches each frame (a wall, a doorway), so a robot
turning on the spot in a corridor looks, frame after frame, like a robot at a place. Here every
place keeps a distribution over the headings of its spin (the turn taught there), conditioned
on the robot standing there: turned every frame by the robot's odometry, it predicts which
spin views the frame should match, and the place's likelihood is that prediction's
expectation of the views' similarities (the predictive likelihood of an HMM over headings).
At the place, after a few frames the distribution settles on the heading the robot faces and
the likelihood is that view's similarity, the best one (as eq. 2 gives); elsewhere a run of
frames has to agree with the spin's order as the odometry turns the robot.

Shapes: ``K`` appearance models, ``L`` locations, ``B`` heading bins per location
(:attr:`HeadingParams.bins`), ``n_images`` the tour's images in canonical order (the
locations' spin images first, location by location).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from server.domain import TourGraph

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class HeadingParams:
    """The heading filter's settings (fixed a priori, not tuned).

    * ``enabled`` (True): ``False`` gives a place the best of its spin views every frame
      (001 eq. 2).
    * ``bins`` (36): heading bins per place (10 degrees each); a bin's similarity is the best
      of the spin images taught facing into it.
    * ``sd_rad`` (0.05 rad) and ``turn_sd`` (0.1, per radian turned): the heading's noise
      added every frame, on top of the odometry's turn.
    * ``forget`` (0.02): the share of every place's distribution mixed back to uniform every
      frame (a robot carried, a turn the odometry missed).
    """

    enabled: bool = True
    bins: int = 36
    sd_rad: float = 0.05
    turn_sd: float = 0.1
    forget: float = 0.02

    def __post_init__(self) -> None:
        if self.bins < 3:
            raise ValueError(f"bins must be >= 3, got {self.bins}")
        if self.sd_rad < 0 or self.turn_sd < 0:
            raise ValueError("sd_rad and turn_sd must be >= 0")
        if not 0.0 <= self.forget <= 1.0:
            raise ValueError(f"forget must be in [0, 1], got {self.forget}")


def spin_headings(timestamps: npt.ArrayLike, w: npt.ArrayLike) -> FloatArray:
    """``(n,)`` each spin image's heading relative to the first, rad (counter-clockwise),
    dead-reckoned from the spin's own odometry: image ``k``'s ``w[k]`` (rad/s) is the rate over
    the interval that ends at ``timestamps[k]`` (s). Without usable odometry (missing,
    non-finite, or a spin that turned less than half a turn either way) the images are taken as
    evenly spaced over one counter-clockwise turn."""
    t = np.asarray(timestamps, dtype=np.float64)
    rate = np.asarray(w, dtype=np.float64)
    n = len(t)
    even = np.arange(n, dtype=np.float64) * (2 * math.pi / max(n, 1))
    if n < 2 or rate.shape != t.shape or not (np.all(np.isfinite(t)) and np.all(np.isfinite(rate))):
        return even
    turned = np.concatenate([[0.0], np.cumsum(rate[1:] * np.clip(np.diff(t), 0.0, None))])
    if abs(turned[-1]) < math.pi:
        return even
    return turned


@dataclass(frozen=True)
class HeadingBins:
    """Which heading bin every spin image of a tour falls in, built once per graph.

    ``order`` sorts the ``(n_loc,)`` location images by (location, bin); ``starts`` are the
    first of each non-empty (location, bin) group in that order and ``cell`` its flat index
    ``location * bins + bin``."""

    n_locations: int
    bins: int
    n_loc_images: int
    order: IntArray
    starts: IntArray
    cell: IntArray

    @classmethod
    def of(cls, graph: TourGraph, bins: int) -> HeadingBins:
        """Bin every spin image by its heading (:func:`spin_headings` of its location's spin;
        the first image's bin centred on heading 0)."""
        loc_of: list[IntArray] = []
        bin_of: list[IntArray] = []
        width = 2 * math.pi / bins
        for k, loc in enumerate(graph.locations):
            n = len(loc.image_ids)
            if n == 0:
                continue
            heading = spin_headings(loc.timestamps, loc.w) if len(loc.timestamps) == n else None
            if heading is None:
                heading = spin_headings(np.zeros(n), np.zeros(n))
            b = np.floor(np.mod(heading + width / 2, 2 * math.pi) / width).astype(np.int64) % bins
            loc_of.append(np.full(n, k, dtype=np.int64))
            bin_of.append(b)
        if not loc_of:
            empty = np.zeros(0, dtype=np.int64)
            return cls(graph.n_locations, bins, 0, empty, empty, empty)
        flat = np.concatenate(loc_of) * bins + np.concatenate(bin_of)
        order = np.argsort(flat, kind="stable").astype(np.int64)
        ordered = flat[order]
        first = np.flatnonzero(np.concatenate([[True], ordered[1:] != ordered[:-1]]))
        return cls(
            graph.n_locations, bins, len(flat), order, first.astype(np.int64), ordered[first]
        )

    def similarities(self, location_sims: npt.ArrayLike, floor: float) -> FloatArray:
        """``(K, L, B)`` each bin's similarity, the best of its spin images' (``(K, n_loc)``
        ``location_sims``, canonical order). A bin no spin image faces into (the spin's
        images further apart than a bin) takes the mean of the nearest bins either side that
        have one: the spin did not look there, which says nothing against the place. A place
        without images: ``floor`` throughout."""
        s = np.asarray(location_sims, dtype=np.float64)
        out = np.full((s.shape[0], self.n_locations * self.bins), np.nan)
        if self.n_loc_images:
            out[:, self.cell] = np.maximum.reduceat(s[:, self.order], self.starts, axis=1)
        grid = out.reshape(s.shape[0], self.n_locations, self.bins)
        grid = np.where(np.isnan(grid).all(axis=-1, keepdims=True), floor, grid)
        left, right = grid.copy(), grid.copy()
        for _ in range(self.bins):  # each empty bin: its nearest filled bin on each side
            if not np.isnan(left).any():
                break
            left = np.where(np.isnan(left), np.roll(left, 1, axis=-1), left)
            right = np.where(np.isnan(right), np.roll(right, -1, axis=-1), right)
        grid = np.where(np.isnan(grid), (left + right) / 2, grid)
        return np.maximum(grid, floor)


def turn(q: npt.ArrayLike, dtheta: float, params: HeadingParams) -> FloatArray:
    """Prediction: ``(..., B)`` heading distributions turned by ``dtheta`` rad (the robot's
    odometry, counter-clockwise), the fractional bin shared linearly between the two bins it
    falls between, blurred by ``sd_rad + turn_sd * |dtheta|`` and mixed with uniform by
    ``forget``. Mass-preserving; returns a new array."""
    p = np.asarray(q, dtype=np.float64)
    bins = p.shape[-1]
    width = 2 * math.pi / bins
    shift = dtheta / width
    whole = math.floor(shift)
    frac = shift - whole
    out = (1 - frac) * np.roll(p, whole, axis=-1) + frac * np.roll(p, whole + 1, axis=-1)
    sd = params.sd_rad + params.turn_sd * abs(dtheta)
    a = min(0.25, 0.5 * (sd / width) ** 2)
    if a > 0:
        out = (1 - 2 * a) * out + a * (np.roll(out, 1, axis=-1) + np.roll(out, -1, axis=-1))
    return np.asarray((1 - params.forget) * out + params.forget / bins, dtype=np.float64)


def expect(q: npt.ArrayLike, s: npt.ArrayLike) -> FloatArray:
    """``(..., )`` each place's predictive likelihood: the ``(..., B)`` heading distribution's
    expectation of the ``(..., B)`` bins' similarities."""
    return np.asarray(np.sum(np.asarray(q) * np.asarray(s), axis=-1), dtype=np.float64)


def correct(q: npt.ArrayLike, s: npt.ArrayLike) -> FloatArray:
    """Correction: ``q * s`` normalised over the bins (uniform where that is all zero)."""
    post = np.asarray(q, dtype=np.float64) * np.asarray(s, dtype=np.float64)
    total = post.sum(axis=-1, keepdims=True)
    bins = post.shape[-1]
    return np.where(total > 0, post / np.where(total > 0, total, 1.0), 1.0 / bins)


class PlaceHeadings:
    """One robot's heading filter over every place of its tour, one per appearance model
    (``q``: ``(K, L, B)``, uniform until the first frame and whenever the number of models
    changes)."""

    def __init__(self, graph: TourGraph, params: HeadingParams) -> None:
        self.graph = graph
        self.params = params
        self.bins = HeadingBins.of(graph, params.bins)
        self.q = np.full((0, graph.n_locations, params.bins), 1.0 / params.bins)

    def reset(self) -> None:
        """Every place's heading uniform again (a belief that restarts from the prior)."""
        self.q = np.full((0, self.graph.n_locations, self.params.bins), 1.0 / self.params.bins)

    def likelihood(
        self, image_sims: npt.ArrayLike, turned: float, *, floor: float = 1e-3
    ) -> FloatArray:
        """``(K, n_fine)`` the frame's likelihood of every fine state from the ``(K, n_images)``
        engine similarities (canonical order) after the robot turned ``turned`` rad since the
        last frame: a place's through its heading distribution (:func:`expect` of the turned
        one, which is then corrected by the frame), an edge image its own similarity, every
        value at least ``floor`` (as :func:`~server.belief.tracker.fine_likelihood`)."""
        g = self.graph
        sims = np.atleast_2d(np.asarray(image_sims, dtype=np.float64))
        if sims.ndim != 2 or sims.shape[1] != g.n_images:
            raise ValueError(
                f"image_sims has shape {sims.shape}, expected (K, {g.n_images}): one row per "
                "appearance model, one similarity per image of the tour in canonical order"
            )
        if self.q.shape[0] != sims.shape[0]:
            self.q = np.full((sims.shape[0], g.n_locations, self.params.bins), 1 / self.params.bins)
        n_loc = self.bins.n_loc_images
        s = self.bins.similarities(sims[:, :n_loc], floor)
        predicted = turn(self.q, turned, self.params)
        out = np.full((sims.shape[0], g.n_fine), float(floor))
        has = np.fromiter((len(loc.image_ids) > 0 for loc in g.locations), bool, g.n_locations)
        out[:, : g.n_locations][:, has] = expect(predicted, s)[:, has]
        out[:, g.n_locations :] = sims[:, n_loc:]
        self.q = correct(predicted, s)
        np.maximum(out, floor, out=out)
        return out
