"""Large tours: the inverted files against naive references, and the switch at the threshold."""

from __future__ import annotations

import itertools
import sys
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vision_testkit import scene

from server.vision import EngineParams, ImageFeatures, TourIndex, extract
from server.vision.features import signature_blocks
from server.vision.index import CHANGED_WEIGHTS, IndexParams, block_distances
from server.vision.inverted import (
    InvertedFile,
    VocabularyTree,
    WordFile,
    kmeans,
    nearest_centroid,
)

NEVER = EngineParams(index_min_images=sys.maxsize)
SMALL = IndexParams(branching=8, depth=2, word_sample=5000)  # a small vocabulary: fast tests
ALWAYS = EngineParams(index_min_images=1, index=SMALL)
BOUNDS = np.concatenate([[0], np.cumsum([n for _, n in signature_blocks()])])


# ------------------------------------------------------------------ k-means and the lists


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 60), k=st.integers(1, 9))
def test_nearest_centroid_equals_a_naive_loop(seed: int, n: int, k: int) -> None:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, 5)).astype(np.float32)
    c = rng.normal(size=(k, 5)).astype(np.float32)
    naive = [int(np.argmin([np.sum((xi - cj) ** 2) for cj in c])) for xi in x]
    np.testing.assert_array_equal(nearest_centroid(x, c, chunk=7), naive)


def test_kmeans_finds_separated_clusters_and_is_repeatable() -> None:
    rng = np.random.default_rng(1)
    centres = np.array([[0, 0], [10, 0], [0, 10], [10, 10]], np.float32)
    x = np.concatenate([c + rng.normal(0, 0.3, size=(50, 2)) for c in centres]).astype(np.float32)
    c = kmeans(x, 4, iterations=10, seed=3)
    found = sorted(map(tuple, np.round(c / 10) * 10))
    assert found == sorted(map(tuple, centres))
    np.testing.assert_array_equal(c, kmeans(x, 4, iterations=10, seed=3))
    # k = n: every row is a centroid
    np.testing.assert_array_equal(np.sort(kmeans(x[:7], 7), axis=0), np.sort(x[:7], axis=0))
    with pytest.raises(ValueError, match="k <= n"):
        kmeans(x[:3], 4)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 80), n_lists=st.integers(1, 10))
def test_inverted_file_holds_every_image_once(seed: int, n: int, n_lists: int) -> None:
    rng = np.random.default_rng(seed)
    labels = rng.integers(0, n_lists, size=n)
    ivf = InvertedFile.of(np.zeros((n_lists, 3), np.float32), labels, n_trained=n)
    np.testing.assert_array_equal(np.sort(ivf.members), np.arange(n))
    np.testing.assert_array_equal(ivf.rows(np.arange(n_lists)), np.arange(n))
    pick = rng.integers(0, n_lists, size=3)
    np.testing.assert_array_equal(ivf.rows(pick), np.flatnonzero(np.isin(labels, pick)))
    for lst in range(n_lists):
        members = ivf.members[ivf.offsets[lst] : ivf.offsets[lst + 1]]
        np.testing.assert_array_equal(members, np.flatnonzero(labels == lst))


def test_extending_the_lists_files_new_rows_in_their_nearest_list() -> None:
    rng = np.random.default_rng(2)
    c = rng.normal(size=(4, 3)).astype(np.float32)
    x = rng.normal(size=(30, 3)).astype(np.float32)
    first = InvertedFile.of(c, nearest_centroid(x[:20], c), n_trained=20)
    grown = first.extended(x[20:])
    whole = InvertedFile.of(c, nearest_centroid(x, c), n_trained=20)
    for name in ("labels", "offsets", "members"):
        np.testing.assert_array_equal(getattr(grown, name), getattr(whole, name))


# ------------------------------------------------------------------ visual words


def test_vocabulary_tree_descends_to_the_nearest_child() -> None:
    rng = np.random.default_rng(4)
    x = rng.normal(size=(3000, 6)).astype(np.float32)
    tree = VocabularyTree.train(x, branching=4, depth=3, iterations=5)
    assert tree.n_words == 64 and len(tree.levels) == 3
    q = rng.normal(size=(40, 6)).astype(np.float32)
    naive = []
    for row in q:
        node = 0
        for cent in tree.levels:
            node = node * 4 + int(np.argmin(np.sum((cent[node] - row) ** 2, axis=1)))
        naive.append(node)
    np.testing.assert_array_equal(tree.quantise(q), naive)  # few rows: gathered children
    many = np.concatenate([q] * 120)  # many rows: one product per node, the same words
    np.testing.assert_array_equal(tree.quantise(many)[:40], naive)
    # few rows at a node: repeated centroids, the first wins
    small = VocabularyTree.train(x[:3], branching=4, depth=2)
    assert len(np.unique(small.quantise(x[:3]))) == 3


def _dense_scores(words, owners, n_words, n_images, query, stop):
    tf = np.zeros((n_images, n_words))
    np.add.at(tf, (owners, words), 1.0)
    df = (tf > 0).sum(axis=0)
    idf = np.where(df > 0, np.log(n_images / np.maximum(df, 1)), 0.0)
    docs = tf * idf
    q = np.bincount(query, minlength=n_words) * idf
    q[(df == 0) | (df > stop * n_images)] = 0.0
    if not q.any():
        return np.zeros(n_images)
    q /= np.linalg.norm(q)
    norms = np.linalg.norm(docs, axis=1)
    return docs @ q / np.maximum(norms, 1e-12)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n_images=st.integers(1, 30),
    n_words=st.integers(1, 40),
    stop=st.sampled_from([0.1, 0.3, 1.0]),
)
def test_word_scores_equal_a_dense_tf_idf_cosine(
    seed: int, n_images: int, n_words: int, stop: float
) -> None:
    rng = np.random.default_rng(seed)
    m = int(rng.integers(0, 200))
    words = rng.integers(0, n_words, size=m)
    owners = rng.integers(0, n_images, size=m)
    query = rng.integers(0, n_words, size=int(rng.integers(0, 30)))
    wf = WordFile.of(words, owners, n_words, n_images)
    got = wf.scores(query, stop=stop)
    want = _dense_scores(words, owners, n_words, n_images, query, stop)
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5)
    # adding images one batch at a time gives the same file
    cut = int(rng.integers(0, n_images + 1))
    first = owners < cut
    grown = WordFile.of(words[first], owners[first], n_words, max(cut, 1)) if cut else None
    if grown is not None:
        grown = grown.extended(words[~first], owners[~first], n_images)
        for name in ("offsets", "images", "counts", "idf", "norms"):
            np.testing.assert_allclose(getattr(grown, name), getattr(wf, name), rtol=1e-6)


def test_the_stop_list_leaves_out_words_most_images_hold() -> None:
    # word 0 in three of four images, word 1 in image 3 only
    wf = WordFile.of([0, 0, 0, 1], [0, 1, 2, 3], n_words=2, n_images=4)
    assert np.all(wf.scores([0], stop=1.0)[:3] > 0)
    assert np.all(wf.scores([0], stop=0.5) == 0)  # held by 3/4 > 0.5 of the images: stopped
    np.testing.assert_array_equal(np.flatnonzero(wf.scores([0, 1], stop=0.5)), [3])


# ------------------------------------------------------------------ the tour index


@pytest.fixture(scope="module")
def scenes() -> list[ImageFeatures]:
    return [extract(scene(4000 + k)) for k in range(48)]


def _random_signatures(rng: np.random.Generator, n: int) -> np.ndarray:
    sig = rng.normal(size=(n, BOUNDS[-1])).astype(np.float32)
    for a, b in itertools.pairwise(BOUNDS):
        sig[:, a:b] /= np.linalg.norm(sig[:, a:b], axis=1, keepdims=True)
    return sig


def _no_corners(signature: np.ndarray) -> ImageFeatures:
    return ImageFeatures(
        keypoints=np.zeros((0, 2), np.float32),
        descriptors=np.zeros((0, 36), np.uint8),
        signature=signature.astype(np.float32),
    )


def test_probed_candidates_are_the_brute_force_nearest_within_the_probed_lists(
    scenes,
) -> None:
    """Naive reference: rank the list centres by weighted distance, take the probed lists'
    images, the n_candidates nearest of them by brute force: the index's candidates (a query
    without corners has no visual-word candidates). Probing every list: the exhaustive ones."""
    rng = np.random.default_rng(7)
    n = 400
    params = replace(ALWAYS, n_candidates=5, index=replace(SMALL, lists=1.0, probe=4))
    idx = TourIndex(params)
    idx.add([scenes[k % len(scenes)] for k in range(n)], np.arange(n) // 10)
    idx.set_block_signatures(_random_signatures(rng, n))
    idx.set_weights([0.5, 0.1, 0.1, 0.1, 0.2])
    ivf = idx.inverted_file
    assert ivf is not None and ivf.n_lists == 20
    w = idx.weights
    found = 0
    for _ in range(30):
        q = _random_signatures(rng, 1)[0]
        sim = idx.query(_no_corners(q))
        to_centres = block_distances(q, ivf.centroids, BOUNDS) @ w
        probed = np.argsort(to_centres, kind="stable")[:4]
        rows = np.flatnonzero(np.isin(ivf.labels, probed))
        d = block_distances(q, idx.signatures, BOUNDS) @ w
        want = rows[np.argsort(d[rows], kind="stable")[:5]]
        assert set(sim.candidates.tolist()) == set(want.tolist())
        assert sim.n_scored == len(rows)
        found += int(np.argmin(d)) in sim.candidates  # the true nearest, if its list is probed
    assert found >= 15  # 4 of 20 lists probed, random data: most true nearest still found
    wide = idx.with_params(replace(params, index=replace(SMALL, lists=1.0, probe=20)))
    q = _random_signatures(rng, 1)[0]
    d = block_distances(q, wide.signatures, BOUNDS) @ w
    want = np.argsort(d, kind="stable")[:5]
    assert set(wide.query(_no_corners(q)).candidates.tolist()) == set(want.tolist())


def test_below_the_threshold_the_answers_are_the_exhaustive_ones_bit_for_bit(scenes) -> None:
    for changed in (None, CHANGED_WEIGHTS):
        default = TourIndex(EngineParams(changed_weights=changed))
        never = TourIndex(replace(NEVER, changed_weights=changed))
        just_above = TourIndex(replace(NEVER, changed_weights=changed, index_min_images=49))
        for idx in (default, never, just_above):
            idx.add(scenes, np.arange(len(scenes)) // 4)
            idx.set_weights([0.3, 0.1, 0.2, 0.1, 0.3])
            assert not idx.uses_inverted_files and idx.index_bytes_per_image == 0.0
        for q in [*scenes[:6], extract(scene(5000))]:
            answers = [idx.query_models(q) for idx in (default, never, just_above)]
            for a, b, c in zip(*answers, strict=True):
                assert a.n_scored == len(scenes)
                for name in ("image", "state", "best_image", "candidates"):
                    np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
                    np.testing.assert_array_equal(getattr(a, name), getattr(c, name))


def test_the_index_is_built_when_the_tour_reaches_the_threshold_and_kept_up(scenes) -> None:
    idx = TourIndex(replace(NEVER, index_min_images=30, index=SMALL))
    idx.add(scenes[:20], np.zeros(20, np.int64))
    assert not idx.uses_inverted_files
    idx.add(scenes[20:32], np.ones(12, np.int64))
    ivf = idx.inverted_file
    assert idx.uses_inverted_files and ivf is not None and ivf.n_trained == 32
    idx.add(scenes[32:40], np.full(8, 2))  # filed in the lists it has
    ivf = idx.inverted_file
    assert ivf is not None and ivf.n_trained == 32 and len(ivf.labels) == 40
    assert idx._words is not None and idx._words.n_images == 40
    idx.add(scenes[40:48] * 3, np.full(24, 3))  # doubled: trained afresh
    ivf = idx.inverted_file
    assert ivf is not None and ivf.n_trained == 64 and len(ivf.members) == 64
    assert idx.index_bytes_per_image > 0
    idx.set_weights([0.2, 0.2, 0.2, 0.2, 0.2])  # the lists serve any weights: kept
    assert idx.inverted_file is ivf


_BASE = [extract(scene(6000 + k)) for k in range(5)]


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 50), n_states=st.integers(1, 12))
def test_indexed_similarity_properties(seed: int, n: int, n_states: int) -> None:
    rng = np.random.default_rng(seed)
    base = _BASE
    idx = TourIndex(replace(ALWAYS, n_candidates=3))
    idx.add([base[int(rng.integers(len(base)))] for _ in range(n)], rng.integers(0, n_states, n))
    idx.set_block_signatures(
        idx.signatures + rng.normal(0, 0.05, size=idx.signatures.shape).astype(np.float32)
    )
    p = idx.params
    sim = idx.query(base[seed % len(base)], n_states=n_states + 1)
    assert sim.image.shape == (n,) and sim.state.shape == (n_states + 1,)
    assert np.all(sim.image >= p.floor) and np.all(sim.image <= 1)
    assert sim.image.max() == pytest.approx(1.0) and sim.state[n_states] == p.floor
    states = idx.states
    covered = set(states[sim.candidates].tolist())
    for s in range(n_states):
        members = np.flatnonzero(states == s)
        if s in covered:
            assert sim.best_image[s] in sim.candidates and states[sim.best_image[s]] == s
            assert sim.state[s] == pytest.approx(sim.image[members].max())
        else:  # no candidate: the floor
            assert sim.state[s] == p.floor and sim.best_image[s] == -1
            assert np.all(sim.image[members] == p.floor)


def test_a_stored_image_finds_itself_through_the_inverted_files(scenes) -> None:
    never = TourIndex(replace(NEVER, changed_weights=CHANGED_WEIGHTS))
    never.add(scenes, np.arange(len(scenes)) // 3)
    idx = never.with_params(replace(ALWAYS, changed_weights=CHANGED_WEIGHTS))
    assert idx.uses_inverted_files
    for i in (0, 17, 47):
        for sim in idx.query_models(scenes[i]):
            assert sim.candidates[0] == i and sim.image[i] == pytest.approx(1.0)
            assert sim.n_scored < len(scenes)
    back = idx.with_params(replace(NEVER, changed_weights=CHANGED_WEIGHTS))
    for a, b in zip(back.query_models(scenes[5]), never.query_models(scenes[5]), strict=True):
        np.testing.assert_array_equal(a.image, b.image)
    with pytest.raises(ValueError, match="re-extract"):
        from server.vision import FeatureParams

        idx.with_params(EngineParams(features=FeatureParams(descriptor="orb")))


def test_new_signatures_refile_the_lists_and_blank_tours_have_no_words(scenes) -> None:
    idx = TourIndex(ALWAYS)
    idx.add(scenes[:10], np.arange(10))
    words = idx._words
    before = idx.inverted_file
    idx.set_block_signatures(idx.signatures[::-1].copy())
    assert idx.inverted_file is not before and idx._words is words
    blank = TourIndex(ALWAYS)
    blank.add([_no_corners(f.signature) for f in scenes[:6]], np.arange(6))
    assert blank.uses_inverted_files and blank._words is None
    assert blank.query(_no_corners(scenes[2].signature)).candidates[0] == 2


def test_index_parameters_are_checked() -> None:
    with pytest.raises(ValueError, match="index_min_images"):
        EngineParams(index_min_images=0)
    for bad in ({"lists": 0.0}, {"probe": 0}, {"branching": 1}, {"stop": 0.0}):
        with pytest.raises(ValueError):
            IndexParams(**bad)
