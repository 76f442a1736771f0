"""Learned transitions (001 section 10.1): refine the taught motion model from finished runs.

001 hand-tunes its transition probabilities and names the hybrid as future work: "begin with the
hand-tuned probabilities, and refine them by learning from experience", and "learn that some
edges are harder to traverse than others". Here the refined quantity is the lower layer's
**advance per step along each edge** (:meth:`BeliefModel.expected_advance`, images per frame),
which the taught model derives from the teaching run's pace; a robot that drives an edge slower
or faster than it was taught (a difficult curve, a carpet, a different camera rate) makes the
belief lag or lead the truth.

From one finished run (the filter's steps, :class:`FilterStep`) a forward-backward pass gives
the smoothed marginals ``gamma_t = P(x_t | all frames)``. Per edge ``e`` and forward-driving
step ``t``, let ``w_t(e) = min(gamma_{t-1}(e), gamma_t(e))`` (the mass that was on ``e`` at both
ends of the step; 0 below ``TransitionLearnParams.min_mass``) and ``mu_t(e)`` the smoothed
most likely position along ``e`` (images; the mean was tried first: a broad posterior on a
short edge is clipped at its ends, which compresses the mean's travel and learned 0.83-0.90 on
the corridor data, whose traversals have the same pace; the mode learned 0.87-0.96 there and
1.00 on clean synthetic runs). The
**expected counts** are

* ``steps[e] = sum_t w_t(e)``: expected steps spent driving along ``e``,
* ``moved[e] = sum_t w_t(e) (mu_t(e) - mu_{t-1}(e))``: expected images moved,
* ``taught[e] = sum_t w_t(e) k_t(e)``: what the taught kernel expected over those same steps
  (``k_t(e)`` its mean offset at that step's advance; a run filtered with a learned model
  divides by its scale, so counts of every run stay relative to the taught model and add).

Why smoothed positions and not the pairwise marginals ``xi_t(i, j)``: the taught kernel is
narrow (a few images around the expected advance), so a pairwise marginal cannot show a move
the kernel rules out; the filter explains a robot that drives 1.6 images a frame where the
kernel says 1 by its kidnap mixing, and the pairwise counts of in-edge moves stay at ~1 (tried:
1.03 on the synthetic test below). The smoothed positions follow the images, whatever path
the model took to get there.

Counts of several runs add (:meth:`TransitionCounts.plus`). The learned advance scale is a
conjugate-style rate estimate shrunk toward the taught model by a **pseudo-count** of
``prior_images`` images of taught advance at rate 1, first for the whole tour and then per edge
toward the tour's rate (:func:`advance_scale`)::

    r_tour = (sum moved + k) / (sum taught + k)
    r[e]   = (moved[e] + k * r_tour) / (taught[e] + k)

so zero evidence gives exactly 1 (the taught model), an edge seen once moves little, an edge
seen on many runs follows them. The scaled model stays row-stochastic: only the advance fed to
the taught kernel changes (``BeliefModel(graph, params, advance_scale=r)``).

This module imports NumPy, SciPy and the belief model only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from server.belief.model import BeliefModel, TransitionOperator

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "FilterStep",
    "TransitionCounts",
    "TransitionLearnParams",
    "advance_scale",
    "expected_motion_counts",
    "forward_backward",
]


@dataclass(frozen=True)
class TransitionLearnParams:
    """How learned counts become a learned model.

    * ``prior_images`` (50.0, images): pseudo-count of the taught model, in images of taught
      advance at rate 1 (at one image per frame, 5 s of driving at 10 frames/s). Larger: learns
      slower, trusts the taught pace longer.
    * ``min_scale`` / ``max_scale`` (0.25 / 4.0): the learned advance scale is clipped to this
      range (a run that went wrong cannot make the model absurd).
    * ``min_mass`` (0.5): a step counts for an edge only when the smoothed belief holds at
      least this mass on it at both ends of the step. Without it the small mass the belief
      keeps on look-alike places (aliasing, kidnap mixing) counts steps there that go nowhere,
      and the learned pace came out 10-20 % slow on both real data sets (whose traversals have
      the same pace).
    """

    prior_images: float = 50.0
    min_scale: float = 0.25
    max_scale: float = 4.0
    min_mass: float = 0.5

    def __post_init__(self) -> None:
        if not (math.isfinite(self.prior_images) and self.prior_images > 0):
            raise ValueError("prior_images must be finite and > 0")
        if not 0 < self.min_scale <= 1 <= self.max_scale:
            raise ValueError("need 0 < min_scale <= 1 <= max_scale")


@dataclass(frozen=True)
class FilterStep:
    """One filter step as :class:`server.belief.tracker.Tracker` ran it.

    ``op`` is the transition that led into the step (``None`` for the start), ``eps`` its kidnap
    mixing, ``likelihood`` the ``(n_fine,)`` likelihood it used (``None`` at the start) and
    ``alpha`` the ``(n_fine,)`` filtered posterior after it (the start: the initial belief).
    """

    op: TransitionOperator | None
    eps: float
    likelihood: FloatArray | None
    alpha: FloatArray


@dataclass(frozen=True)
class TransitionCounts:
    """Expected counts of one or more runs, each ``(n_edges,) float64 >= 0`` (see the module
    doc): ``steps`` moving along each edge, images ``moved``, images the taught model expected
    (``taught``)."""

    steps: FloatArray
    moved: FloatArray
    taught: FloatArray

    @classmethod
    def zeros(cls, n_edges: int) -> TransitionCounts:
        z = np.zeros(n_edges)
        return cls(z, z.copy(), z.copy())

    def plus(self, other: TransitionCounts) -> TransitionCounts:
        """The counts of both (same tour)."""
        if other.steps.shape != self.steps.shape:
            raise ValueError("counts of different tours (edge counts differ) cannot be added")
        return TransitionCounts(
            self.steps + other.steps, self.moved + other.moved, self.taught + other.taught
        )

    def to_bytes(self) -> bytes:
        """``(3, n_edges)`` float64, C order."""
        return np.stack([self.steps, self.moved, self.taught]).astype("<f8").tobytes()

    @classmethod
    def from_bytes(cls, blob: bytes, n_edges: int) -> TransitionCounts:
        a = np.frombuffer(blob, dtype="<f8")
        if a.size != 3 * n_edges:
            raise ValueError(f"stored counts hold {a.size // 3} edges, the tour has {n_edges}")
        a = a.reshape(3, n_edges).astype(np.float64)
        return cls(a[0].copy(), a[1].copy(), a[2].copy())


def forward_backward(model: BeliefModel, run: Sequence[FilterStep]) -> list[FloatArray]:
    """Backward messages of a whole run: ``beta[t]`` ``(n_fine,)`` for every step, each scaled
    to max 1 (the smoothed marginal is ``alpha_t * beta_t`` normalised; :mod:`smoother`)."""
    n = len(run)
    beta = np.ones(model.n_fine)
    out = [beta]
    prior = model.prior
    for t in range(n - 1, 0, -1):
        step = run[t]
        if step.op is None or step.likelihood is None:
            raise ValueError(f"step {t} of the run has no transition or likelihood")
        msg = step.likelihood * beta
        beta = (1.0 - step.eps) * step.op.apply_transpose(msg) + step.eps * float(prior @ msg)
        beta = beta / beta.max()
        out.append(beta)
    out.reverse()
    return out


def smoothed_marginals(model: BeliefModel, run: Sequence[FilterStep]) -> list[FloatArray]:
    """``gamma_t`` ``(n_fine,)`` (each sums to 1) of every step of the run, start first."""
    out = []
    for step, beta in zip(run, forward_backward(model, run), strict=True):
        g = step.alpha * beta
        out.append(g / g.sum())
    return out


def expected_motion_counts(
    model: BeliefModel,
    run: Sequence[FilterStep],
    params: TransitionLearnParams | None = None,
) -> TransitionCounts:
    """Expected per-edge motion counts of one run (module doc), from its filter steps.

    ``run[0]`` is the start (its ``alpha`` the initial belief), ``run[1:]`` the steps. Only
    steps that drove forward (Navigate with an advance) count. Cost: one backward pass and a few
    segment sums per step; no per-state Python loop.
    """
    p = params if params is not None else TransitionLearnParams()
    E = model.n_edges
    counts = TransitionCounts.zeros(E)
    if len(run) < 2 or model.n_edge_images == 0:
        return counts
    gammas = smoothed_marginals(model, run)
    L = model.n_locations
    pos = model.row_pos.astype(np.float64)
    starts = model.offsets[:-1][model.valid_edge]
    valid = np.flatnonzero(model.valid_edge)

    seg = np.repeat(np.arange(len(valid)), model.edge_len[valid])

    def along(g: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Mass on every valid edge and its most likely position along it (images)."""
        ge = g[L:]
        mass = np.add.reduceat(ge, starts)
        top = np.maximum.reduceat(ge, starts)
        where = np.where(ge >= top[seg], pos, np.inf)
        return mass, np.minimum.reduceat(where, starts)

    prev = along(gammas[0])
    for t in range(1, len(run)):
        now = along(gammas[t])
        op = run[t].op
        if op is not None and op.motion is not None and op.structure.motion == "forward":
            w = np.minimum(prev[0], now[0])
            w = np.where(w >= p.min_mass, w, 0.0)
            w_ = op.motion.weights
            kernel = w_ @ (op.motion.lo + np.arange(w_.shape[1]))
            if model.advance_scale is not None:  # counts stay relative to the taught model
                kernel = kernel / model.advance_scale
            counts.steps[valid] += w
            counts.moved[valid] += w * (now[1] - prev[1])
            counts.taught[valid] += w * kernel[valid]
        prev = now
    return counts


def advance_scale(
    counts: TransitionCounts | None, params: TransitionLearnParams | None = None
) -> FloatArray:
    """``(n_edges,)`` multiplier of the taught advance per edge (module doc); all ones for
    ``None`` counts or zero evidence."""
    if counts is None:
        raise ValueError("give the counts (TransitionCounts.zeros(n_edges) for none)")
    p = params if params is not None else TransitionLearnParams()
    k = p.prior_images
    moved = np.maximum(counts.moved, 0.0)
    taught = np.maximum(counts.taught, 0.0)
    if not (moved.any() or taught.any()):
        return np.ones(len(counts.steps))
    tour = (float(moved.sum()) + k) / (float(taught.sum()) + k)
    scale: FloatArray = np.clip((moved + k * tour) / (taught + k), p.min_scale, p.max_scale)
    return scale
