"""Which appearance model explains the camera now: the tour's light, or a changed one.

The engine can score a frame against the tour with more than one set of signature weights
(:class:`server.vision.index.EngineParams`): the weights learned for the tour, which separate
places best in the light the tour was taught in, and change-robust weights (the
patch-normalised thumbnail), which hold when the light, the season or the furniture's colours
changed. Which one to trust is a hidden variable of the robot's situation, like its place, so
the tracker keeps a belief over it too:

* the **score** of model k is how much better than chance its likelihood ``L_k`` explains the
  frame where the predicted belief ``b`` says the robot is:
  ``s_k = (b . L_k) / (sum(b) * mean(L_k))`` (scale free: 1 = no better than a uniform
  belief);
* its **log posterior** accumulates the scores with a forgetting factor ``memory`` in [0, 1)
  (the light can change again): ``l_k <- memory * l_k + log s_k``;
* the **likelihood** the belief update uses is the mixture ``sum_k pi_k L_k`` with
  ``pi = softmax(l)``.

A model that keeps placing its peaks where the belief (predicted from motion and the earlier
frames) expects the robot gains weight; one whose peaks wander is discounted.

That relative test alone lets the change-robust model win in the tour's own light whenever its
flatter peaks happen to sit where the belief is (a robot turning between the taught headings of
one place; docs/localize.md), and it cannot tell two rooms apart. So a second, absolute test
says whether the light changed at all, on a slower time scale than one frame:

* each frame's **familiarity** ``q`` (:func:`familiarity`) is the quantile of its best error
  under the tour's model (:attr:`server.vision.index.Similarity.best_error`, before
  normalisation) among the tour's own **error levels**, the best errors of taught images
  against the places they are not at (:meth:`server.vision.index.TourIndex.error_levels`):
  low when the frame matches the tour better than the tour matches itself at wrong places;
* the tracker smooths ``q`` over the last frames (``change_rate``), starting from
  ``change_prior`` (0: the tour's light until shown otherwise): one view off the taught path,
  or one look-alike, says little; a whole stretch that matches nothing as the tour was taught
  says the light (the season, the lamps) changed;
* the **change evidence** ``g`` (:func:`change_evidence`) rises from 0 at ``change_low`` to 1
  at ``change_high`` of the smoothed ``q``. At ``g`` = 0 the other models neither gain trust
  (:func:`gated_scores`) nor enter the mixture (:func:`gated_mixture`): the belief update is the
  tour's model alone, bit for bit; at ``g`` = 1 the models compete as above.

Nothing here is tuned to a data set: the scale comes from each tour's own images.

Pure: NumPy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class AppearanceParams:
    """How fast the belief over appearance models follows the evidence.

    Attributes:
        memory: forgetting factor of the accumulated log scores, in [0, 1) (per frame; 0.9
            forgets half of the evidence in about 7 frames, 0.7 s at 10 Hz).
        min_score: scores are clipped below at this, so one blank frame cannot veto a model.
        change_rate: weight of each frame's familiarity in its running mean (per frame;
            0.05: a time constant of 20 frames, 2 s at 10 Hz).
        change_low, change_high: the running mean of the familiarity at which the change
            evidence starts to rise from 0 and reaches 1 (quantiles of the tour's error
            levels; chosen on the simulated apartment and the first halves of the shared data
            sets, docs/localize.md: views near a home's taught images have a median of
            0.41-0.45, views off its paths 0.56-0.58, the corridor's second traversal 0.67,
            Nordland across seasons 0.87-0.92).
        change_gate: apply the change evidence (``False``: the models compete on every
            frame, as before 2026-11-26).
        change_prior: the running mean's value before the first frame (a fresh task, or a
            belief restored without the tracker's memory). 0: the light is the tour's until a
            stretch of frames says otherwise (frames that all match nothing, familiarity ~0.9,
            raise it to ``change_low`` in 16 frames and to ``change_high`` in 21 at a
            ``change_rate`` of 0.05). Starting from the first frame's own familiarity
            instead opened the gate at once for a robot that started facing a bare wall, and
            the change-robust model, which cannot tell the hall from the office, took half
            the likelihood (docs/localize.md).
    """

    memory: float = 0.9
    min_score: float = 1e-3
    change_rate: float = 0.05
    change_low: float = 0.5
    change_high: float = 0.6
    change_gate: bool = True
    change_prior: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.memory < 1.0:
            raise ValueError("memory must lie in [0, 1)")
        if not 0.0 < self.min_score <= 1.0:
            raise ValueError("min_score must lie in (0, 1]")
        if not 0.0 < self.change_rate <= 1.0:
            raise ValueError("change_rate must lie in (0, 1]")
        if not 0.0 <= self.change_low < self.change_high <= 1.0:
            raise ValueError("change_low < change_high must both lie in [0, 1]")
        if not 0.0 <= self.change_prior <= 1.0:
            raise ValueError("change_prior must lie in [0, 1]")


def model_scores(predicted: npt.ArrayLike, likelihoods: npt.ArrayLike) -> FloatArray:
    """``(K,)`` score of each model: ``(b . L_k) / (sum(b) * mean(L_k))``.

    Args:
        predicted: ``(n,)`` predicted belief (non-negative, need not sum to 1).
        likelihoods: ``(K, n)`` non-negative likelihood of each model.
    """
    b = np.asarray(predicted, np.float64)
    lik = np.asarray(likelihoods, np.float64)
    mean = lik.mean(axis=1)
    total = float(b.sum())
    if total <= 0:
        return np.ones(len(lik))
    return np.where(mean > 0, (lik @ b) / (total * np.maximum(mean, 1e-300)), 1.0)


def update_log_posterior(
    log_posterior: npt.ArrayLike, scores: npt.ArrayLike, params: AppearanceParams
) -> FloatArray:
    """``memory * l + log(max(scores, min_score))``, shifted so that its maximum is 0."""
    out = params.memory * np.asarray(log_posterior, np.float64) + np.log(
        np.maximum(np.asarray(scores, np.float64), params.min_score)
    )
    return out - out.max()


def posterior(log_posterior: npt.ArrayLike) -> FloatArray:
    """``softmax(l)``: ``(K,)`` probabilities summing to 1."""
    lp = np.asarray(log_posterior, np.float64)
    p = np.exp(lp - lp.max())
    return p / p.sum()


def familiarity(best_error: float, levels: npt.ArrayLike) -> float:
    """``q`` in [0, 1]: the fraction of the tour's error levels below the frame's best error
    (0: it matches the tour better than any taught image matches a wrong place). NaN without
    information (no levels, or no best error).

    Args:
        best_error: the frame's best error under the tour's model
            (:attr:`~server.vision.index.Similarity.best_error`).
        levels: ``(P,)`` ascending (:meth:`~server.vision.index.TourIndex.error_levels`).
    """
    lv = np.asarray(levels, np.float64)
    if len(lv) == 0 or not np.isfinite(best_error):
        return math.nan
    return float(np.searchsorted(lv, best_error, side="left")) / len(lv)


def change_evidence(smoothed: float, params: AppearanceParams) -> float:
    """``g`` in [0, 1] from the running mean of the familiarity: 0 up to ``change_low``, 1
    from ``change_high`` on, linear between; 1 without information (NaN) or with the gate
    off, so the models compete as without it."""
    if not params.change_gate or not math.isfinite(smoothed):
        return 1.0
    span = params.change_high - params.change_low
    return float(np.clip((smoothed - params.change_low) / span, 0.0, 1.0))


def gated_scores(scores: npt.ArrayLike, change: float) -> FloatArray:
    """``(K,)`` scores with the change evidence ``change`` (``g`` in [0, 1]) applied: a model
    other than the first (the tour's) keeps a score at or below the first's; above it, it
    gets ``s_0 ** (1 - g) * s_k ** g`` (at ``g`` = 0 the first's score, at 1 its own)."""
    s = np.asarray(scores, np.float64).copy()
    if len(s) < 2:
        return s
    g = float(np.clip(change, 0.0, 1.0))
    first = s[0]
    above = s[1:] > first
    s[1:][above] = first ** (1.0 - g) * s[1:][above] ** g
    return s


def gated_mixture(weights: npt.ArrayLike, change: float) -> FloatArray:
    """``(K,)`` mixture weights with every model but the first scaled by ``change`` and
    renormalised: at ``g`` = 0 ``(1, 0, ...)``, the tour's model alone; at 1 unchanged."""
    w = np.asarray(weights, np.float64).copy()
    w[1:] *= float(np.clip(change, 0.0, 1.0))
    total = float(w.sum())
    return w / total if total > 0 else np.eye(len(w))[0]
