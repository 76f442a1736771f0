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
    """

    memory: float = 0.9
    min_score: float = 1e-3

    def __post_init__(self) -> None:
        if not 0.0 <= self.memory < 1.0:
            raise ValueError("memory must lie in [0, 1)")
        if not 0.0 < self.min_score <= 1.0:
            raise ValueError("min_score must lie in (0, 1]")


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
