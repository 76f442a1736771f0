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
says whether the light changed at all: the frame's best error under the tour's model
(:attr:`server.vision.index.Similarity.best_error`, before normalisation) against the tour's
own scale for it, the best errors of taught images against the *other* places of the tour
(:meth:`server.vision.index.TourIndex.error_levels`). A frame that matches the tour better than
a taught image matches a wrong place is seen in the tour's light: the **change evidence**
``g`` (:func:`change_evidence`) is 0 and no other model may score above the tour's on it
(:func:`gated_scores`); from the ``familiar_high`` quantile of the levels up, ``g`` = 1 and the
models compete as above. Nothing here is tuned to a data set: the scale comes from each tour.

Pure: NumPy only.
"""

from __future__ import annotations

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
        familiar_low, familiar_high: quantiles of the tour's error levels
            (:meth:`~server.vision.index.TourIndex.error_levels`) between which the change
            evidence rises from 0 (the frame matches the tour at least as well as the best
            ``familiar_low`` of its taught images match a wrong place) to 1 (no better than
            the median one does).
        change_gate: apply the change evidence (``False``: the models compete on every
            frame, as before 2026-11-26's gate).
    """

    memory: float = 0.9
    min_score: float = 1e-3
    familiar_low: float = 0.1
    familiar_high: float = 0.5
    change_gate: bool = True

    def __post_init__(self) -> None:
        if not 0.0 <= self.memory < 1.0:
            raise ValueError("memory must lie in [0, 1)")
        if not 0.0 < self.min_score <= 1.0:
            raise ValueError("min_score must lie in (0, 1]")
        if not 0.0 <= self.familiar_low < self.familiar_high <= 1.0:
            raise ValueError("familiar_low < familiar_high must both lie in [0, 1]")


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


def change_evidence(best_error: float, levels: npt.ArrayLike, params: AppearanceParams) -> float:
    """``g`` in [0, 1]: how little the frame looks like the tour in the tour's own light.

    Args:
        best_error: the frame's best error under the tour's model
            (:attr:`~server.vision.index.Similarity.best_error`; NaN: no information).
        levels: ``(P,)`` the tour's error levels
            (:meth:`~server.vision.index.TourIndex.error_levels`); empty: no information.

    Returns:
        0 when ``best_error`` is at or below the ``familiar_low`` quantile of ``levels``, 1 at
        or above the ``familiar_high`` quantile (and without information), linear between.
    """
    lv = np.asarray(levels, np.float64)
    if not params.change_gate or len(lv) == 0 or not np.isfinite(best_error):
        return 1.0
    lo, hi = np.quantile(lv, [params.familiar_low, params.familiar_high])
    if hi <= lo:
        return 0.0 if best_error <= lo else 1.0
    return float(np.clip((best_error - lo) / (hi - lo), 0.0, 1.0))


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
