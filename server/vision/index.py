"""The per-tour index and the two-pass similarity query (001 section 5.2-5.3, DESIGN section 3).

A :class:`TourIndex` holds every stored image of one tour in contiguous arrays that grow by
doubling (``add`` is amortised O(new images)). :meth:`TourIndex.query` turns the features of a
camera frame into a :class:`Similarity`: one value per stored image and per upper state, the
observation model of the belief tracker.

Query, step by step:

1. **First pass** - weighted signature distance to every stored image in one matrix-vector
   product: ``d(q, i) = sum_t w_t ||q_t - x_{i,t}||^2`` over the signature blocks t (each block
   has unit norm, so ``d_t`` lies in [0, 4]; the weights sum to 1).
2. **Candidates** - the ``n_candidates`` images with the smallest ``d`` plus the best image of
   every state (001: "we add the best match from every state").
3. **Second pass** - for each query corner, its nearest corner in each candidate (one batched
   matrix product for all candidates); the mean nearest distance is ``e_features`` (descriptor
   units normalised to about [0, 1]). ``e = feature_weight * e_features + signature_weight * d``.
4. **Geometric check** (beyond 001, seeds 003/004, optional) - RANSAC homography between the
   frame and the ``geometric_top`` best candidates on mutual nearest-neighbour matches;
   ``e += geometric_weight * (1 - inlier fraction)``; candidates not verified count as 0 inliers.
5. **Normalisation** - eq. (4) over the candidates: ``sim = 1 - (e - e_min) / (e_max - e_min)``;
   an image outside the candidates gets half the smallest candidate similarity of its state; a
   floor keeps every similarity > 0. Per state: the max over its images (eq. 2).

The weights are learned per tour (:func:`server.vision.learning.learn_weights`); with
``EngineParams.changed_weights`` set, :meth:`TourIndex.query_models` answers under a second,
change-robust set of weights too.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
import numpy.typing as npt

from server.vision.features import (
    FeatureParams,
    ImageFeatures,
    signature_blocks,
    signature_length,
)
from server.vision.inverted import (
    InvertedFile,
    VocabularyTree,
    WordFile,
    kmeans,
    nearest_centroid,
)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

#: Default signature weights (hist, thumb, desc_mean, desc_var, patch), sum 1; used when a
#: tour is too small to learn from. Chosen on the benchmark (docs/retrieval.md).
DEFAULT_WEIGHTS: tuple[float, ...] = (0.7, 0.0, 0.05, 0.05, 0.2)

#: Weights of the change-robust appearance model: the patch-normalised thumbnail alone (each
#: pixel against its neighbourhood, as in SeqSLAM), which a change of light or season moves
#: least (docs/localize.md).
CHANGED_WEIGHTS: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 1.0)


@dataclass(frozen=True)
class IndexParams:
    """How a large tour's inverted files (:mod:`server.vision.inverted`) are built and probed;
    used from ``EngineParams.index_min_images`` images on (docs/retrieval.md, "Large tours").

    Attributes:
        lists: the signature file has ``round(lists * sqrt(n_images))`` lists.
        probe: signature lists a query probes: the nearest centroids under each of its weights.
        sample_per_list: signatures sampled per list to train the centroids.
        iterations: Lloyd iterations of every k-means (signature lists, vocabulary nodes).
        branching, depth: the vocabulary tree, ``branching ** depth`` visual words.
        word_sample: corner descriptors sampled to train the vocabulary.
        stop: the stop-list: words held by more than this fraction of the images are not
            scored (seed 000).
        word_candidates: the images with the best visual-word scores (tf-idf cosine > 0) that
            join the second pass.
        seed: seed of the samples and of k-means (the same images give the same index).
    """

    lists: float = 4.0
    probe: int = 16
    sample_per_list: int = 16
    iterations: int = 10
    branching: int = 64
    depth: int = 2
    word_sample: int = 200_000
    stop: float = 0.05
    word_candidates: int = 30
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.lists > 0:
            raise ValueError("IndexParams.lists must be > 0")
        for name in ("probe", "sample_per_list", "word_sample", "word_candidates"):
            if getattr(self, name) < 1:
                raise ValueError(f"IndexParams.{name} must be at least 1")
        if self.branching < 2 or self.depth < 1:
            raise ValueError("IndexParams needs branching >= 2 and depth >= 1")
        if not 0.0 < self.stop <= 1.0:
            raise ValueError("IndexParams.stop must lie in (0, 1]")


@dataclass(frozen=True)
class EngineParams:
    """Parameters of the two-pass engine.

    Attributes:
        features: how images are extracted (must match the features added to the index).
        n_candidates: N, images kept by the first pass besides the best image of every state.
        weights: signature block weights (hist, thumb, desc_mean, desc_var, patch), >= 0;
            normalised to sum 1. ``None`` means :data:`DEFAULT_WEIGHTS`.
        changed_weights: weights of a second appearance model that holds when the light or
            the season changed (:data:`CHANGED_WEIGHTS`); :meth:`TourIndex.query_models`
            scores a frame with both, and the belief tracker weighs them by how well each
            explains the camera (:mod:`server.belief.appearance`). ``None`` (the default):
            one model only. ``bench localize`` and navigation use both
            (:func:`server.navigation.params.two_appearance_models`, docs/localize.md).
        feature_weight: weight of ``e_features`` (mean nearest-corner distance, ~[0, 1]).
        signature_weight: weight of the first-pass signature distance (~[0, 4]) in ``e``.
        symmetric: ``e_features`` also averages each candidate corner's nearest query corner
            (beyond 001; same distance matrix, measured to help on the corridor data).
        geometric: run the RANSAC homography check on the best candidates.
        geometric_top: how many of the best candidates the check verifies.
        geometric_weight: weight of ``1 - inlier fraction`` in ``e``.
        ransac_threshold: RANSAC reprojection threshold (px at the working size).
        min_matches: fewer mutual matches than this count as 0 inliers.
        floor: smallest similarity any image or state gets, so no likelihood is zero.
        outside_factor: similarity of a non-candidate image as a fraction of the smallest
            candidate similarity of its state (001: 1/2).
        index_min_images: the automatic switch to sub-linear retrieval. A tour of at least
            this many images takes the second pass's candidates from two inverted files
            (:mod:`server.vision.inverted`), built as the images are added: the
            ``n_candidates`` nearest signatures among the probed lists, plus the
            ``index.word_candidates`` best visual-word matches in place of the best image of
            every state (states without a candidate get ``floor``). Below it nothing changes:
            every signature is scanned, bit for bit as before. Chosen by measurement, the same
            for every data set (docs/retrieval.md, "Large tours").
        index: how the inverted files are built and probed (:class:`IndexParams`).
    """

    features: FeatureParams = field(default_factory=FeatureParams)
    n_candidates: int = 20
    weights: tuple[float, ...] | None = None
    changed_weights: tuple[float, ...] | None = None
    feature_weight: float = 1.0
    signature_weight: float = 0.2
    symmetric: bool = True
    geometric: bool = False
    geometric_top: int = 5
    geometric_weight: float = 0.3
    ransac_threshold: float = 8.0
    min_matches: int = 6
    floor: float = 1e-3
    outside_factor: float = 0.5
    index_min_images: int = 10_000
    index: IndexParams = field(default_factory=IndexParams)

    def __post_init__(self) -> None:
        if self.n_candidates < 1:
            raise ValueError("n_candidates must be at least 1")
        if self.index_min_images < 1:
            raise ValueError("index_min_images must be at least 1")
        if not 0.0 < self.floor < 1.0:
            raise ValueError("floor must lie in (0, 1)")
        blocks = [n for n, _ in signature_blocks(self.features)]
        for name in ("weights", "changed_weights"):
            value = getattr(self, name)
            if value is not None and len(value) != len(blocks):
                raise ValueError(f"{name} needs one value per signature block {blocks}")


@dataclass(frozen=True)
class Similarity:
    """Result of one query.

    Attributes:
        image: ``(n_images,) float64`` in (0, 1], per stored image in insertion order.
        state: ``(n_states,) float64`` in (0, 1], eq. (2): max over the state's images
            (``floor`` for a state without images).
        best_image: ``(n_states,) int64`` index of the best image of each state, -1 if none.
        candidates: ``(C,) int64`` image indices that went through the second pass, best first.
        first_pass_ms, second_pass_ms: wall time of the two passes (ms).
        n_scored: images whose signature distance the first pass computed (every image, or
            those in the probed lists and the visual-word candidates on a large tour).
        best_error: the smallest error ``e`` of the candidates *before* eq. (4) normalises
            it (unitless, ~[0, 1.5]; lower = a closer match; NaN without candidates): how
            well the frame matches anything in the tour at all, which the normalised
            similarities no longer say (:meth:`TourIndex.error_levels` gives the tour's own
            scale for it).
    """

    image: FloatArray
    state: FloatArray
    best_image: IntArray
    candidates: IntArray
    first_pass_ms: float
    second_pass_ms: float
    n_scored: int = 0
    best_error: float = math.nan

    @property
    def total_ms(self) -> float:
        return self.first_pass_ms + self.second_pass_ms


def default_weights(params: FeatureParams | None = None) -> FloatArray:
    """The documented default signature weights, ``(T,) float64`` summing to 1."""
    params = params or FeatureParams()
    w = np.asarray(DEFAULT_WEIGHTS, np.float64)
    if len(w) != len(signature_blocks(params)):
        w = np.full(len(signature_blocks(params)), 1.0 / len(signature_blocks(params)))
    return w / w.sum()


def _normalise_weights(w: npt.ArrayLike, n_blocks: int) -> FloatArray:
    arr = np.asarray(w, np.float64).ravel()
    if arr.shape != (n_blocks,) or not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ValueError(f"weights must be {n_blocks} finite non-negative numbers, got {arr}")
    if arr.sum() <= 0:
        raise ValueError("weights must not all be zero")
    return arr / arr.sum()


def _block_bounds(params: FeatureParams) -> IntArray:
    sizes = [n for _, n in signature_blocks(params)]
    return np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)


def block_distances(
    query: npt.NDArray[np.floating], signatures: npt.NDArray[np.floating], bounds: IntArray
) -> npt.NDArray[np.float64]:
    """Squared Euclidean distance per signature block: ``(n, T)`` for a ``(S,)`` query against
    ``(n, S)`` signatures (a plain reference implementation, used by learning and tests)."""
    diff = signatures.astype(np.float64) - query.astype(np.float64)[None, :]
    sq = diff * diff
    return np.stack([sq[:, a:b].sum(axis=1) for a, b in itertools.pairwise(bounds)], 1)


class TourIndex:
    """All stored images of one tour, ready for :meth:`query`.

    Images are appended with :meth:`add` in the order the caller chooses (storage uses the
    canonical image order of :class:`server.domain.TourGraph`); indices in every result refer to
    that insertion order.
    """

    def __init__(self, params: EngineParams = EngineParams()) -> None:
        self.params = params
        fp = params.features
        self._bounds = _block_bounds(fp)
        self._n_blocks = len(self._bounds) - 1
        self._s = signature_length(fp)
        self._k = fp.n_features
        self._d = fp.descriptor_bytes
        self._n = 0
        self._cap = 0
        # first-pass matrices, one contiguous (cap, S_t) float32 array per signature block, so
        # that blocks with weight 0 cost nothing
        self._blocks = [np.zeros((0, int(b - a)), np.float32) for a, b in self._block_pairs()]
        self._sqn = np.zeros((0, self._n_blocks), np.float32)  # per-block squared norms
        self._kp = np.zeros((0, self._k, 2), np.float16)
        self._desc = np.zeros((0, self._k, self._d), np.uint8)
        self._nkp = np.zeros(0, np.int16)
        self._state = np.zeros(0, np.int64)
        self._order: IntArray | None = None  # images sorted by state (lazy)
        self._sorted = True  # states already non-decreasing in insertion order
        self._seg_starts = np.zeros(0, np.int64)
        self._seg_states = np.zeros(0, np.int64)
        self._weights = (
            default_weights(fp)
            if params.weights is None
            else _normalise_weights(params.weights, self._n_blocks)
        )
        # the inverted files (None below params.index_min_images): signature lists with their
        # centroids by block, the vocabulary and the word file (None when no image has corners)
        self._ivf: InvertedFile | None = None
        self._cblocks: list[npt.NDArray[np.float32]] = []
        self._csqn = np.zeros((0, self._n_blocks), np.float32)
        self._vocab: VocabularyTree | None = None
        self._words: WordFile | None = None

    # ------------------------------------------------------------------ storage

    @property
    def n_images(self) -> int:
        return self._n

    @property
    def states(self) -> IntArray:
        """``(n_images,) int64`` upper state of every stored image (a copy)."""
        return self._state[: self._n].copy()

    @property
    def signatures(self) -> npt.NDArray[np.float32]:
        """``(n_images, S) float32`` stored signatures (a copy)."""
        return np.concatenate([blk[: self._n] for blk in self._blocks], axis=1)

    @property
    def bytes_per_image(self) -> float:
        """Memory per stored image in bytes (arrays at their used size; growth slack, at most
        2x, excluded): signature float32, block norms, keypoints float16, descriptors, counts,
        state."""
        return float(
            4 * self._s
            + self._sqn.itemsize * self._n_blocks
            + 2 * 2 * self._k
            + self._k * self._d
            + 2
            + 8
        )

    def features(self, i: int) -> ImageFeatures:
        """The stored features of image ``i`` (keypoints rounded to float16 precision)."""
        if not 0 <= i < self._n:
            raise IndexError(f"image {i} not in index of {self._n} images")
        k = int(self._nkp[i])
        return ImageFeatures(
            keypoints=self._kp[i, :k].astype(np.float32),
            descriptors=self._desc[i, :k].copy(),
            signature=np.concatenate([blk[i] for blk in self._blocks]),
            descriptor=self.params.features.descriptor,
            size=(self.params.features.width, self.params.features.height),
            flags=self.params.features.flags,
        )

    def _grow(self, need: int) -> None:
        if need <= self._cap:
            return
        cap = max(need, 2 * self._cap, 64)

        def grown(a: np.ndarray) -> np.ndarray:
            out = np.zeros((cap, *a.shape[1:]), a.dtype)
            out[: self._n] = a[: self._n]
            return out

        self._blocks = [grown(blk) for blk in self._blocks]
        self._sqn = grown(self._sqn)
        self._kp = grown(self._kp)
        self._desc = grown(self._desc)
        self._nkp = grown(self._nkp)
        self._state = grown(self._state)
        self._cap = cap

    def add(self, features: Sequence[ImageFeatures], states: npt.ArrayLike) -> None:
        """Append images. From ``params.index_min_images`` images on, each call also files the
        new images in the inverted files, re-sorting the word postings (time in proportion to
        the tour's size per call: add in batches, as the tour runtime does).

        Args:
            features: one :class:`ImageFeatures` per image, extracted with
                ``params.features``.
            states: ``(len(features),)`` int, the upper state of each image (>= 0).
        """
        st = np.asarray(states, np.int64).ravel()
        if len(st) != len(features):
            raise ValueError(f"{len(features)} images but {len(st)} states; give one per image")
        if len(st) and st.min() < 0:
            raise ValueError("states must be >= 0")
        fp = self.params.features
        for f in features:
            if f.descriptor != fp.descriptor or len(f.signature) != self._s:
                raise ValueError(
                    f"features ({f.descriptor}, signature {len(f.signature)}) do not match the "
                    f"index ({fp.descriptor}, signature {self._s}); re-extract with the "
                    "index's FeatureParams"
                )
        m = len(st)
        if m == 0:
            return
        self._grow(self._n + m)
        lo, hi = self._n, self._n + m
        sig = np.stack([f.signature for f in features]).astype(np.float32)
        for blk, (a, b) in zip(self._blocks, self._block_pairs(), strict=True):
            blk[lo:hi] = sig[:, a:b]
        self._sqn[lo:hi] = self._block_sqnorms(sig)
        for j, f in enumerate(features):
            k = min(f.n_keypoints, self._k)
            self._kp[lo + j, :k] = f.keypoints[:k]
            self._kp[lo + j, k:] = 0
            self._desc[lo + j, :k] = f.descriptors[:k]
            self._desc[lo + j, k:] = 0
            self._nkp[lo + j] = k
        self._state[lo:hi] = st
        self._n = hi
        self._order = None
        self._update_inverted_files(lo)

    def _block_sqnorms(self, sig: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        sq = sig.astype(np.float32) ** 2
        return np.add.reduceat(sq, self._bounds[:-1], axis=1).astype(np.float32)

    # ------------------------------------------------------------------ inverted files

    @property
    def uses_inverted_files(self) -> bool:
        """Whether queries take their candidates from the inverted files (the tour has at
        least ``params.index_min_images`` images)."""
        return self._ivf is not None

    @property
    def inverted_file(self) -> InvertedFile | None:
        """The inverted file over the signatures; ``None`` below the threshold."""
        return self._ivf

    @property
    def index_bytes_per_image(self) -> float:
        """Memory of the inverted files per stored image in bytes (0 below the threshold):
        list labels and members, word postings (image and count), norms, centroids and the
        vocabulary spread over the images."""
        if self._ivf is None or self._n == 0:
            return 0.0
        total = self._ivf.labels.nbytes + self._ivf.members.nbytes + self._ivf.offsets.nbytes
        total += self._ivf.centroids.nbytes + sum(c.nbytes for c in self._cblocks)
        if self._words is not None and self._vocab is not None:
            w = self._words
            total += w.offsets.nbytes + w.images.nbytes + w.counts.nbytes + w.idf.nbytes
            total += w.norms.nbytes + sum(lv.nbytes for lv in self._vocab.levels)
        return total / self._n

    def with_params(self, params: EngineParams) -> TourIndex:
        """The same images (signatures, corners, states, weights) under other engine
        parameters, e.g. another ``index_min_images``; ``params.features`` must match."""
        if params.features != self.params.features:
            raise ValueError("with_params keeps the features; re-extract for other FeatureParams")
        out = TourIndex(params)
        n = self._n
        out._grow(n)
        for mine, theirs in zip(self._blocks, out._blocks, strict=True):
            theirs[:n] = mine[:n]
        for name in ("_sqn", "_kp", "_desc", "_nkp", "_state"):
            getattr(out, name)[:n] = getattr(self, name)[:n]
        out._n = n
        out._weights = self._weights.copy()
        out._update_inverted_files(0)
        return out

    def _signature_rows(self, rows: npt.NDArray[np.int64] | slice) -> npt.NDArray[np.float32]:
        """``(r, S) float32`` stored signatures of ``rows`` (a copy)."""
        return np.concatenate([blk[: self._n][rows] for blk in self._blocks], axis=1)

    def _descriptor_floats(self, desc: npt.NDArray[np.uint8]) -> npt.NDArray[np.float32]:
        """``(m, D')`` descriptors as the vocabulary sees them: vector kinds scaled to nominal
        unit norm, binary kinds as their bits."""
        fp = self.params.features
        if fp.binary:
            return np.unpackbits(desc, axis=1).astype(np.float32)
        return desc.astype(np.float32) * np.float32(fp.descriptor_scale)

    def _corners(self, images: npt.NDArray[np.int64]) -> tuple[npt.NDArray[np.uint8], IntArray]:
        """The descriptors of every corner of ``images`` ``(m, D) uint8`` and their images."""
        nk = self._nkp[images].astype(np.int64)
        real = np.arange(self._k)[None, :] < nk[:, None]
        return self._desc[images][real], np.repeat(images, nk)

    def _quantised(self, lo: int, hi: int) -> tuple[IntArray, IntArray]:
        """Words and images of every corner of images ``lo..hi`` (in chunks, to bound memory)."""
        assert self._vocab is not None
        words, owners = [], []
        for a in range(lo, hi, 4096):
            desc, own = self._corners(np.arange(a, min(hi, a + 4096), dtype=np.int64))
            words.append(self._vocab.quantise(self._descriptor_floats(desc)))
            owners.append(own)
        if not words:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        return np.concatenate(words), np.concatenate(owners)

    def _update_inverted_files(self, first_new: int) -> None:
        """Keep the inverted files in step after images ``first_new..n`` were added: none below
        the threshold; trained afresh when there are none yet or the tour has doubled since
        they were trained (so O(1) trainings per image, amortised); else the new images are
        filed in their nearest lists and their corners under their words."""
        n = self._n
        if n < self.params.index_min_images:
            return
        if self._ivf is not None and n < 2 * self._ivf.n_trained:
            self._ivf = self._ivf.extended(self._signature_rows(slice(first_new, n)))
            if self._words is not None:
                words, owners = self._quantised(first_new, n)
                self._words = self._words.extended(words, owners, n)
            return
        self._train_signature_file()
        self._train_words()

    def _train_signature_file(self) -> None:
        ip = self.params.index
        n = self._n
        n_lists = int(min(n, max(1, round(ip.lists * np.sqrt(n)))))
        rng = np.random.default_rng(ip.seed)
        rows = np.sort(rng.choice(n, min(n, ip.sample_per_list * n_lists), replace=False))
        centroids = kmeans(
            self._signature_rows(rows.astype(np.int64)),
            n_lists,
            iterations=ip.iterations,
            seed=ip.seed,
        )
        labels = [
            nearest_centroid(self._signature_rows(slice(a, min(n, a + 8192))), centroids)
            for a in range(0, n, 8192)
        ]
        self._ivf = InvertedFile.of(centroids, np.concatenate(labels), n_trained=n)
        self._cblocks = [np.ascontiguousarray(centroids[:, a:b]) for a, b in self._block_pairs()]
        self._csqn = self._block_sqnorms(centroids)

    def _train_words(self) -> None:
        ip = self.params.index
        n = self._n
        nk = self._nkp[:n].astype(np.int64)
        total = int(nk.sum())
        if total == 0:
            self._vocab, self._words = None, None
            return
        rng = np.random.default_rng(ip.seed)
        pick = np.sort(rng.choice(total, min(total, ip.word_sample), replace=False))
        ends = np.cumsum(nk)
        img = np.searchsorted(ends, pick, side="right")
        slot = pick - (ends[img] - nk[img])
        self._vocab = VocabularyTree.train(
            self._descriptor_floats(self._desc[img, slot]),
            branching=ip.branching,
            depth=ip.depth,
            iterations=ip.iterations,
            seed=ip.seed,
        )
        words, owners = self._quantised(0, n)
        self._words = WordFile.of(words, owners, self._vocab.n_words, n)

    # ------------------------------------------------------------------ weights

    @property
    def weights(self) -> FloatArray:
        """``(T,) float64`` signature block weights in use (sum 1)."""
        return self._weights.copy()

    def set_weights(self, w: npt.ArrayLike) -> None:
        """Use new signature weights (e.g. from :func:`learn_weights`); normalised to sum 1."""
        self._weights = _normalise_weights(w, self._n_blocks)

    # ------------------------------------------------------------------ query

    def _segments(self) -> None:
        """Images grouped by state: a stable order and the segment starts (cached)."""
        st = self._state[: self._n]
        self._sorted = bool(np.all(st[1:] >= st[:-1]))
        if self._sorted:
            order = np.arange(self._n, dtype=np.int64)
        else:
            order = np.argsort(st, kind="stable").astype(np.int64)
        sorted_states = st[order]
        starts = np.flatnonzero(np.r_[True, sorted_states[1:] != sorted_states[:-1]])
        self._order = order
        self._seg_starts = starts.astype(np.int64)
        self._seg_states = sorted_states[starts]

    def model_weights(self) -> tuple[FloatArray, ...]:
        """``(T,)`` weights of every appearance model, in the order :meth:`query_models`
        answers: the tour's (:meth:`set_weights`), then ``params.changed_weights`` if set."""
        if self.params.changed_weights is None:
            return (self._weights.copy(),)
        return (
            self._weights.copy(),
            _normalise_weights(self.params.changed_weights, self._n_blocks),
        )

    def block_distances(
        self, query: ImageFeatures, blocks: npt.NDArray[np.bool_] | None = None
    ) -> npt.NDArray[np.float32]:
        """``(n_images, T) float32`` squared distance of every signature block to every image
        (``||q_t - x_t||^2``; columns of blocks not in ``blocks`` are 0)."""
        q = self._query_signature(query)
        n = self._n
        use = np.ones(self._n_blocks, bool) if blocks is None else blocks
        qsq = self._block_sqnorms(q[None, :])[0]
        out = np.zeros((n, self._n_blocks), np.float32)
        for t, (blk, (a, b)) in enumerate(zip(self._blocks, self._block_pairs(), strict=True)):
            if use[t]:
                col = blk[:n] @ (-2.0 * q[a:b])
                col += self._sqn[:n, t]
                col += qsq[t]
                out[:, t] = col
        np.maximum(out, 0.0, out=out)
        return out

    def _query_signature(self, query: ImageFeatures) -> npt.NDArray[np.float32]:
        q = np.asarray(query.signature, np.float32)
        if q.shape != (self._s,):
            raise ValueError(
                f"query signature has {q.shape} values, the index expects ({self._s},); "
                "extract the frame with the index's FeatureParams"
            )
        return q

    @staticmethod
    def _rows_block_distances(
        q: npt.NDArray[np.float32],
        qsq: npt.NDArray[np.float32],
        blocks: Sequence[npt.NDArray[np.float32] | None],
        sqn: npt.NDArray[np.float32],
        pairs: Sequence[tuple[int, int]],
    ) -> npt.NDArray[np.float32]:
        """``(r, T)`` squared block distances of ``q`` to the rows of ``blocks`` (``(r, S_t)``
        each, ``None`` for a block not used: its column is 0; norms ``sqn`` ``(r, T)``)."""
        out = np.zeros((len(sqn), len(pairs)), np.float32)
        for t, (blk, (a, b)) in enumerate(zip(blocks, pairs, strict=True)):
            if blk is not None:
                col = blk @ (-2.0 * q[a:b])
                col += sqn[:, t]
                col += qsq[t]
                out[:, t] = col
        np.maximum(out, 0.0, out=out)
        return out

    def _indexed_candidates(
        self, features: ImageFeatures, used: npt.NDArray[np.bool_], w32: npt.NDArray[np.float32]
    ) -> tuple[list[IntArray], list[npt.NDArray[np.float32]], int]:
        """The candidates of a large tour, per weight set (rows of ``w32``): the
        ``n_candidates`` nearest signatures among the images of the probed lists and the
        visual-word candidates (ascending image indices); their signature distances; how many
        images the first pass scored."""
        assert self._ivf is not None
        p = self.params
        ip = p.index
        q = self._query_signature(features)
        qsq = self._block_sqnorms(q[None, :])[0]
        pairs = self._block_pairs()
        centres = [c if u else None for c, u in zip(self._cblocks, used, strict=True)]
        cd = self._rows_block_distances(q, qsq, centres, self._csqn, pairs) @ w32.T  # (L, M)
        cd[np.diff(self._ivf.offsets) == 0] = np.inf  # an empty list is never worth a probe
        n_lists = self._ivf.n_lists
        k = min(ip.probe, n_lists)
        probe = [np.argpartition(c, k - 1)[:k] if k < n_lists else np.arange(n_lists) for c in cd.T]
        rows = self._ivf.rows(np.concatenate(probe))
        by_words = np.zeros(0, np.int64)
        if self._words is not None and self._vocab is not None and features.n_keypoints:
            words = self._vocab.quantise(self._descriptor_floats(features.descriptors))
            score = self._words.scores(words, stop=ip.stop)
            hits = np.flatnonzero(score > 0)
            t = len(hits) - ip.word_candidates
            if t > 0:
                hits = hits[np.argpartition(score[hits], t)[t:]]
            by_words = np.sort(hits).astype(np.int64)
        scored = np.union1d(rows, by_words).astype(np.int64)
        gathered = [blk[scored] if u else None for blk, u in zip(self._blocks, used, strict=True)]
        bd = self._rows_block_distances(q, qsq, gathered, self._sqn[scored], pairs)
        dists = (bd @ w32.T).T  # (M, r)
        r = len(scored)
        m = min(p.n_candidates, r)
        from_words = np.searchsorted(scored, by_words)
        cands, dcand = [], []
        for d in dists:
            top = np.argpartition(d, m - 1)[:m] if m < r else np.arange(r)
            local = np.union1d(top, from_words).astype(np.int64)
            cands.append(scored[local])
            dcand.append(d[local])
        return cands, dcand, r

    def signature_distances(self, query: ImageFeatures) -> npt.NDArray[np.float32]:
        """First pass: ``(n_images,) float32`` weighted signature distance to every image,
        ``sum_t w_t ||q_t - x_t||^2``, with the tour's weights."""
        w = self._weights
        return self.block_distances(query, w > 0) @ w.astype(np.float32)

    def _block_pairs(self) -> list[tuple[int, int]]:
        return [(int(a), int(b)) for a, b in zip(self._bounds[:-1], self._bounds[1:], strict=True)]

    def set_block_signatures(self, sig: npt.NDArray[np.float32]) -> None:
        """Overwrite the stored signatures of all images: ``(n_images, S) float32`` (used by
        the benchmark to jitter tiled synthetic tours)."""
        sig = np.asarray(sig, np.float32)
        if sig.shape != (self._n, self._s):
            raise ValueError(f"expected ({self._n}, {self._s}) signatures, got {sig.shape}")
        for blk, (a, b) in zip(self._blocks, self._block_pairs(), strict=True):
            blk[: self._n] = sig[:, a:b]
        self._sqn[: self._n] = self._block_sqnorms(sig)
        if self._ivf is not None:  # new signatures, same corners: the lists only
            self._train_signature_file()

    def _best_per_state(self, d: npt.NDArray[np.float32]) -> tuple[IntArray, IntArray]:
        """``(states present, best image of each)`` by first-pass distance."""
        if self._order is None:
            self._segments()
        assert self._order is not None
        order = self._order
        identity = self._sorted
        ds = d if identity else d[order]
        mins = np.minimum.reduceat(ds, self._seg_starts)
        counts = np.diff(np.r_[self._seg_starts, len(ds)])
        hits = np.flatnonzero(ds <= np.repeat(mins, counts))
        first = hits[np.searchsorted(hits, self._seg_starts)]
        best = first if identity else order[first]
        return self._seg_states, best.astype(np.int64)

    def feature_errors(self, query: ImageFeatures, candidates: IntArray) -> FloatArray:
        """Second pass: ``(C,) float64`` mean distance from each query corner to its nearest
        corner in each candidate, normalised to about [0, 1] (1 when either side has none)."""
        dist, valid = self._corner_distances(query, candidates)
        if dist is None:
            return np.ones(len(candidates), np.float64)
        err = self._feature_errors_from(dist)
        err[~valid] = 1.0
        return err

    def _feature_errors_from(self, dist: npt.NDArray[np.float32]) -> FloatArray:
        """``(C,)`` mean nearest-corner distance from a ``(Kq, C, K)`` distance tensor; with
        ``symmetric`` also the mean from each candidate corner to its nearest query corner."""
        err = self._to_distance(dist.min(axis=2)).mean(axis=0)  # query -> candidate
        if self.params.symmetric:
            back = dist.min(axis=0)  # (C, K), huge for padding
            real = back < 1e5
            counts = np.maximum(real.sum(axis=1), 1)
            back_d = np.where(real, self._to_distance(back), 0.0)
            err = 0.5 * (err + back_d.sum(axis=1) / counts)
        return err

    def _corner_distances(
        self, query: ImageFeatures, candidates: IntArray
    ) -> tuple[npt.NDArray[np.float32] | None, npt.NDArray[np.bool_]]:
        """``(Kq, C, K)`` descriptor dissimilarities and which candidates have corners.

        Vector kinds (grad36, SIFT): *squared* Euclidean distance of descriptors scaled to
        nominal unit norm (``FeatureParams.descriptor_scale``; take the square root after any
        min); binary kinds (ORB): Hamming distance / bits. Padding slots hold a huge value so
        they never win a min.
        """
        kq = query.n_keypoints
        c = len(candidates)
        nk = self._nkp[candidates]
        valid = nk > 0
        if kq == 0 or c == 0 or not valid.any():
            return None, valid
        k = self._k
        flat = self._desc[candidates].reshape(c * k, self._d)  # (C*K, D) uint8
        pad = (np.arange(k)[None, :] >= nk[:, None]).ravel()  # (C*K,)
        fp = self.params.features
        if not fp.binary:
            scale = np.float32(fp.descriptor_scale)
            qf = query.descriptors.astype(np.float32) * scale
            cf = flat.astype(np.float32) * scale
            c2 = np.einsum("ij,ij->i", cf, cf)
            c2[pad] = 1e6
            q2 = np.einsum("ij,ij->i", qf, qf)
            dd = qf @ (-2.0 * cf).T  # (Kq, C*K)
            dd += c2[None, :]
            dd += q2[:, None]
        else:
            bits = 8.0 * self._d
            qf = np.unpackbits(query.descriptors, axis=1).astype(np.float32) * 2.0 - 1.0
            cf = np.unpackbits(flat, axis=1).astype(np.float32) * 2.0 - 1.0
            dd = qf @ cf.T  # (Kq, C*K): bits - 2 * hamming
            dd *= np.float32(-1.0 / (2.0 * bits))
            dd += np.float32(0.5)
            dd[:, pad] = 1e6
        return dd.reshape(kq, c, k), valid

    def _to_distance(self, x: npt.NDArray[np.floating]) -> npt.NDArray[np.float64]:
        """Map values of :meth:`_corner_distances` (after a min) to distances."""
        y: npt.NDArray[np.float64] = np.asarray(x, np.float64)
        if not self.params.features.binary:
            return np.asarray(np.sqrt(np.maximum(y, 0.0)), np.float64)
        return y

    def geometric_inliers(self, query: ImageFeatures, candidates: npt.ArrayLike) -> IntArray:
        """``(C,) int64`` RANSAC homography inliers between ``query`` and each of ``candidates``
        (image indices) on mutual nearest-neighbour corner matches: the count the geometric
        check's inlier fraction is made of (0 when unverifiable)."""
        cand = np.asarray(candidates, np.int64).ravel()
        if len(cand) and (cand.min() < 0 or cand.max() >= self._n):
            raise IndexError(f"candidates {cand} not all in index of {self._n} images")
        dist, _ = self._corner_distances(query, cand)
        return self._geometric_inliers(query, cand, dist)

    def _geometric_errors(
        self, query: ImageFeatures, candidates: IntArray, dist: npt.NDArray[np.float32] | None
    ) -> FloatArray:
        """``(C,)`` 1 - RANSAC inlier fraction for each of ``candidates`` (1 when unverifiable)."""
        inliers = self._geometric_inliers(query, candidates, dist)
        return 1.0 - inliers / float(max(query.n_keypoints, 1))

    def _geometric_inliers(
        self, query: ImageFeatures, candidates: IntArray, dist: npt.NDArray[np.float32] | None
    ) -> IntArray:
        """``(C,)`` RANSAC inliers for each of ``candidates`` (0 when unverifiable)."""
        p = self.params
        out = np.zeros(len(candidates), np.int64)
        if dist is None:
            return out
        kq = query.n_keypoints
        for j, i in enumerate(candidates):
            nk = int(self._nkp[i])
            if nk < p.min_matches:
                continue
            d = dist[:, j, :nk]  # (Kq, nk)
            fwd = d.argmin(axis=1)
            back = d.argmin(axis=0)
            mutual = back[fwd] == np.arange(kq)
            if int(mutual.sum()) < p.min_matches:
                continue
            src = query.keypoints[mutual].astype(np.float32)
            dst = self._kp[i, fwd[mutual]].astype(np.float32)
            _, mask = cv2.findHomography(src, dst, cv2.RANSAC, p.ransac_threshold)
            if mask is None:
                continue
            out[j] = int(mask.sum())
        return out

    def query(self, features: ImageFeatures, *, n_states: int | None = None) -> Similarity:
        """Similarity of a frame to every stored image and every state, with the tour's
        weights (the first appearance model).

        Args:
            features: the frame's features (extracted with ``params.features``).
            n_states: number of upper states; defaults to ``max(state) + 1``. States without
                images get ``floor``.

        Returns:
            :class:`Similarity` (see there for shapes).
        """
        return self._query(features, n_states, (self._weights,))[0]

    def query_models(
        self, features: ImageFeatures, *, n_states: int | None = None
    ) -> tuple[Similarity, ...]:
        """:meth:`query` under every appearance model (:meth:`model_weights`), sharing the
        block distances of the first pass and the corner distances of the second."""
        return self._query(features, n_states, self.model_weights())

    def error_levels(self, related: npt.ArrayLike | None = None, n_probe: int = 128) -> FloatArray:
        """``(P,) float64``, ascending: the tour's own scale for :attr:`Similarity.best_error`.

        ``P <= n_probe`` taught images, evenly spaced, are each queried with the tour's
        weights against the images of the states not related to its own; each gives its best
        error. So the levels say how well a frame taken in the tour's own light matches the
        tour where it is *not* (:func:`server.belief.appearance.familiarity`).

        Args:
            related: ``(n_states, n_states) bool``, ``related[a, b]``: an image of state ``a``
                must not be scored against the images of state ``b`` (a state and its graph
                neighbours, whose images overlap its own). ``None``: only the state itself.
            n_probe: at most this many taught images are queried (time in proportion).

        Returns:
            the best errors, ascending; empty when no image has an unrelated state.
        """
        n = self._n
        states = self._state[:n]
        if n == 0:
            return np.zeros(0)
        ns = int(states.max()) + 1
        rel = np.eye(ns, dtype=bool) if related is None else np.asarray(related, bool)
        if rel.ndim != 2 or rel.shape[0] != rel.shape[1] or rel.shape[0] < ns:
            raise ValueError(f"related must be (n_states, n_states) with n_states >= {ns}")
        rel = rel | np.eye(len(rel), dtype=bool)  # a state is always related to itself
        out: list[float] = []
        probes = np.unique(np.linspace(0, n - 1, min(int(n_probe), n)).round().astype(np.int64))
        for i in probes:
            exclude = rel[int(states[i])]
            sim = self._query(self.features(int(i)), len(rel), (self._weights,), exclude=exclude)
            if math.isfinite(sim[0].best_error):
                out.append(sim[0].best_error)
        return np.sort(np.asarray(out, np.float64))

    def _query(
        self,
        features: ImageFeatures,
        n_states: int | None,
        weight_sets: Sequence[FloatArray],
        *,
        exclude: npt.NDArray[np.bool_] | None = None,
    ) -> tuple[Similarity, ...]:
        p = self.params
        n = self._n
        max_state = int(self._state[:n].max()) if n else -1
        ns = max_state + 1 if n_states is None else int(n_states)
        if ns <= max_state:
            raise ValueError(f"n_states={ns} but the index holds state {max_state}")
        if n == 0:
            empty = np.zeros(0, np.int64)
            none = Similarity(
                image=np.zeros(0),
                state=np.full(ns, p.floor),
                best_image=np.full(ns, -1, np.int64),
                candidates=empty,
                first_pass_ms=0.0,
                second_pass_ms=0.0,
            )
            return tuple(none for _ in weight_sets)

        t0 = time.perf_counter()
        w32 = np.stack(weight_sets).astype(np.float32)  # (M, T)
        used = np.asarray((w32 > 0).any(axis=0), bool)
        if self._ivf is not None:
            cands, dcand, n_scored = self._indexed_candidates(features, used, w32)
        else:
            dists = (self.block_distances(features, used) @ w32.T).T  # (M, n)
            m = min(p.n_candidates, n)
            cands, dcand, n_scored = [], [], n
            for d in dists:
                top = np.argpartition(d, m - 1)[:m] if m < n else np.arange(n)
                _, best = self._best_per_state(d)
                cand = np.union1d(top, best).astype(np.int64)
                cands.append(cand)
                dcand.append(d[cand])
        if exclude is not None:  # (n_states,) bool: states whose images may not answer
            keep = [~exclude[self._state[c]] for c in cands]
            cands = [c[k] for c, k in zip(cands, keep, strict=True)]
            dcand = [dc[k] for dc, k in zip(dcand, keep, strict=True)]
            if not all(len(c) for c in cands):
                return tuple(
                    Similarity(np.zeros(0), np.zeros(0), np.zeros(0, np.int64), c, 0.0, 0.0)
                    for c in cands
                )
        union = functools.reduce(np.union1d, cands).astype(np.int64)
        t1 = time.perf_counter()

        dist, valid = self._corner_distances(features, union)
        if dist is None:
            e_feat = np.ones(len(union), np.float64)
        else:
            e_feat = self._feature_errors_from(dist)
            e_feat[~valid] = 1.0
        out: list[Similarity] = []
        best_errors: list[float] = []
        for dc, cand in zip(dcand, cands, strict=True):
            pos = np.searchsorted(union, cand)
            e = p.feature_weight * e_feat[pos] + p.signature_weight * dc.astype(np.float64)
            if p.geometric and p.geometric_weight > 0:
                g = min(p.geometric_top, len(cand))
                verify = np.argsort(e, kind="stable")[:g]
                e_geo = np.ones(len(cand), np.float64)
                sub = None if dist is None else dist[:, pos[verify]]
                e_geo[verify] = self._geometric_errors(features, cand[verify], sub)
                e = e + p.geometric_weight * e_geo
            out.append(self._similarity(cand, _normalise_errors(e, p.floor), ns))
            best_errors.append(float(e.min()))
        t2 = time.perf_counter()
        return tuple(
            dataclasses.replace(
                sim,
                first_pass_ms=(t1 - t0) * 1e3,
                second_pass_ms=(t2 - t1) * 1e3,
                n_scored=n_scored,
                best_error=b,
            )
            for sim, b in zip(out, best_errors, strict=True)
        )

    def _similarity(self, cand: IntArray, sim_c: FloatArray, ns: int) -> Similarity:
        """The :class:`Similarity` of the candidates' similarities ``sim_c`` (timings 0)."""
        image = self._spread(cand, sim_c, ns)
        state = np.full(ns, self.params.floor, np.float64)
        np.maximum.at(state, self._state[cand], sim_c)
        best_image = np.full(ns, -1, np.int64)
        # best image of each state = its best candidate (every state has one candidate)
        order = np.lexsort((-sim_c, self._state[cand]))
        cs = self._state[cand][order]
        firsts = np.r_[True, cs[1:] != cs[:-1]]
        best_image[cs[firsts]] = cand[order][firsts]
        ranked = cand[np.argsort(-sim_c, kind="stable")]
        return Similarity(
            image=image,
            state=state,
            best_image=best_image,
            candidates=ranked,
            first_pass_ms=0.0,
            second_pass_ms=0.0,
        )

    def _spread(self, cand: IntArray, sim_c: FloatArray, n_states: int) -> FloatArray:
        """Per-image similarity: candidates keep theirs, others get ``outside_factor`` times the
        smallest candidate similarity of their state, never below ``floor``."""
        p = self.params
        n = self._n
        smallest = np.full(n_states, np.inf)
        np.minimum.at(smallest, self._state[cand], sim_c)
        smallest[~np.isfinite(smallest)] = p.floor
        image = np.maximum(p.outside_factor * smallest[self._state[:n]], p.floor)
        image[cand] = sim_c
        return image


def _normalise_errors(e: FloatArray, floor: float) -> FloatArray:
    """Eq. (4) over the candidates, then the floor: ``(C,)`` in [floor, 1]; the best is 1."""
    lo, hi = float(e.min()), float(e.max())
    if hi - lo <= 1e-12:
        return np.ones_like(e)
    return np.maximum(1.0 - (e - lo) / (hi - lo), floor)
