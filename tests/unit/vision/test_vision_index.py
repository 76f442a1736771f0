"""The two-pass query: ranking, candidates, normalisation, learned weights."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vision_testkit import index_of, scene, shifted

from server.vision import EngineParams, TourIndex, default_weights, extract, learn_weights
from server.vision.features import signature_blocks
from server.vision.index import block_distances

N_SCENES = 12


@pytest.fixture(scope="module")
def tour() -> tuple[TourIndex, list[np.ndarray]]:
    images = [scene(s) for s in range(N_SCENES)]
    states = [s // 3 for s in range(N_SCENES)]  # 4 states of 3 images
    idx, _ = index_of(images, states)
    return idx, images


def test_identical_image_ranks_first_with_similarity_one(tour) -> None:
    idx, images = tour
    for i in (0, 5, 11):
        sim = idx.query(extract(images[i]))
        assert int(np.argmax(sim.image)) == i
        assert sim.image[i] == pytest.approx(1.0)
        assert sim.candidates[0] == i


@pytest.mark.parametrize(
    "change",
    [
        lambda im: shifted(im, 12),
        lambda im: cv2.resize(cv2.resize(im, (400, 300)), (320, 240))[10:230, 12:310],
        lambda im: cv2.convertScaleAbs(im, alpha=1.3, beta=15),
        lambda im: cv2.convertScaleAbs(im, alpha=0.7),
        lambda im: cv2.GaussianBlur(im, (5, 5), 1.0),
    ],
    ids=["shifted", "rescaled-cropped", "brighter", "darker", "blurred"],
)
def test_changed_copy_still_ranks_first(tour, change) -> None:
    idx, images = tour
    for i in (1, 7, 10):
        sim = idx.query(extract(change(images[i])))
        assert int(np.argmax(sim.image)) == i


def test_every_state_is_among_the_candidates() -> None:
    images = [scene(100 + s) for s in range(30)]
    states = [s % 10 for s in range(30)]  # interleaved states
    idx, _ = index_of(images, states, EngineParams(n_candidates=2))
    sim = idx.query(extract(scene(500)))
    assert set(states) <= {states[c] for c in sim.candidates}
    for s in range(10):
        assert states[sim.best_image[s]] == s


def test_first_pass_equals_a_naive_loop(tour) -> None:
    idx, _ = tour
    idx.set_weights([0.1, 0.2, 0.3, 0.15, 0.25])
    q = extract(scene(77))
    fast = idx.signature_distances(q)
    bounds = np.concatenate([[0], np.cumsum([n for _, n in signature_blocks()])])
    naive = np.zeros(idx.n_images)
    for i in range(idx.n_images):
        x = idx.features(i).signature
        for t in range(len(bounds) - 1):
            a, b = bounds[t], bounds[t + 1]
            naive[i] += idx.weights[t] * float(np.sum((q.signature[a:b] - x[a:b]) ** 2))
    np.testing.assert_allclose(fast, naive, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(
        naive, block_distances(q.signature, idx.signatures, bounds) @ idx.weights, rtol=1e-6
    )
    idx.set_weights(default_weights())


def _random_index(seed: int, n: int, n_states: int) -> TourIndex:
    rng = np.random.default_rng(seed)
    base = [extract(scene(1000 + k)) for k in range(4)]
    feats = [base[int(rng.integers(4))] for _ in range(n)]
    idx = TourIndex(EngineParams(n_candidates=3))
    idx.add(feats, rng.integers(0, n_states, size=n))
    sig = idx.signatures + rng.normal(0, 0.05, size=idx.signatures.shape).astype(np.float32)
    idx.set_block_signatures(sig)
    return idx


_BASE_QUERIES = [extract(scene(2000 + k)) for k in range(3)]


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 40), n_states=st.integers(1, 8))
def test_similarity_properties(seed: int, n: int, n_states: int) -> None:
    idx = _random_index(seed, n, n_states)
    extra = 2  # states without images get the floor
    sim = idx.query(_BASE_QUERIES[seed % 3], n_states=n_states + extra)
    p = idx.params
    assert sim.image.shape == (n,) and sim.state.shape == (n_states + extra,)
    assert np.all(sim.image > 0) and np.all(sim.image <= 1)
    assert np.all(sim.state > 0) and np.all(sim.state <= 1)
    assert sim.image.max() == pytest.approx(1.0)
    states = idx.states
    for s in range(n_states + extra):
        members = np.flatnonzero(states == s)
        if len(members) == 0:
            assert sim.state[s] == p.floor and sim.best_image[s] == -1
        else:
            assert sim.state[s] == pytest.approx(sim.image[members].max())
            assert sim.best_image[s] in members
            assert sim.image[sim.best_image[s]] == pytest.approx(sim.state[s])
    outside = np.setdiff1d(np.arange(n), sim.candidates)
    for i in outside:  # half the smallest candidate similarity of its state, floored
        same = [c for c in sim.candidates if states[c] == states[i]]
        expect = max(p.outside_factor * min(sim.image[c] for c in same), p.floor)
        assert sim.image[i] == pytest.approx(expect)


def test_incremental_add_equals_bulk_add() -> None:
    feats = [extract(scene(300 + k)) for k in range(9)]
    states = [0, 0, 1, 1, 1, 2, 0, 3, 3]
    bulk = TourIndex()
    bulk.add(feats, states)
    inc = TourIndex()
    for k in range(0, 9, 2):
        inc.add(feats[k : k + 2], states[k : k + 2])
    q = extract(scene(301))
    a, b = bulk.query(q), inc.query(q)
    np.testing.assert_allclose(a.image, b.image)
    np.testing.assert_array_equal(a.best_image, b.best_image)
    assert inc.n_images == 9 and inc.bytes_per_image > 0


def test_empty_index_and_errors() -> None:
    idx = TourIndex()
    sim = idx.query(extract(scene(1)), n_states=3)
    assert sim.image.shape == (0,) and np.all(sim.state == idx.params.floor)
    with pytest.raises(ValueError, match="one per image"):
        idx.add([extract(scene(1))], [0, 1])
    idx.add([extract(scene(1))], [2])
    with pytest.raises(ValueError, match="n_states"):
        idx.query(extract(scene(1)), n_states=2)
    from server.vision import FeatureParams

    with pytest.raises(ValueError, match="re-extract"):
        idx.add([extract(scene(1), FeatureParams(descriptor="orb"))], [0])


def test_geometric_check_keeps_the_identical_image_first(tour) -> None:
    idx, images = tour
    geo = TourIndex(EngineParams(geometric=True))
    geo.add([idx.features(i) for i in range(idx.n_images)], idx.states)
    sim = geo.query(extract(shifted(images[4], 8)))
    assert int(np.argmax(sim.image)) == 4


def test_geometric_inliers_single_out_the_same_scene(tour) -> None:
    idx, images = tour
    everything = np.arange(idx.n_images)
    for i in (1, 4, 7):
        inliers = idx.geometric_inliers(extract(shifted(images[i], 10)), everything)
        assert inliers.shape == (idx.n_images,) and inliers.dtype == np.int64
        assert inliers[i] >= 50
        # RANSAC on mutual nearest neighbours of unrelated scenes still finds a few
        assert np.delete(inliers, i).max() <= 12
    with pytest.raises(IndexError, match="not all in index"):
        idx.geometric_inliers(extract(images[0]), [idx.n_images])


def test_learn_weights_defaults_for_small_tours() -> None:
    sig = np.random.default_rng(0).normal(size=(5, 600)).astype(np.float32)
    np.testing.assert_allclose(learn_weights(sig, [0, 0, 1, 1, 2]), default_weights())
    one_per_state = np.random.default_rng(0).normal(size=(40, 600))
    np.testing.assert_allclose(learn_weights(one_per_state, np.arange(40)), default_weights())


def test_learn_weights_finds_the_informative_block() -> None:
    rng = np.random.default_rng(1)
    sizes = [n for _, n in signature_blocks()]
    n_states, per = 20, 5
    states = np.repeat(np.arange(n_states), per)
    blocks = []
    for t, size in enumerate(sizes):
        if t == 2:  # desc_mean: a per-state prototype plus small noise
            proto = rng.normal(size=(n_states, size))
            b = proto[states] + rng.normal(0, 0.1, size=(len(states), size))
        else:  # pure noise
            b = rng.normal(size=(len(states), size))
        blocks.append(b / np.linalg.norm(b, axis=1, keepdims=True))
    w = learn_weights(np.concatenate(blocks, axis=1), states)
    assert w.shape == (5,) and w.sum() == pytest.approx(1.0) and np.all(w >= 0)
    assert w[2] > 0.2 > default_weights()[2]  # the informative block gained weight


def test_query_models_equals_a_query_under_each_models_weights(tour) -> None:
    from server.vision.index import CHANGED_WEIGHTS

    one, images = tour
    idx = TourIndex(EngineParams(changed_weights=CHANGED_WEIGHTS))
    idx.add([one.features(i) for i in range(one.n_images)], one.states)
    idx.set_weights(one.weights)
    models = idx.model_weights()
    assert len(models) == 2 and models[1][-1] == 1.0  # the tour's, then the change-robust
    frame = extract(shifted(images[3], 5))
    both = idx.query_models(frame)
    for w, sim in zip(models, both, strict=True):
        alone = TourIndex(idx.params)
        alone.add([idx.features(i) for i in range(idx.n_images)], idx.states)
        alone.set_weights(w)
        ref = alone.query(frame)
        np.testing.assert_allclose(sim.image, ref.image, rtol=1e-5)
        np.testing.assert_array_equal(sim.candidates, ref.candidates)
    np.testing.assert_allclose(both[0].image, idx.query(frame).image, rtol=1e-5)
    single = TourIndex(EngineParams(changed_weights=None))
    assert len(single.model_weights()) == 1


def test_block_distances_match_the_naive_reference(tour) -> None:
    idx, images = tour
    frame = extract(images[2])
    bounds = np.concatenate([[0], np.cumsum([n for _, n in signature_blocks()])])
    naive = block_distances(frame.signature, idx.signatures, bounds)
    np.testing.assert_allclose(idx.block_distances(frame), naive, atol=1e-4)


def test_best_error_is_the_raw_error_of_the_best_match(tour) -> None:
    """``best_error`` is e before normalisation: ~0 for a stored image, larger for a changed
    copy, larger still for an unseen scene; the naive reference is e over every image."""
    idx, images = tour
    p = idx.params
    same = idx.query(extract(images[4]))
    changed = idx.query(extract(cv2.GaussianBlur(images[4], (7, 7), 2.0)))
    unseen_frame = extract(scene(900))
    unseen = idx.query(unseen_frame)
    assert same.best_error == pytest.approx(0.0, abs=1e-3)  # float32 signatures
    assert same.best_error < changed.best_error < unseen.best_error
    every = np.arange(idx.n_images)
    naive = p.feature_weight * idx.feature_errors(unseen_frame, every) + p.signature_weight * (
        idx.signature_distances(unseen_frame).astype(np.float64)
    )
    assert unseen.best_error == pytest.approx(float(naive.min()), rel=1e-5)


def test_error_levels_score_each_image_against_the_unrelated_states_only(tour) -> None:
    idx, _ = tour  # 4 states of 3 images
    levels = idx.error_levels()
    assert len(levels) == N_SCENES and np.all(np.diff(levels) >= 0)
    assert np.all(np.isfinite(levels)) and levels[0] > 0.0  # never an image against itself
    # the naive reference for one image: its best e among the other states' images
    p = idx.params
    frame = idx.features(4)
    others = np.flatnonzero(idx.states != idx.states[4])
    e = p.feature_weight * idx.feature_errors(frame, others) + p.signature_weight * (
        idx.signature_distances(frame)[others].astype(np.float64)
    )
    assert np.isclose(levels, float(e.min()), rtol=1e-5).any()
    # relating every state to its neighbours leaves fewer, worse matches
    related = np.eye(4, dtype=bool) | np.eye(4, k=1, dtype=bool) | np.eye(4, k=-1, dtype=bool)
    apart = idx.error_levels(related)
    assert len(apart) == N_SCENES and np.median(apart) >= np.median(levels)
    assert len(idx.error_levels(np.ones((4, 4), bool))) == 0  # nothing unrelated
    assert len(idx.error_levels(n_probe=5)) == 5
    with pytest.raises(ValueError):
        idx.error_levels(np.eye(2, dtype=bool))
