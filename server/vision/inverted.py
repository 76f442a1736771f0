"""Inverted files for large tours: the candidates of the two-pass query in sub-linear time.

Below ``EngineParams.index_min_images`` the first pass compares a frame's signature with every
stored image. Above it, :class:`server.vision.index.TourIndex` keeps two inverted files and
takes the second pass's candidates from them (docs/retrieval.md, "Large tours"):

* :class:`InvertedFile` over the **global signatures** - a coarse quantiser (k-means,
  :func:`kmeans`) splits the signatures into lists of similar images; a query ranks the list
  centres under its weights, probes the nearest lists and computes the exact weighted signature
  distance to the images in them only (the IVF of Jegou et al., "Product quantization for
  nearest neighbor search", 2011). It gives the images the signature finds nearest.
* :class:`WordFile` over **visual words** - every corner descriptor is quantised by a
  :class:`VocabularyTree` (Nister & Stewenius, "Scalable recognition with a vocabulary tree",
  2006; seed 000); the file lists, per word, the images holding it. A query scores images by
  the cosine of tf-idf word vectors, skipping words held by too many images (the stop-list of
  seed 000). It gives the images whose corners look like the frame's, which the exhaustive
  engine found by adding the best image of every state to the second pass.

The signature centroids live in the plain signature space (every block unit norm, all blocks
counted alike), not in the space of one set of weights, so that the lists serve the tour's
learned weights and the change-robust model alike and :meth:`TourIndex.set_weights` does not
rebuild them.

Pure NumPy; every function returns new arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

F32 = npt.NDArray[np.float32]
I64 = npt.NDArray[np.int64]


def nearest_centroid(x: F32, centroids: F32, *, chunk: int = 8192) -> I64:
    """``(n,) int64``: the index of the nearest of ``centroids`` ``(L, S)`` (squared Euclidean
    distance; the first on a tie) for every row of ``x`` ``(n, S)``."""
    c = np.asarray(centroids, np.float32)
    c2 = np.einsum("ij,ij->i", c, c)
    minus2ct = -2.0 * c.T
    out = np.empty(len(x), np.int64)
    for lo in range(0, len(x), chunk):
        d = np.asarray(x[lo : lo + chunk], np.float32) @ minus2ct
        d += c2
        out[lo : lo + chunk] = d.argmin(axis=1)
    return out


def kmeans(x: F32, k: int, *, iterations: int = 10, seed: int = 0) -> F32:
    """``(k, S) float32`` centroids of ``x`` ``(n, S)`` by Lloyd's algorithm.

    Starts from ``k`` distinct rows chosen at random (the same data and ``seed`` give the same
    centroids); a centroid left without rows moves onto the row farthest from its own centroid.
    Needs ``1 <= k <= n``.
    """
    x = np.asarray(x, np.float32)
    n = len(x)
    if not 1 <= k <= n:
        raise ValueError(f"k-means needs 1 <= k <= n rows, got k={k}, n={n}")
    rng = np.random.default_rng(seed)
    c = x[np.sort(rng.choice(n, k, replace=False))].copy()
    for _ in range(iterations):
        labels = nearest_centroid(x, c)
        counts = np.bincount(labels, minlength=k)
        order = np.argsort(labels, kind="stable")
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        full = counts > 0
        c_new = np.zeros_like(c)
        c_new[full] = np.add.reduceat(x[order], starts[full], axis=0) / counts[full, None]
        empty = np.flatnonzero(~full)
        if len(empty):
            resid = x - c_new[labels]
            far = np.argsort(-np.einsum("ij,ij->i", resid, resid), kind="stable")
            c_new[empty] = x[far[: len(empty)]]
        c = c_new
    return c


def _ranges(lo: I64, hi: I64) -> I64:
    """The concatenated integer ranges ``lo[i]..hi[i]`` (exclusive), without a Python loop."""
    sizes = hi - lo
    total = int(sizes.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    starts = np.repeat(lo - np.concatenate([[0], np.cumsum(sizes)[:-1]]), sizes)
    return np.arange(total, dtype=np.int64) + starts


@dataclass(frozen=True)
class InvertedFile:
    """Images grouped by their nearest signature centroid.

    Attributes:
        centroids: ``(L, S) float32`` list centres (plain signature space).
        labels: ``(n,) int64`` the list of every image, insertion order.
        offsets: ``(L + 1,) int64`` list ``l`` holds ``members[offsets[l]:offsets[l + 1]]``.
        members: ``(n,) int64`` image indices, list by list, ascending within a list.
        n_trained: how many images there were when the centroids were trained.
    """

    centroids: F32
    labels: I64
    offsets: I64
    members: I64
    n_trained: int

    @property
    def n_lists(self) -> int:
        return len(self.centroids)

    @classmethod
    def of(cls, centroids: F32, labels: I64, *, n_trained: int) -> InvertedFile:
        """The inverted file of ``centroids`` ``(L, S)`` and the image ``labels`` ``(n,)``."""
        labels = np.asarray(labels, np.int64)
        counts = np.bincount(labels, minlength=len(centroids))
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        members = np.argsort(labels, kind="stable").astype(np.int64)
        return cls(np.asarray(centroids, np.float32), labels, offsets, members, n_trained)

    def extended(self, x_new: F32) -> InvertedFile:
        """This file with the images ``x_new`` ``(m, S)`` appended, each in its nearest list
        (the centroids stay)."""
        labels = np.concatenate([self.labels, nearest_centroid(x_new, self.centroids)])
        return InvertedFile.of(self.centroids, labels, n_trained=self.n_trained)

    def rows(self, lists: npt.ArrayLike) -> I64:
        """``(r,) int64`` the images in ``lists``, ascending, each once."""
        ls = np.unique(np.asarray(lists, np.int64))
        return np.sort(self.members[_ranges(self.offsets[ls], self.offsets[ls + 1])])


@dataclass(frozen=True)
class VocabularyTree:
    """Visual words by hierarchical k-means: ``depth`` levels of ``branching`` children,
    ``branching ** depth`` leaves, the words (Nister & Stewenius 2006; seed 000 uses 10 x 4).

    Attributes:
        levels: per level ``l``, ``(branching ** l, branching, D) float32``, the centroids of
            the children of every node at that level (level 0 holds the root's).
    """

    levels: tuple[F32, ...]

    @property
    def branching(self) -> int:
        return int(self.levels[0].shape[1])

    @property
    def n_words(self) -> int:
        return int(self.levels[-1].shape[0] * self.branching)

    @classmethod
    def train(
        cls, x: F32, *, branching: int, depth: int, iterations: int = 8, seed: int = 0
    ) -> VocabularyTree:
        """Split the descriptors ``x`` ``(m, D)`` into ``branching`` clusters, each of those
        again, ``depth`` times. A node with fewer rows than ``branching`` repeats a centroid
        (the first copy wins every tie, so the others stay empty words)."""
        if branching < 2 or depth < 1:
            raise ValueError("a vocabulary tree needs branching >= 2 and depth >= 1")
        x = np.asarray(x, np.float32)
        if len(x) == 0:
            raise ValueError("a vocabulary tree needs at least one descriptor")
        node = np.zeros(len(x), np.int64)
        levels: list[F32] = []
        for level in range(depth):
            n_nodes = branching**level
            cent = np.zeros((n_nodes, branching, x.shape[1]), np.float32)
            order = np.argsort(node, kind="stable")
            bounds = np.searchsorted(node[order], np.arange(n_nodes + 1))
            new = np.zeros(len(x), np.int64)
            for c in range(n_nodes):
                rows = order[bounds[c] : bounds[c + 1]]
                if len(rows) == 0:  # an empty word of the level above: children at its centre
                    cent[c] = levels[-1][c // branching, c % branching]
                    continue
                k = min(branching, len(rows))
                cent[c, :k] = kmeans(x[rows], k, iterations=iterations, seed=seed + c)
                cent[c, k:] = cent[c, 0]
                new[rows] = c * branching + nearest_centroid(x[rows], cent[c])
            levels.append(cent)
            node = new
        return cls(tuple(levels))

    def quantise(self, x: F32) -> I64:
        """``(m,) int64`` the word (leaf) of every descriptor in ``x`` ``(m, D)``: at every
        level the nearest child of the node reached so far."""
        x = np.asarray(x, np.float32)
        m = len(x)
        b = self.branching
        node = np.zeros(m, np.int64)
        for cent in self.levels:
            if m * b <= 1 << 14:  # a query's corners: each row against its node's children
                ch = cent[node]  # (m, b, D)
                dist = np.einsum("mbd,mbd->mb", ch, ch) - 2.0 * np.einsum("mbd,md->mb", ch, x)
                node = node * b + dist.argmin(axis=1)
                continue
            order = np.argsort(node, kind="stable")  # many rows: one product per node
            bounds = np.searchsorted(node[order], np.arange(len(cent) + 1))
            new = np.empty(m, np.int64)
            for c in np.flatnonzero(np.diff(bounds)):
                rows = order[bounds[c] : bounds[c + 1]]
                new[rows] = c * b + nearest_centroid(x[rows], cent[c])
            node = new
        return node


@dataclass(frozen=True)
class WordFile:
    """An inverted file over visual words: for every word, the images holding it and how many
    of their corners fell on it (tf-idf scoring, Nister & Stewenius 2006).

    Attributes:
        n_words: size of the vocabulary.
        offsets: ``(n_words + 1,) int64`` word ``w``'s postings are ``[offsets[w]:offsets[w+1]]``.
        images: ``(P,) int32`` the image of every posting (ascending within a word).
        counts: ``(P,) float32`` the image's corners on the word.
        idf: ``(n_words,) float32`` ``ln(n_images / images holding the word)``, 0 for none.
        norms: ``(n_images,) float32`` length of every image's tf-idf vector.
    """

    n_words: int
    offsets: I64
    images: npt.NDArray[np.int32]
    counts: F32
    idf: F32
    norms: F32

    @property
    def n_images(self) -> int:
        return len(self.norms)

    @classmethod
    def of(
        cls, words: npt.ArrayLike, owners: npt.ArrayLike, n_words: int, n_images: int
    ) -> WordFile:
        """The file of corners on ``words`` ``(m,)`` belonging to images ``owners`` ``(m,)``
        (``0 <= owners < n_images``)."""
        w = np.asarray(words, np.int64)
        pairs, cnt = np.unique(w * n_images + np.asarray(owners, np.int64), return_counts=True)
        return cls._of_postings(pairs // n_images, pairs % n_images, cnt, n_words, n_images)

    @classmethod
    def _of_postings(
        cls, w: I64, img: I64, cnt: npt.ArrayLike, n_words: int, n_images: int
    ) -> WordFile:
        """From postings sorted by word, then image."""
        df = np.bincount(w, minlength=n_words)
        offsets = np.concatenate([[0], np.cumsum(df)]).astype(np.int64)
        idf = np.where(df > 0, np.log(n_images / np.maximum(df, 1)), 0.0).astype(np.float32)
        counts = np.asarray(cnt, np.float32)
        norms = np.sqrt(np.bincount(img, weights=(counts * idf[w]) ** 2, minlength=n_images))
        return cls(n_words, offsets, img.astype(np.int32), counts, idf, norms.astype(np.float32))

    def extended(self, words: npt.ArrayLike, owners: npt.ArrayLike, n_images: int) -> WordFile:
        """This file with the corners of new images (``owners`` all ``>= self.n_images``,
        ``< n_images``) added; idf and norms recomputed for ``n_images`` images."""
        new = WordFile.of(words, owners, self.n_words, n_images)
        old_w = np.repeat(np.arange(self.n_words), np.diff(self.offsets))
        new_w = np.repeat(np.arange(self.n_words), np.diff(new.offsets))
        w = np.concatenate([old_w, new_w])
        order = np.argsort(w, kind="stable")  # old images first within a word: still ascending
        img = np.concatenate([self.images, new.images]).astype(np.int64)[order]
        cnt = np.concatenate([self.counts, new.counts])[order]
        return WordFile._of_postings(w[order], img, cnt, self.n_words, n_images)

    def scores(self, words: npt.ArrayLike, *, stop: float) -> F32:
        """``(n_images,) float32`` cosine of the tf-idf vectors of a query (its corners'
        ``words``) and every image. Words held by more than a fraction ``stop`` of the images
        are left out (the stop-list), as are words no image holds."""
        qw, qc = np.unique(np.asarray(words, np.int64), return_counts=True)
        df = self.offsets[qw + 1] - self.offsets[qw]
        keep = (df > 0) & (df <= stop * self.n_images)
        qw, qc, df = qw[keep], qc[keep], df[keep]
        if len(qw) == 0:
            return np.zeros(self.n_images, np.float32)
        qv = qc.astype(np.float64) * self.idf[qw]
        qv /= max(float(np.linalg.norm(qv)), 1e-12)
        pos = _ranges(self.offsets[qw], self.offsets[qw + 1])
        contrib = np.repeat(qv * self.idf[qw], df) * self.counts[pos]
        out = np.bincount(self.images[pos], weights=contrib, minlength=self.n_images)
        return (out / np.maximum(self.norms, 1e-12)).astype(np.float32)
