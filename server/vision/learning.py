"""Signature weights learned per tour (001 section 5.2), robust to a change of light.

001 learns, per environment, how much each signature block counts: images of the same place
should be near, images of different places far. Learned on the taught traversal alone, that
rewards whatever separates places *in the light of the tour* - colour histograms above all -
which is exactly what differs in the evening, under another bulb or in another season. So the
learning here sees two kinds of triplets:

* **taught** (as in 001): anchor and positive are two tour images of the same state at most
  ``positive_window`` apart; negatives are tour images of other states;
* **changed** (beyond 001): the anchor is a tour image under a random photometric change
  (:func:`server.vision.augment.photometric_change`), the positive a tour image of the same
  state at most ``positive_window`` from it (itself included), the negatives tour images of
  other states, as a repeat run in other light is compared with the tour.

Minimised: ``(1 - changed_share) * L_taught + changed_share * L_changed + prior * ||w - w0||^2``
with ``L`` the mean soft triplet loss ``softplus((w.d_pos - w.d_neg + margin) / T)``, by
projected gradient descent on the simplex ``w >= 0, sum w = 1``. No labels from the user; the
changed views come from the tour's own images (:func:`learn_tour_weights`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from server.vision.augment import ChangeParams, photometric_change
from server.vision.features import extract, signature_length
from server.vision.index import (
    EngineParams,
    FloatArray,
    IntArray,
    TourIndex,
    _block_bounds,
    _normalise_weights,
    default_weights,
)

#: ``image_of(i)``: the ``(H, W, 3) uint8`` BGR image of the tour's image ``i`` (insertion order).
ImageSource = Callable[[int], npt.NDArray[np.uint8]]


@dataclass(frozen=True)
class LearnParams:
    """How the signature weights are learned.

    Attributes:
        min_images: fewer images than this -> :func:`default_weights`.
        min_states: fewer states with at least two images than this -> defaults.
        positive_window: a positive is an image of the same state at most this many places
            away in insertion order (images along an edge change as the robot moves).
        n_anchors: taught anchors sampled per run.
        n_negatives: images of other states compared with each anchor.
        iterations, learning_rate: projected gradient descent on the simplex.
        temperature: softness of the triplet loss (signature distance units).
        margin: required gap between negative and positive distance.
        prior: pull towards the default weights (L2), keeps small tours sane.
        changed_images: tour images (evenly spaced in insertion order) seen under a changed
            light by :func:`learn_tour_weights`; 0 learns from the taught triplets alone.
        changes_per_image: random photometric changes of each of those images.
        changed_share: weight of the changed triplets' loss, in [0, 1].
        change: ranges of the photometric changes.
        seed: random seed (learning is deterministic for a given tour).
    """

    min_images: int = 20
    min_states: int = 2
    positive_window: int = 3
    n_anchors: int = 2000
    n_negatives: int = 64
    iterations: int = 300
    learning_rate: float = 0.05
    temperature: float = 0.05
    margin: float = 0.05
    prior: float = 0.05
    changed_images: int = 256
    changes_per_image: int = 2
    changed_share: float = 0.5
    change: ChangeParams = field(default_factory=ChangeParams)
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 <= self.changed_share <= 1.0:
            raise ValueError("changed_share must lie in [0, 1]")
        if self.changed_images < 0 or self.changes_per_image < 1:
            raise ValueError("changed_images must be >= 0 and changes_per_image >= 1")


@dataclass(frozen=True)
class ChangedViews:
    """Tour images seen under changed light.

    Attributes:
        signatures: ``(m, S) float32`` signatures of the changed images.
        source: ``(m,) int64`` the tour image (insertion order) each one was made from.
    """

    signatures: npt.NDArray[np.float32]
    source: IntArray

    def __post_init__(self) -> None:
        if self.signatures.ndim != 2 or len(self.signatures) != len(self.source):
            raise ValueError("one signature row per source image")


def changed_views(
    n_images: int,
    image_of: ImageSource,
    params: EngineParams | None = None,
    learn: LearnParams = LearnParams(),
) -> ChangedViews:
    """``learn.changed_images`` tour images, evenly spaced, each under
    ``learn.changes_per_image`` random photometric changes, extracted as the engine would.

    Cost: one image decode and ``changes_per_image`` extractions per chosen image (about 3 ms
    each at 320x240), so about 1.5 s with the defaults, once per tour.
    """
    params = params or EngineParams()
    s = signature_length(params.features)
    if n_images == 0 or learn.changed_images == 0:
        return ChangedViews(np.zeros((0, s), np.float32), np.zeros(0, np.int64))
    chosen = np.unique(np.linspace(0, n_images - 1, min(learn.changed_images, n_images)).round())
    rng = np.random.default_rng(learn.seed)
    sigs: list[npt.NDArray[np.float32]] = []
    source: list[int] = []
    for i in chosen.astype(np.int64).tolist():
        image = image_of(i)
        for _ in range(learn.changes_per_image):
            changed = photometric_change(image, rng, learn.change)
            sigs.append(extract(changed, params.features).signature)
            source.append(i)
    return ChangedViews(np.stack(sigs).astype(np.float32), np.asarray(source, np.int64))


def learn_tour_weights(
    index: TourIndex,
    image_of: ImageSource | None,
    *,
    learn: LearnParams = LearnParams(),
) -> FloatArray:
    """The signature weights the engine uses for a tour: :func:`learn_weights` on the tour's
    images and on changed-light views of them (:func:`changed_views`).

    Args:
        index: the tour's index (signatures and states in insertion order).
        image_of: the tour's image ``i`` as ``(H, W, 3) uint8`` BGR; ``None`` learns from the
            taught triplets alone.
        learn: learning settings.

    Returns:
        ``(T,) float64`` weights summing to 1.
    """
    changed = None
    if image_of is not None and index.n_images >= learn.min_images:
        changed = changed_views(index.n_images, image_of, index.params, learn)
    return learn_weights(index, params=index.params, learn=learn, changed=changed)


def learn_weights(
    signatures_or_index: npt.ArrayLike | TourIndex,
    states: npt.ArrayLike | None = None,
    *,
    params: EngineParams | None = None,
    learn: LearnParams = LearnParams(),
    changed: ChangedViews | None = None,
) -> FloatArray:
    """Learn the signature block weights of one tour (the loss in the module docstring).

    Args:
        signatures_or_index: ``(n, S)`` signatures or a :class:`TourIndex` (then ``states``
            may be omitted).
        states: ``(n,)`` int upper state of each image.
        params: engine parameters (for the signature layout and the prior ``params.weights``;
            default ``EngineParams()``).
        learn: optimiser settings and the too-small thresholds.
        changed: tour images under changed light; ``None`` (or empty) learns from the taught
            triplets alone, as 001 does.

    Returns:
        ``(T,) float64`` weights summing to 1; :func:`default_weights` when the tour is too small
        (fewer than ``learn.min_images`` images or ``learn.min_states`` states with two images).
    """
    params = params or EngineParams()
    if isinstance(signatures_or_index, TourIndex):
        sig = np.asarray(signatures_or_index.signatures, np.float64)
        st = signatures_or_index.states if states is None else np.asarray(states, np.int64)
    else:
        sig = np.asarray(signatures_or_index, np.float64)
        if states is None:
            raise ValueError("give the state of every image")
        st = np.asarray(states, np.int64).ravel()
    w0 = default_weights(params.features)
    if params.weights is not None:
        w0 = _normalise_weights(params.weights, len(w0))
    n = len(sig)
    if sig.ndim != 2 or len(st) != n:
        raise ValueError(f"signatures {sig.shape} and states {st.shape} do not match")
    if n < learn.min_images:
        return w0
    bounds = _block_bounds(params.features)
    if sig.shape[1] != bounds[-1]:
        raise ValueError(f"signatures have {sig.shape[1]} values, expected {bounds[-1]}")

    pa, pb = _positive_pairs(st, learn.positive_window)
    multi = np.unique(st[pa]) if len(pa) else np.zeros(0, np.int64)
    if len(multi) < learn.min_states or len(np.unique(st)) < 2:
        return w0

    rng = np.random.default_rng(learn.seed)
    pick = rng.choice(len(pa), size=min(learn.n_anchors, len(pa)), replace=False)
    terms = [_triplets(sig[pa[pick]], st[pa[pick]], pb[pick], sig, st, bounds, learn, rng)]
    shares = [1.0]
    if changed is not None and len(changed.source):
        if changed.signatures.shape[1] != sig.shape[1] or changed.source.max() >= n:
            raise ValueError("changed views do not belong to these signatures")
        src = changed.source
        offset = rng.integers(-learn.positive_window, learn.positive_window + 1, size=len(src))
        pos = np.clip(src + offset, 0, n - 1)
        pos = np.where(st[pos] == st[src], pos, src)  # stay within the source's state
        anchors = changed.signatures.astype(np.float64)
        terms.append(_triplets(anchors, st[src], pos, sig, st, bounds, learn, rng))
        shares = [1.0 - learn.changed_share, learn.changed_share]

    w = w0.copy()
    for it in range(learn.iterations):
        step = learn.learning_rate / np.sqrt(1.0 + it)
        grad = 2.0 * learn.prior * (w - w0)
        for share, (delta, weight) in zip(shares, terms, strict=True):
            z = (delta @ w + learn.margin) / learn.temperature
            s = 1.0 / (1.0 + np.exp(-np.clip(z, -50, 50)))  # d softplus / dz
            grad += share * np.einsum("mn,mnt->t", s * weight, delta) / learn.temperature
        w = _project_simplex(w - step * grad / max(np.abs(grad).max(), 1e-12))
    return w


def _positive_pairs(st: IntArray, window: int) -> tuple[IntArray, IntArray]:
    """Pairs ``(a, b)`` of images of the same state at most ``window`` apart, ``a < b``."""
    idx = np.arange(len(st))
    pairs_a: list[IntArray] = [np.zeros(0, np.int64)]
    pairs_b: list[IntArray] = [np.zeros(0, np.int64)]
    for off in range(1, window + 1):
        same = st[off:] == st[:-off]
        pairs_a.append(idx[:-off][same])
        pairs_b.append(idx[off:][same])
    return np.concatenate(pairs_a), np.concatenate(pairs_b)


_ANCHOR_BLOCK = 16  # anchors per block of _triplets' differences (16 x 64 x 600 float64: 5 MB)


def _triplets(
    anchors: FloatArray,
    anchor_states: IntArray,
    positives: IntArray,
    sig: FloatArray,
    st: IntArray,
    bounds: IntArray,
    learn: LearnParams,
    rng: np.random.Generator,
) -> tuple[FloatArray, FloatArray]:
    """``delta (M, Nn, T)``: per block, positive minus negative squared distance of each
    anchor ``(M, S)`` to its positive (a tour image) and ``learn.n_negatives`` random tour
    images; ``weight (M, Nn)``: 1 / count for the negatives that are of another state, else 0."""
    neg = rng.integers(0, len(sig), size=(len(anchors), learn.n_negatives))
    ok = st[neg] != anchor_states[:, None]
    d_pos = _blocks(sig[positives] - anchors, bounds)  # (M, T)
    # (M, Nn, T), a few anchors at a time: the (M, Nn, S) differences at once were 600 MB and
    # took 11 s of a tour's 13 s runtime build; in blocks they stay in cache (same sums, 0.2 s)
    d_neg = np.empty((len(anchors), neg.shape[1], len(bounds) - 1))
    for i in range(0, len(anchors), _ANCHOR_BLOCK):
        part = slice(i, i + _ANCHOR_BLOCK)
        d_neg[part] = _blocks(sig[neg[part]] - anchors[part, None, :], bounds)
    weight = ok.astype(np.float64) / max(int(ok.sum()), 1)
    return d_pos[:, None, :] - d_neg, weight


def _blocks(diff: FloatArray, bounds: IntArray) -> FloatArray:
    """Squared norm per signature block along the last axis: ``(..., S) -> (..., T)``."""
    return np.add.reduceat(diff * diff, bounds[:-1], axis=-1)


def _project_simplex(v: FloatArray) -> FloatArray:
    """Euclidean projection onto ``{w >= 0, sum w = 1}``."""
    u = np.sort(v)[::-1]
    css = np.cumsum(u) - 1.0
    k = np.arange(1, len(v) + 1)
    rho = int(np.nonzero(u - css / k > 0)[0][-1])
    theta = css[rho] / (rho + 1.0)
    return np.maximum(v - theta, 0.0)
