"""Belief update (001 eq. 1), the observation likelihood (eq. 2) and the per-robot Tracker.

Pure functions over arrays, in the filterpy style:

* :func:`predict` ``(belief, transition) -> belief``  (sparse mat-vec, new array)
* :func:`update` ``(belief, likelihood) -> belief``   (elementwise product, normalised)
* :func:`fine_likelihood` ``(image_sim, graph) -> likelihood`` (max over a location's images)

:class:`Tracker` wires them for one robot: predict with the action just executed, mix in a little
"kidnap" mass, update with the engine's similarities, and summarise (``b(s)``, ``b(i | e)``, top
states, most likely image per edge, entropy, a conservative "localised" flag). It also feeds a
fixed-lag smoother (:mod:`server.belief.smoother`) whose estimate is available next to the filter.

This module imports NumPy, SciPy and :mod:`server.domain` only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp

from server.belief.appearance import (
    AppearanceParams,
    change_evidence,
    gated_mixture,
    gated_scores,
    model_scores,
    posterior,
    update_log_posterior,
)
from server.belief.model import (
    Action,
    BeliefModel,
    TransitionOperator,
    mix_prior,
)
from server.belief.smoother import FixedLagSmoother, SmoothedTrajectory
from server.domain import TourGraph

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

__all__ = [
    "BeliefError",
    "BeliefSummary",
    "InvalidLikelihoodError",
    "Tracker",
    "TrackerMemory",
    "TrackerParams",
    "ZeroLikelihoodError",
    "fine_likelihood",
    "predict",
    "summarise",
    "update",
]


class BeliefError(ValueError):
    """Base class of the belief tracker's errors."""


class InvalidLikelihoodError(BeliefError):
    """The likelihood has the wrong shape, a negative or a non-finite value."""


class ZeroLikelihoodError(BeliefError):
    """Every state with belief mass got likelihood 0: the update is undefined."""


def predict(belief: npt.ArrayLike, transition: sp.csr_array | TransitionOperator) -> FloatArray:
    """Prediction step: ``b'(s') = sum_s b(s) tr(s, a, s')``.

    ``belief`` is ``(n_fine,)``; ``transition`` is the row-stochastic ``(n_fine, n_fine)`` matrix
    from :meth:`BeliefModel.transition` or the factored :class:`TransitionOperator`. Returns a new
    ``(n_fine,) float64`` array (same total mass as ``belief``); the input is not modified.
    """
    b = np.asarray(belief, dtype=np.float64)
    if isinstance(transition, TransitionOperator):
        return transition.apply(b)
    if transition.shape != (b.shape[0], b.shape[0]):
        raise BeliefError(
            f"transition has shape {transition.shape} but the belief has {b.shape[0]} states"
        )
    return np.asarray(transition.T @ b, dtype=np.float64)


def update(belief: npt.ArrayLike, likelihood: npt.ArrayLike) -> FloatArray:
    """Correction step (001 eq. 1): ``b'(s) = O(s, o) b(s) / kappa``.

    ``belief`` and ``likelihood`` are ``(n_fine,)``; the likelihood must be finite and >= 0 (any
    scale: it is normalised away). Returns a new ``(n_fine,) float64`` array summing to 1.
    Raises :class:`InvalidLikelihoodError` on a wrong shape / negative / non-finite likelihood and
    :class:`ZeroLikelihoodError` when the product is all zero (give the engine's similarities a
    floor > 0, see :func:`fine_likelihood`).
    """
    b = np.asarray(belief, dtype=np.float64)
    lik = np.asarray(likelihood, dtype=np.float64)
    if lik.shape != b.shape:
        raise InvalidLikelihoodError(
            f"likelihood has shape {lik.shape}, expected {b.shape} (one value per fine state; "
            "build it with fine_likelihood(image_sim, graph))"
        )
    if not np.all(np.isfinite(lik)):
        raise InvalidLikelihoodError("likelihood has NaN or infinite values; check the engine")
    if np.any(lik < 0):
        raise InvalidLikelihoodError("likelihood has negative values; similarities must be >= 0")
    post = b * lik
    total = float(post.sum())
    if not (total > 0 and math.isfinite(total)):
        raise ZeroLikelihoodError(
            "the likelihood is zero wherever the belief has mass; give the similarities a floor "
            "> 0 (fine_likelihood(..., floor=...)) or reset the tracker"
        )
    out: FloatArray = post / total
    return out


def fine_likelihood(
    image_sim: npt.ArrayLike, graph: TourGraph, *, floor: float = 1e-3
) -> FloatArray:
    """Observation likelihood of every fine state from the engine's per-image similarities.

    ``image_sim`` is ``(n_images,)`` in canonical image order (``graph.image_ids``), values >= 0
    (the engine's eq. 4 similarities in [0, 1]). A location gets the max over its images
    (001 eq. 2); an edge image its own similarity; a location with no images gets ``floor``.
    Every value is raised to at least ``floor``. Returns ``(n_fine,) float64 > 0``.
    """
    sim = np.asarray(image_sim, dtype=np.float64)
    if sim.shape != (graph.n_images,):
        raise InvalidLikelihoodError(
            f"image_sim has shape {sim.shape}, expected ({graph.n_images},): one similarity per "
            "image of the tour in canonical order"
        )
    if not np.all(np.isfinite(sim)):
        raise InvalidLikelihoodError("image_sim has NaN or infinite values; check the engine")
    L = graph.n_locations
    out = np.full(graph.n_fine, float(floor))
    n_loc_images = graph.n_images - (graph.n_fine - L)
    counts = np.fromiter((len(loc.image_ids) for loc in graph.locations), np.int64, L)
    has = counts > 0
    if n_loc_images > 0:
        starts = (np.cumsum(counts) - counts)[has]
        out[:L][has] = np.maximum.reduceat(sim[:n_loc_images], starts)
    out[L:] = sim[n_loc_images:]
    np.maximum(out, floor, out=out)
    return out


@dataclass(frozen=True)
class TrackerParams:
    """Tracker settings (everything that is not a transition probability).

    * ``localised_mass`` (0.8): an upper state must hold at least this belief mass ...
    * ``localised_steps`` (2): ... on this many consecutive steps ...
    * ``localised_evidence`` (0.75): ... and the recent evidence must be at least this fraction of
      the usual evidence (below). This turns "localised" off within a few frames of a kidnapping,
      long before the mass has moved, and keeps it off while the belief is still catching up.
    * ``evidence_fast`` (0.5) / ``evidence_slow`` (0.05): EMA weights of the per-step evidence
      ratio ``sum(prediction * L) / max(L)`` (how well the predicted place explains the image,
      relative to the best-matching place anywhere; scale-free): the fast EMA is the recent
      evidence, the slow one the usual evidence (as w_fast / w_slow in the augmented particle
      filter of Thrun, Burgard & Fox's *Probabilistic Robotics*). The slow one rises at the
      fast rate and decays at the slow rate, so it remembers good tracking.
    * ``surprise_gain`` (0.15) / ``surprise_teleport`` (0.1): the kidnap mixing of a step is
      ``TransitionParams.teleport + surprise_gain * max(0, 1 - fast / slow)``, capped at
      ``surprise_teleport``: when the images stop matching where we think we are, mass is
      re-seeded everywhere and a kidnapped robot re-localises within a few frames.
    * ``likelihood_floor`` (1e-6): every likelihood is raised to at least this fraction of the
      frame's largest one (scale-free; one bad match can never zero out the true state). An
      all-zero frame is treated as no information (prediction only).
    * ``likelihood_power`` (1.0): ``L ** power`` sharpens (> 1) or tempers (< 1) the engine.
    * ``changed_likelihood_power`` (0.75): with more than one appearance model, the power once
      the change evidence is 1 (the light or the season changed: the models' likelihoods are
      less sure of themselves, and one look-alike frame must not take the belief from where
      the route has been); at change evidence ``g`` the power is ``likelihood_power + g *
      (changed_likelihood_power - likelihood_power)``, so at ``g`` = 0 (the tour's own light)
      it is ``likelihood_power`` exactly. ``None``: ``likelihood_power`` always. Chosen on the
      first halves of the shared data (docs/localize.md).
    * ``motion_quantum`` (0.02): the travelled distance ``|v| dt`` and ``dt`` are rounded on a
      logarithmic grid of this relative step before computing the advance, so that the cached
      motion matrices are reused from frame to frame (a 1% error in the expected advance).
    * ``top_k`` (5): how many upper states :attr:`BeliefSummary.top_states` lists.
    * ``smoother_lag`` (10): steps kept for the fixed-lag smoother (0 disables it).
    * ``appearance``: how the belief over appearance models follows the evidence when
      :meth:`Tracker.step` gets one likelihood per model (:mod:`server.belief.appearance`).
    """

    localised_mass: float = 0.8
    localised_steps: int = 2
    localised_evidence: float = 0.75
    evidence_fast: float = 0.5
    evidence_slow: float = 0.05
    surprise_gain: float = 0.15
    surprise_teleport: float = 0.1
    likelihood_floor: float = 1e-6
    likelihood_power: float = 1.0
    changed_likelihood_power: float | None = 0.75
    motion_quantum: float = 0.02
    top_k: int = 5
    smoother_lag: int = 10
    appearance: AppearanceParams = field(default_factory=AppearanceParams)

    def __post_init__(self) -> None:
        if not 0 < self.localised_mass <= 1:
            raise ValueError("localised_mass must be in (0, 1]")
        if self.localised_steps < 1:
            raise ValueError("localised_steps must be >= 1")
        if not (0 < self.evidence_fast <= 1 and 0 < self.evidence_slow <= 1):
            raise ValueError("evidence_fast and evidence_slow must be in (0, 1]")
        if not 0 <= self.surprise_teleport <= 1:
            raise ValueError("surprise_teleport must be in [0, 1]")
        if not self.likelihood_floor > 0:
            raise ValueError("likelihood_floor must be > 0")
        changed = self.changed_likelihood_power
        if not (self.likelihood_power > 0 and (changed is None or changed > 0)):
            raise ValueError("likelihood_power and changed_likelihood_power must be > 0")
        if self.top_k < 1 or self.smoother_lag < 0:
            raise ValueError("top_k must be >= 1 and smoother_lag >= 0")


@dataclass(frozen=True)
class BeliefSummary:
    """What the tracker exposes after a step. Probabilities are plain floats / float64 arrays.

    * ``belief``: ``(n_fine,)`` the full fine belief (sums to 1).
    * ``state``: ``(n_states,)`` ``b(s)`` over upper states (locations then edges), sums to 1.
    * ``along_edge_flat`` (computed on first use): ``(n_edge_images,)`` ``b(i | e)`` for every
      edge image, each edge's slice sums to 1 (0 for an edge with no mass); :attr:`along_edge`
      splits it per edge.
    * ``top_states``: ``((state, prob), ...)`` the ``top_k`` upper states, most likely first.
    * ``best_image``: ``(n_edges,) int`` most likely image index along each edge (-1: no images).
    * ``entropy``: nats, of ``state``.
    * ``localised`` / ``localised_state``: the conservative flag (see :class:`TrackerParams`).
    * ``evidence``: recent / usual evidence (see :class:`TrackerParams`; ~1 when the images
      match the belief, well below 1 after a kidnapping); ``teleport``: kidnap mixing used.
    * ``appearance``: ``(K,)`` belief over the appearance models whose likelihoods the step
      mixed (:mod:`server.belief.appearance`); ``(1.0,)`` with a single likelihood.
    * ``light_change``: the change evidence the step weighed the models with, in [0, 1] (0:
      the frame is seen in the tour's own light; 1 with a single likelihood).
    """

    belief: FloatArray
    state: FloatArray
    row_edge: IntArray
    edge_offsets: IntArray
    top_states: tuple[tuple[int, float], ...]
    best_image: IntArray
    entropy: float
    localised: bool
    localised_state: int | None
    evidence: float = 1.0
    teleport: float = 0.0
    step: int = 0
    appearance: tuple[float, ...] = (1.0,)
    light_change: float = 1.0

    @cached_property
    def along_edge_flat(self) -> FloatArray:
        """``(n_edge_images,)`` ``b(i | e)``; each edge's slice sums to 1 (0 if no mass)."""
        n_loc = len(self.state) - (len(self.edge_offsets) - 1)
        denom = self.state[n_loc:][self.row_edge]
        b_edge = self.belief[n_loc:]
        out: FloatArray = np.divide(b_edge, denom, out=np.zeros_like(b_edge), where=denom > 0)
        return out

    @cached_property
    def along_edge(self) -> tuple[FloatArray, ...]:
        """``b(i | e)`` per edge: tuple of ``(n_images_e,)`` arrays (views)."""
        if len(self.edge_offsets) < 2:
            return ()
        return tuple(np.split(self.along_edge_flat, self.edge_offsets[1:-1]))

    @property
    def map_state(self) -> int:
        """The most likely upper state."""
        return self.top_states[0][0]


@dataclass(frozen=True)
class TrackerMemory:
    """What a tracker remembers of the frames besides its belief, so a belief restored after
    a restart (:meth:`Tracker.set_belief`) goes on as the tracker would have: without it the
    appearance models would start level again and the change evidence from the next frame
    alone (a robot facing a wall as the server came back opened the gate at once and the
    change-robust model took half the likelihood, docs/localize.md).

    * ``appearance``: ``(K,)`` log posterior over the appearance models (empty: none yet).
    * ``familiar``: running mean of the frames' familiarity (NaN: none yet).
    * ``evidence_fast`` / ``evidence_slow``: the EMAs of the evidence ratio (< 0: no frame yet).

    :meth:`to_dict` / :meth:`from_dict` give it a JSON-safe form (NaN as ``None``).
    """

    appearance: tuple[float, ...] = ()
    familiar: float = math.nan
    evidence_fast: float = -1.0
    evidence_slow: float = -1.0

    def to_dict(self) -> dict[str, object]:
        """Plain floats and lists, NaN as ``None`` (strict JSON has no NaN)."""

        def num(x: float) -> float | None:
            return x if math.isfinite(x) else None

        return {
            "appearance": [num(float(x)) for x in self.appearance],
            "familiar": num(self.familiar),
            "evidence_fast": num(self.evidence_fast),
            "evidence_slow": num(self.evidence_slow),
        }

    @classmethod
    def from_dict(cls, data: dict[str, object]) -> TrackerMemory:
        """The inverse of :meth:`to_dict`. Raises :class:`BeliefError` on anything else."""

        def num(x: object, missing: float) -> float:
            if x is None:
                return missing
            if isinstance(x, bool) or not isinstance(x, int | float):
                raise BeliefError(f"tracker memory: {x!r} is not a number")
            return float(x)

        try:
            raw = data.get("appearance") or []
            if not isinstance(raw, list):
                raise BeliefError("tracker memory: appearance must be a list")
            appearance = tuple(num(x, math.nan) for x in raw)
            if not all(math.isfinite(x) for x in appearance):
                raise BeliefError("tracker memory: appearance must be finite")
            return cls(
                appearance=appearance,
                familiar=num(data.get("familiar"), math.nan),
                evidence_fast=num(data.get("evidence_fast"), -1.0),
                evidence_slow=num(data.get("evidence_slow"), -1.0),
            )
        except AttributeError:
            raise BeliefError("tracker memory must be a mapping") from None


def summarise(
    belief: FloatArray,
    model: BeliefModel,
    *,
    top_k: int = 5,
    localised: bool = False,
    localised_state: int | None = None,
    evidence: float = 1.0,
    teleport: float = 0.0,
    step: int = 0,
    state: FloatArray | None = None,
    appearance: tuple[float, ...] = (1.0,),
    light_change: float = 1.0,
) -> BeliefSummary:
    """Build a :class:`BeliefSummary` of a ``(n_fine,)`` belief (vectorised, no state loops).

    ``state`` may pass ``model.upper_mass(belief)`` when already computed.
    """
    L = model.n_locations
    if state is None:
        state = model.upper_mass(belief)
    b_edge = belief[L:]
    best = np.full(model.n_edges, -1, dtype=np.int64)
    if model.n_edge_images:
        valid = np.flatnonzero(model.valid_edge)
        starts = model.offsets[valid]
        seg_max = np.maximum.reduceat(b_edge, starts)
        full_max = np.zeros(model.n_edges)
        full_max[valid] = seg_max
        cand = np.where(b_edge >= full_max[model.row_edge], model.row_pos, np.iinfo(np.int64).max)
        best[valid] = np.minimum.reduceat(cand, starts)
    k = min(top_k, model.n_states)
    top = np.argpartition(-state, k - 1)[:k] if k < model.n_states else np.arange(k)
    top = top[np.argsort(-state[top], kind="stable")]
    nz = state[state > 0]
    entropy = float(-(nz * np.log(nz)).sum())
    return BeliefSummary(
        belief=belief,
        state=state,
        row_edge=model.row_edge,
        edge_offsets=model.offsets,
        top_states=tuple((int(s), float(state[s])) for s in top),
        best_image=best,
        entropy=entropy,
        localised=localised,
        localised_state=localised_state,
        evidence=evidence,
        teleport=teleport,
        step=step,
        appearance=appearance,
        light_change=light_change,
    )


class Tracker:
    """The belief of one robot on one tour.

    ``Tracker(model, params)``; :meth:`step` once per frame with the action that was executed
    since the previous frame, the ``(n_fine,)`` likelihood (:func:`fine_likelihood`; or
    ``(K, n_fine)``, one per appearance model, mixed as :mod:`server.belief.appearance` says),
    the current forward speed ``v`` (m/s) and the time since the previous frame ``dt`` (s).
    ``belief`` is ``(n_fine,) float64`` summing to 1 (a copy; the tracker never hands out its
    own array).
    """

    def __init__(self, model: BeliefModel, params: TrackerParams | None = None) -> None:
        self.model = model
        self.params = params if params is not None else TrackerParams()
        self._smoother = (
            FixedLagSmoother(model, self.params.smoother_lag) if self.params.smoother_lag else None
        )
        self.reset()

    @property
    def belief(self) -> FloatArray:
        """``(n_fine,) float64``, sums to 1 (a copy)."""
        return self._belief.copy()

    @property
    def last_summary(self) -> BeliefSummary:
        return self._summary

    def reset(self) -> None:
        """Back to the prior: uniform over upper states, uniform inside each edge (001 Sec. 6)."""
        self._belief = self.model.prior.copy()
        self._fast = -1.0  # EMAs of the evidence ratio; < 0 = no observation yet
        self._slow = -1.0
        self._streak_state = -1
        self._streak = 0
        self._steps = 0
        self._appearance = np.zeros(0)  # log posterior over appearance models; empty = none yet
        self._familiar = math.nan  # running mean of the frames' familiarity; NaN = none yet
        if self._smoother is not None:
            self._smoother.reset(self._belief)
        self._summary = summarise(self._belief, self.model, top_k=self.params.top_k)

    def memory(self) -> TrackerMemory:
        """What the tracker remembers besides its belief (:class:`TrackerMemory`), to restore
        with :meth:`set_belief` after a restart."""
        return TrackerMemory(
            appearance=tuple(float(x) for x in self._appearance),
            familiar=self._familiar,
            evidence_fast=self._fast,
            evidence_slow=self._slow,
        )

    def set_belief(self, belief: npt.ArrayLike, memory: TrackerMemory | None = None) -> None:
        """Replace the belief (e.g. "the robot is in the kitchen"); it is normalised.
        ``memory`` (from :meth:`memory`, e.g. persisted with the belief): go on with what the
        tracker remembered of the frames too; ``None``: as after :meth:`reset`."""
        b = np.asarray(belief, dtype=np.float64)
        if b.shape != (self.model.n_fine,) or not np.all(np.isfinite(b)) or np.any(b < 0):
            raise BeliefError(f"belief must be ({self.model.n_fine},), finite and >= 0")
        total = float(b.sum())
        if total <= 0:
            raise BeliefError("belief must have positive mass")
        self.reset()
        self._belief = b / total
        if memory is not None:
            self._appearance = np.asarray(memory.appearance, np.float64)
            self._familiar = float(memory.familiar)
            self._fast, self._slow = float(memory.evidence_fast), float(memory.evidence_slow)
        if self._smoother is not None:
            self._smoother.reset(self._belief)
        self._summary = summarise(self._belief, self.model, top_k=self.params.top_k)

    def step(
        self,
        action: Action,
        likelihood: npt.ArrayLike,
        *,
        v: float,
        dt: float,
        w: float = 0.0,
        familiarity: float = math.nan,
    ) -> BeliefSummary:
        """Predict with ``action`` (advance from ``v`` m/s, ``w`` rad/s and ``dt`` s), update,
        summarise. ``familiarity``: with one likelihood per appearance model, the frame's
        familiarity in [0, 1] (:func:`~server.belief.appearance.familiarity`), smoothed over
        the frames into the change evidence that weighs the models; NaN (the default): no
        information, the models compete freely."""
        p = self.params
        m = self.model
        lik = np.asarray(likelihood, dtype=np.float64)
        stacked = lik.ndim == 2 and len(lik) > 1  # one model: nothing to weigh
        if lik.shape[-1:] != (m.n_fine,) or lik.ndim not in (1, 2) or len(lik) == 0:
            raise InvalidLikelihoodError(
                f"likelihood has shape {lik.shape}, expected ({m.n_fine},) or (K, {m.n_fine}); "
                "build it with fine_likelihood(image_sim, graph)"
            )
        if not math.isfinite(float(lik.sum())) or float(lik.min()) < 0:
            raise InvalidLikelihoodError("likelihood must be finite and >= 0")
        lik = lik.reshape(-1, m.n_fine)
        change = 1.0  # with one model there is nothing to weigh
        if stacked:
            if math.isfinite(familiarity):
                rate = p.appearance.change_rate
                known = math.isfinite(self._familiar)
                start = self._familiar if known else p.appearance.change_prior
                self._familiar = start + rate * (familiarity - start)
            change = change_evidence(self._familiar, p.appearance)
        power = p.likelihood_power
        if stacked and p.changed_likelihood_power is not None and change > 0:
            power += change * (p.changed_likelihood_power - p.likelihood_power)
        if power != 1.0:
            lik = lik**power
        top = lik.max(axis=1, keepdims=True)
        # an all-zero frame carries no information: predict only
        lik = np.where(top > 0, np.maximum(lik, p.likelihood_floor * top), 1.0)
        op = m.operator(action, advance=self._advance(m.progress_speed(v, w), dt))
        moved = op.apply(self._belief)
        if stacked:
            if len(self._appearance) != len(lik):
                self._appearance = np.zeros(len(lik))
            # while the images stop matching the belief (a kidnapping), a model cannot earn
            # trust by agreeing with the stale belief: only forget
            usual = self._fast < 0 or self._fast >= p.localised_evidence * self._slow
            scores = model_scores(moved, lik) if usual else np.ones(len(lik))
            scores = gated_scores(scores, change)
            self._appearance = update_log_posterior(self._appearance, scores, p.appearance)
            mix = gated_mixture(posterior(self._appearance), change)
            lik = mix @ lik
        else:
            mix = np.ones(1)
            lik = lik[0]
        ratio = float(moved @ lik) / (float(moved.sum()) * float(lik.max()))  # scale-free
        if self._fast < 0:
            self._fast = self._slow = ratio
        else:
            self._fast += p.evidence_fast * (ratio - self._fast)
            rate = p.evidence_fast if ratio > self._slow else p.evidence_slow
            self._slow += rate * (ratio - self._slow)
        evidence = min(1.0, self._fast / self._slow) if self._slow > 0 else 1.0
        eps = min(
            max(m.params.teleport, p.surprise_teleport),
            m.params.teleport + p.surprise_gain * (1.0 - evidence),
        )
        post = mix_prior(moved, m.prior, eps)
        post *= lik  # eq. 1; lik >= floor > 0, so the sum is > 0
        post /= post.sum()
        self._belief = post
        self._steps += 1
        if self._smoother is not None:
            self._smoother.push(op, eps, lik, post)
        # conservative "localised"
        state = m.upper_mass(post)
        top = int(np.argmax(state))
        if state[top] >= p.localised_mass:
            if top == self._streak_state:
                self._streak += 1
            else:
                self._streak_state, self._streak = top, 1
        else:
            self._streak_state, self._streak = -1, 0
        localised = self._streak >= p.localised_steps and evidence >= p.localised_evidence
        self._summary = summarise(
            post,
            m,
            top_k=p.top_k,
            localised=localised,
            localised_state=top if localised else None,
            evidence=evidence,
            teleport=eps,
            step=self._steps,
            state=state,
            appearance=tuple(float(x) for x in mix),
            light_change=float(change),
        )
        return self._summary

    def _advance(self, v: float, dt: float) -> FloatArray:
        """Per-edge advance (images) from ``v`` (m/s) and ``dt`` (s), on a log grid."""
        q = self.params.motion_quantum
        v, dt = float(v), float(dt)
        if q > 0 and math.isfinite(dt) and dt > 0:
            step = math.log1p(q)
            dt_q = math.exp(round(math.log(dt) / step) * step)
            dist = abs(v) * dt if math.isfinite(v) else 0.0
            if dist > 0:  # (a tiny v * dt can underflow to 0)
                v = math.exp(round(math.log(dist) / step) * step) / dt_q
            dt = dt_q
        return self.model.expected_advance(v=v, dt=dt)

    def smoothed(self) -> SmoothedTrajectory | None:
        """Fixed-lag smoothed estimate of the last ``smoother_lag`` steps (None if disabled)."""
        if self._smoother is None:
            return None
        return self._smoother.smooth()
