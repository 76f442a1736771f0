"""Monte-Carlo localisation over metric poses, weighted by image-retrieval scores (seed 002).

Wolf, Burgard & Burkhardt weight the samples of a particle filter over ``(x, y, heading)`` by
the similarity of the reference images whose visibility region holds them (their eq. 5:
``w = sum_i I(xy in sigma_i) d(psi) xi_i``). Here the reference images are the taught images
that carry a pose (``TourGraph.image_pose``: the teaching robot's odometry, or the simulator's
truth), and a soft kernel stands in for the visibility region, which needs a metric map this
system does not have:

* **predict** (:func:`predict`): every particle moves by the reported odometry ``(v, w)`` over
  ``dt``, with multiplicative noise on each (``noise_v``, ``noise_w``) and a little additive
  noise (``noise_xy_m`` per metre, ``noise_theta``), midpoint-heading integration.
* **weigh** (:func:`likelihood`): the ``top_k`` best-scoring images of the frame; a particle's
  likelihood is ``floor + sum_k s_k^sharpness exp(-d_k^2 / 2 sigma_xy^2) exp((cos dtheta_k - 1)
  / sigma_theta^2)`` with ``d_k`` its distance to image k's pose and ``dtheta_k`` the heading
  difference (seen from elsewhere, or facing another way, the image would not have matched;
  the heading kernel is von Mises, ``~ exp(-dtheta^2 / 2 sigma_theta^2)`` for small angles,
  so that both kernels come from matrix products).
* **temper** (:func:`temper`): the likelihood, scaled so that its best particle has 1, is
  raised to a power below 1 (``temper``). Consecutive frames are not independent views (a
  robot turning on the spot sees the same look-alike door for a second; one off the taught
  paths still has a best match): taken at face value, each such frame cut the weight of the
  particles at the right place to 1e-3 of the best ones', resampling soon dropped them and
  the cloud settled in the look-alike.
* **resample** (:func:`resample`, systematic) when the effective sample size falls below
  ``resample_ess`` of the particles; then ``inject`` of them are re-drawn at the poses of the
  best-scoring images (sensor resetting: a kidnapped robot or a wrong mode recovers).
* **estimate** (:func:`estimate`): the densest cell of a ``cell_m`` grid, and the weighted mean
  of the particles within ``mode_m`` of it (a mean over two look-alike rooms would stand in the
  wall between them); its uncertainty: the weighted spread of the whole cloud (``std_m``) and
  the weight within the mode (``mode_mass``).

It runs beside the topological belief and never changes it. Everything is vectorised over the
particles (``(P, 3)`` arrays, a ``(P, K)`` kernel); no Python loop per particle.

This module imports NumPy and the core only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "MclEstimate",
    "MclParams",
    "MonteCarloLocaliser",
    "effective_size",
    "estimate",
    "initial",
    "likelihood",
    "predict",
    "resample",
    "temper",
    "wrap",
]


@dataclass(frozen=True)
class MclParams:
    """Monte-Carlo localisation settings (units in brackets).

    * ``enabled`` (False): run it beside the topological belief (taught images need poses).
    * ``particles`` (1000).
    * ``init_spread_m`` (1.0 m): a uniform start draws particles at random taught poses,
      spread this much, facing anywhere.
    * ``noise_v`` (0.1) / ``noise_w`` (0.15): std of the fractional error of the odometry's
      forward and turning speeds, per frame (the simulated robot reports 0.05 / 0.08).
    * ``noise_xy_m`` (0.02 m per metre, at least 0.005 m a moving frame) and ``noise_theta``
      (0.02 rad a moving frame): additive diffusion.
    * ``top_k`` (30): the best-scoring images that weigh the particles.
    * ``sharpness`` (4): a score counts as ``score ** sharpness`` (the engine's scores are
      relative: 1 for the best candidate, 0 for the worst).
    * ``sigma_xy_m`` (0.4 m) / ``sigma_theta`` (0.5 rad): the kernel around an image's pose.
    * ``floor`` (0.2): likelihood of a particle near no matching image, relative to one
      sitting on the best image (1e-3 before 2026-11-29).
    * ``temper`` (0.1): the power each frame's likelihood is raised to (1 with ``floor``
      1e-3: the likelihood as it is, the behaviour before 2026-11-29). ``floor`` and
      ``temper`` were chosen on the apartment and the office floor (seed 100) and the
      corridor's route (docs/ambiguity.md 5.2).
    * ``resample_ess`` (0.5): resample when the effective sample size is below this fraction.
    * ``inject`` (0.03): after resampling this fraction of particles is re-drawn at the poses
      of the best-scoring images (spread ``inject_spread_m`` 0.3 m, ``noise_theta`` x 5).
    * ``cell_m`` (0.5 m) / ``mode_m`` (1.0 m): the grid that finds the densest place, and the
      radius of the mode averaged around it.
    * ``seed`` (0): the filter's random numbers restart from this with every task, so a
      navigation trial gives the same estimates whatever ran before it.
    """

    enabled: bool = False
    particles: int = 1000
    init_spread_m: float = 1.0
    noise_v: float = 0.1
    noise_w: float = 0.15
    noise_xy_m: float = 0.02
    noise_theta: float = 0.02
    top_k: int = 30
    sharpness: float = 4.0
    sigma_xy_m: float = 0.4
    sigma_theta: float = 0.5
    floor: float = 0.2
    temper: float = 0.1
    resample_ess: float = 0.5
    inject: float = 0.03
    inject_spread_m: float = 0.3
    cell_m: float = 0.5
    mode_m: float = 1.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.particles < 1 or self.top_k < 1:
            raise ValueError("particles and top_k must be at least 1")
        for name in (
            "init_spread_m",
            "noise_v",
            "noise_w",
            "noise_xy_m",
            "noise_theta",
            "sharpness",
            "floor",
            "temper",
            "inject_spread_m",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"MclParams.{name} must be finite and >= 0")
        for name in ("sigma_xy_m", "sigma_theta", "cell_m", "mode_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"MclParams.{name} must be finite and > 0")
        if not (0 <= self.resample_ess <= 1 and 0 <= self.inject < 1):
            raise ValueError("resample_ess must lie in [0, 1] and inject in [0, 1)")


@dataclass(frozen=True)
class MclEstimate:
    """The filter's answer after a frame: ``x``, ``y`` (m) and ``theta`` (rad) of the densest
    mode, ``std_m`` the weighted spread of all particles around their mean (m),
    ``mode_mass`` the weight within ``mode_m`` of the mode, ``ess`` the effective sample
    size (fraction), and a few particles (``cloud``, ``(n, 3)``) for drawing."""

    x: float
    y: float
    theta: float
    std_m: float
    mode_mass: float
    ess: float
    cloud: FloatArray


def wrap(angle: npt.ArrayLike) -> FloatArray:
    """Angles wrapped to ``[-pi, pi)``."""
    a = np.asarray(angle, dtype=np.float64)
    out: FloatArray = (a + np.pi) % (2.0 * np.pi) - np.pi
    return out


def initial(
    poses: npt.ArrayLike, n: int, rng: np.random.Generator, *, spread_m: float = 1.0
) -> FloatArray:
    """``(n, 3)`` particles of a uniform start over the taught paths: at random poses of
    ``(N, 3)`` ``poses``, spread ``spread_m`` (Gaussian std) in x and y, any heading."""
    pts = np.asarray(poses, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise ValueError(f"poses must be (N, 3) with N >= 1, got {pts.shape}")
    pick = pts[rng.integers(len(pts), size=n)]
    xy = pick[:, :2] + rng.normal(0.0, spread_m, size=(n, 2))
    theta = rng.uniform(-np.pi, np.pi, size=n)
    return np.column_stack([xy, theta])


def predict(
    particles: npt.ArrayLike,
    v: float,
    w: float,
    dt: float,
    noise: npt.ArrayLike,
    params: MclParams,
) -> FloatArray:
    """``(P, 3)`` particles moved by odometry ``v`` (m/s), ``w`` (rad/s) over ``dt`` (s).

    ``noise`` is ``(P, 5)`` standard normal draws (fractional v, fractional w, additive
    position along the motion and across it, heading) so a test can replay them. Each particle
    drives ``v_i dt`` along its heading turned by half of ``w_i dt`` and turns ``w_i dt``;
    nothing diffuses while ``dt`` is 0.
    """
    p = np.asarray(particles, dtype=np.float64)
    z = np.asarray(noise, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or z.shape != (len(p), 5):
        raise ValueError(f"particles must be (P, 3) and noise (P, 5), got {p.shape}, {z.shape}")
    if not dt > 0:
        return p.copy()
    vi = v * (1.0 + params.noise_v * z[:, 0])
    wi = w * (1.0 + params.noise_w * z[:, 1])
    dist = vi * dt
    spread = max(params.noise_xy_m * abs(v * dt), 0.005)
    heading = p[:, 2] + 0.5 * wi * dt
    c, s = np.cos(heading), np.sin(heading)
    along = dist + spread * z[:, 2]
    across = spread * z[:, 3]
    x = p[:, 0] + along * c - across * s
    y = p[:, 1] + along * s + across * c
    theta = p[:, 2] + wi * dt + params.noise_theta * z[:, 4]
    return np.column_stack([x, y, wrap(theta)])


def likelihood(
    particles: npt.ArrayLike,
    poses: npt.ArrayLike,
    scores: npt.ArrayLike,
    params: MclParams,
) -> FloatArray:
    """``(P,)`` likelihood of each particle given the frame's ``(K,)`` ``scores`` of the images
    taught at ``(K, 3)`` ``poses`` (002 eq. 5 with a Gaussian kernel in place of the
    visibility region): ``floor * max_k s_k^q + sum_k s_k^q g(d_k) h(dtheta_k)``, ``q`` the
    sharpness, ``g`` Gaussian (``sigma_xy_m``), ``h`` von Mises (``sigma_theta``). The
    ``(P, K)`` distances and heading cosines come from matrix products."""
    p = np.asarray(particles, dtype=np.float64)
    at = np.asarray(poses, dtype=np.float64)
    s = np.asarray(scores, dtype=np.float64) ** params.sharpness
    if at.shape != (len(s), 3):
        raise ValueError(f"poses {at.shape} and scores {s.shape} do not match")
    if len(s) == 0:
        return np.ones(len(p))
    xy, txy = p[:, :2], at[:, :2]
    d2 = (xy * xy).sum(axis=1)[:, None] + (txy * txy).sum(axis=1)[None, :] - 2.0 * xy @ txy.T
    heading = np.column_stack([np.cos(p[:, 2]), np.sin(p[:, 2])])
    taught = np.column_stack([np.cos(at[:, 2]), np.sin(at[:, 2])])
    cos_d = heading @ taught.T
    exponent = -0.5 / params.sigma_xy_m**2 * np.maximum(d2, 0.0)
    exponent += (cos_d - 1.0) / params.sigma_theta**2
    out: FloatArray = np.exp(exponent) @ s + params.floor * float(s.max())
    return out


def temper(lik: npt.ArrayLike, power: float) -> FloatArray:
    """``(P,)`` likelihoods scaled so that the largest is 1, raised to ``power`` (0: all 1,
    the frame weighs nothing; all-zero likelihoods give all 1 too)."""
    x = np.asarray(lik, dtype=np.float64)
    top = float(x.max()) if len(x) else 0.0
    if top <= 0 or power == 0:
        return np.ones(len(x))
    out: FloatArray = (x / top) ** power
    return out


def effective_size(weights: npt.ArrayLike) -> float:
    """``1 / sum w^2`` of normalised ``weights``, as a fraction of their number."""
    w = np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    return float(1.0 / (w @ w) / len(w))


def resample(weights: npt.ArrayLike, u: float) -> npt.NDArray[np.int64]:
    """Systematic resampling: ``(P,)`` indices of the particles drawn, one uniform ``u`` in
    [0, 1) for all (low variance: a particle of weight w is drawn floor(P w) or ceil(P w)
    times)."""
    w = np.asarray(weights, dtype=np.float64)
    n = len(w)
    edges = np.cumsum(w / w.sum())
    edges[-1] = 1.0
    picks = (u + np.arange(n)) / n
    return np.minimum(np.searchsorted(edges, picks, side="right"), n - 1).astype(np.int64)


def estimate(
    particles: npt.ArrayLike, weights: npt.ArrayLike, params: MclParams
) -> tuple[float, float, float, float, float]:
    """``(x, y, theta, std_m, mode_mass)`` of weighted ``(P, 3)`` particles (see the module
    docstring): the densest ``cell_m`` cell, the weighted mean (circular for the heading) of
    the particles within ``mode_m`` of its centre, the spread of the whole cloud and the
    weight within the mode."""
    p = np.asarray(particles, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    cells = np.floor(p[:, :2] / params.cell_m).astype(np.int64)
    cells -= cells.min(axis=0)
    key = cells[:, 0] * (int(cells[:, 1].max()) + 1) + cells[:, 1]
    keys, inverse = np.unique(key, return_inverse=True)
    mass = np.bincount(inverse, weights=w, minlength=len(keys))
    densest = int(np.argmax(mass))
    centre = (np.floor(p[inverse == densest][0, :2] / params.cell_m) + 0.5) * params.cell_m
    near = np.hypot(p[:, 0] - centre[0], p[:, 1] - centre[1]) <= params.mode_m
    wm = np.where(near, w, 0.0)
    mode_mass = float(wm.sum())
    x = float(wm @ p[:, 0] / mode_mass)
    y = float(wm @ p[:, 1] / mode_mass)
    theta = float(np.arctan2(wm @ np.sin(p[:, 2]), wm @ np.cos(p[:, 2])))
    mean = w @ p[:, :2]
    std = float(np.sqrt(w @ ((p[:, :2] - mean) ** 2).sum(axis=1)))
    return x, y, theta, std, mode_mass


class MonteCarloLocaliser:
    """The particle filter of one robot on one tour (holds its particles and random numbers).

    ``MonteCarloLocaliser(poses, params)`` with ``(n_images, 3)`` ``poses`` of the tour's
    images in canonical order (all finite); :meth:`reset` for a uniform start; :meth:`step`
    once per frame with the odometry and the frame's ``(n_images,)`` image scores.
    """

    CLOUD = 200
    """Particles handed out with every estimate (for drawing)."""

    def __init__(self, poses: npt.ArrayLike, params: MclParams | None = None) -> None:
        self.poses = np.asarray(poses, dtype=np.float64)
        if self.poses.ndim != 2 or self.poses.shape[1] != 3 or len(self.poses) == 0:
            raise ValueError("poses must be (n_images, 3) with at least one image")
        if not np.all(np.isfinite(self.poses)):
            raise ValueError("every taught image needs a pose for Monte-Carlo localisation")
        self.params = params if params is not None else MclParams()
        self.reset()

    def reset(self) -> None:
        """A uniform start over the taught paths; the random numbers restart from the seed."""
        p = self.params
        self.rng = np.random.default_rng(p.seed)
        self.particles = initial(self.poses, p.particles, self.rng, spread_m=p.init_spread_m)
        self.weights = np.full(p.particles, 1.0 / p.particles)

    def step(self, *, v: float, w: float, dt: float, scores: npt.ArrayLike) -> MclEstimate:
        """Predict with the odometry, weigh with the frame's image ``scores`` (tempered,
        :func:`temper`), resample when degenerate, estimate."""
        p = self.params
        s = np.asarray(scores, dtype=np.float64)
        if s.shape != (len(self.poses),):
            raise ValueError(f"scores has shape {s.shape}, expected ({len(self.poses)},)")
        noise = self.rng.standard_normal(size=(len(self.particles), 5))
        self.particles = predict(self.particles, v, w, dt, noise, p)
        k = min(p.top_k, len(s))
        top = np.argpartition(-s, k - 1)[:k]
        lik = likelihood(self.particles, self.poses[top], s[top], p)
        w_new = self.weights * temper(lik, p.temper)
        self.weights = (
            w_new / w_new.sum() if w_new.sum() > 0 else np.full_like(w_new, 1 / len(w_new))
        )
        ess = effective_size(self.weights)
        x, y, theta, std, mode_mass = estimate(self.particles, self.weights, p)
        cloud = self.particles[:: max(1, len(self.particles) // self.CLOUD)].copy()
        if ess < p.resample_ess:
            self._resample(self.poses[top], s[top])
        return MclEstimate(x, y, theta, std, mode_mass, ess, cloud)

    def _resample(self, poses: FloatArray, scores: FloatArray) -> None:
        p = self.params
        n = len(self.particles)
        self.particles = self.particles[resample(self.weights, float(self.rng.random()))]
        m = round(p.inject * n)
        if m > 0:
            q = scores**p.sharpness
            pick = self.rng.choice(len(poses), size=m, p=q / q.sum())
            fresh = poses[pick] + self.rng.normal(0.0, 1.0, size=(m, 3)) * [
                p.inject_spread_m,
                p.inject_spread_m,
                5 * p.noise_theta,
            ]
            fresh[:, 2] = wrap(fresh[:, 2])
            self.particles[self.rng.choice(n, size=m, replace=False)] = fresh
        self.weights = np.full(n, 1.0 / n)
