"""Fixed-lag forward-backward smoother over the last M steps (beyond 001; seeds 000 and 003).

The filter answers "where am I now, given everything so far". The smoother re-estimates the
recent trajectory with the frames that came *after* each step: seed 003 re-runs an HMM over a
sliding window of M observations to correct past mis-localisations, seed 000 uses Bayesian
smoothing to decide the start hypothesis after a few motion steps. Here the window holds, for
each of the last M steps, the filtered belief ``alpha_t``, the transition used to reach it and its
likelihood ``L_t``. A backward pass

    beta_T = 1,   beta_t = T_{t+1} (L_{t+1} * beta_{t+1})      (kidnap mixing included)

gives the smoothed marginals ``gamma_t ~ alpha_t * beta_t`` (each beta is rescaled, which does not
change gamma). Cost: M - 1 transposed sparse operator applications, done on demand.

This module imports NumPy and the belief model only.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from server.belief.model import BeliefModel, TransitionOperator

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

__all__ = ["FixedLagSmoother", "SmoothedTrajectory"]


@dataclass(frozen=True)
class SmoothedTrajectory:
    """Smoothed estimate of the last ``n`` steps, oldest first (the last one equals the filter).

    * ``state``: ``(n,) int`` most likely upper state at each step (argmax of smoothed ``b(s)``).
    * ``state_prob``: ``(n,) float`` its smoothed probability.
    * ``fine``: ``(n,) int`` most likely fine state inside that upper state.
    * ``image``: ``(n,) int`` index along the edge of ``fine`` (-1 when ``state`` is a location).
    * ``oldest``: ``(n_fine,)`` smoothed belief of the oldest step of the window (sums to 1).
    """

    state: IntArray
    state_prob: FloatArray
    fine: IntArray
    image: IntArray
    oldest: FloatArray


@dataclass
class _Entry:
    op: TransitionOperator | None  # transition that led INTO this step (None for the start)
    eps: float
    likelihood: FloatArray | None
    alpha: FloatArray


class FixedLagSmoother:
    """Keeps the last ``lag`` filter steps and smooths them on demand (:meth:`smooth`)."""

    def __init__(self, model: BeliefModel, lag: int) -> None:
        if lag < 1:
            raise ValueError("lag must be >= 1")
        self.model = model
        self.lag = lag
        self._window: deque[_Entry] = deque(maxlen=lag)

    def reset(self, belief: FloatArray) -> None:
        """Start a new window from ``belief`` (``(n_fine,)``)."""
        self._window.clear()
        self._window.append(_Entry(None, 0.0, None, np.array(belief, dtype=np.float64)))

    def push(
        self, op: TransitionOperator, eps: float, likelihood: FloatArray, alpha: FloatArray
    ) -> None:
        """Record one filter step: operator, kidnap mixing, likelihood, filtered posterior."""
        self._window.append(_Entry(op, float(eps), likelihood, alpha))

    def __len__(self) -> int:
        return len(self._window)

    def marginals(self) -> list[FloatArray]:
        """Smoothed ``(n_fine,)`` beliefs of every step in the window, oldest first."""
        entries = list(self._window)
        if not entries:
            return []
        prior = self.model.prior
        n = len(entries)
        out: list[FloatArray] = [entries[-1].alpha]
        beta = np.ones(self.model.n_fine)
        for t in range(n - 2, -1, -1):
            nxt = entries[t + 1]
            assert nxt.op is not None and nxt.likelihood is not None
            msg = nxt.likelihood * beta
            moved = nxt.op.apply_transpose(msg)
            beta = (1.0 - nxt.eps) * moved + nxt.eps * float(prior @ msg)
            beta = beta / beta.max()
            g = entries[t].alpha * beta
            out.append(g / g.sum())
        out.reverse()
        return out

    def smooth(self) -> SmoothedTrajectory:
        """The smoothed trajectory of the window (see :class:`SmoothedTrajectory`)."""
        m = self.model
        gammas = self.marginals()
        n = len(gammas)
        state = np.zeros(n, dtype=np.int64)
        prob = np.zeros(n)
        fine = np.zeros(n, dtype=np.int64)
        image = np.full(n, -1, dtype=np.int64)
        L = m.n_locations
        for t, g in enumerate(gammas):
            upper = m.upper_mass(g)
            s = int(np.argmax(upper))
            state[t], prob[t] = s, upper[s]
            if s < L:
                fine[t] = s
            else:
                j = s - L
                lo = L + int(m.offsets[j])
                k = int(np.argmax(g[lo : L + int(m.offsets[j + 1])]))
                fine[t], image[t] = lo + k, k
        return SmoothedTrajectory(
            state=state, state_prob=prob, fine=fine, image=image, oldest=gammas[0]
        )
