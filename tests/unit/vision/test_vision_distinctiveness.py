"""Distinctiveness (seed 000): the entropy of an image's retrieval scores against the tour."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vision_testkit import index_of, scene, shifted

from server.domain import Edge, Location, TourGraph
from server.navigation.runtime import image_layout
from server.vision.distinctiveness import (
    DistinctivenessParams,
    image_entropy,
    retrieval_entropy,
    sample_images,
    spot_mask,
)


def _edge(source: int, target: int, ids: range, *, v: float = 0.5, dt: float = 0.2) -> Edge:
    n = len(ids)
    return Edge(source, target, tuple(ids), np.arange(n) * dt, np.full(n, v), np.zeros(n))


def test_a_duplicated_place_is_more_ambiguous_than_a_unique_one() -> None:
    """Places A, B, C, D (two spin views each) and one edge A -> B. D's views are A's views
    again (a look-alike room): A's and D's images get a higher entropy than B's and C's."""
    views = {"A": (1, 2), "B": (3, 4), "C": (5, 6), "D": (1, 2)}
    images, states = [], []
    for k, name in enumerate("ABCD"):
        for seed in views[name]:
            images.append(shifted(scene(seed), 3 * k))  # not pixel-identical
            states.append(k)
    edge_scenes = [scene(100 + k) for k in range(12)]
    images += edge_scenes
    states += [4] * len(edge_scenes)
    locations = tuple(Location(n, (2 * k, 2 * k + 1)) for k, n in enumerate("ABCD"))
    graph = TourGraph(locations, (_edge(0, 1, range(8, 20)),))
    assert graph.image_state.tolist() == states
    index, feats = index_of(images, states)
    h = image_entropy(index, feats, image_layout(graph))
    assert h.shape == (graph.n_images,) and np.all(h >= 0)
    duplicated = [h[0], h[1], h[6], h[7]]
    unique = [h[2], h[3], h[4], h[5]]
    assert min(duplicated) > max(unique), h[:8]
    assert min(duplicated) > 0.5 * math.log(2)  # about two equal peaks


def _naive_entropy(
    scores: np.ndarray, spot: np.ndarray, state: np.ndarray, sharpness: float
) -> np.ndarray:
    out = []
    for s_row, spot_row in zip(scores, spot, strict=True):
        bins = [max([s for s, m in zip(s_row, spot_row, strict=True) if m], default=0.0)]
        for x in sorted(set(state.tolist())):
            far = [s for s, m, t in zip(s_row, spot_row, state, strict=True) if t == x and not m]
            bins.append(max(far, default=0.0))
        p = np.array(bins) ** sharpness
        p = p / p.sum() if p.sum() > 0 else p
        out.append(-sum(q * math.log(q) for q in p if q > 0))
    return np.array(out)


@settings(max_examples=60, deadline=None)
@given(
    data=st.data(),
    m=st.integers(1, 4),
    sizes=st.lists(st.integers(1, 4), min_size=1, max_size=5),
    sharpness=st.sampled_from([1.0, 2.0, 4.0]),
)
def test_retrieval_entropy_matches_a_naive_loop(
    data: st.DataObject, m: int, sizes: list[int], sharpness: float
) -> None:
    state = np.repeat(np.arange(len(sizes)), sizes)
    n = len(state)
    scores = np.array(
        data.draw(
            st.lists(st.lists(st.floats(0, 1), min_size=n, max_size=n), min_size=m, max_size=m)
        )
    )
    spot = np.array(
        data.draw(st.lists(st.lists(st.booleans(), min_size=n, max_size=n), min_size=m, max_size=m))
    )
    starts = np.flatnonzero(np.concatenate([[True], state[1:] != state[:-1]]))
    h = retrieval_entropy(scores, spot, starts, sharpness=sharpness)
    np.testing.assert_allclose(h, _naive_entropy(scores, spot, state, sharpness), atol=1e-9)
    assert np.all(h >= -1e-12) and np.all(h <= math.log(len(sizes) + 1) + 1e-9)
    # scale free: scores times a constant give the same entropies
    h2 = retrieval_entropy(3.0 * scores, spot, starts, sharpness=sharpness)
    np.testing.assert_allclose(h2, h, atol=1e-9)


def test_the_spot_is_the_neighbourhood_along_the_edge_and_at_the_places() -> None:
    """A -> B, 2 m long; with ``near_m`` 0.5 the spot of A's spin image is itself and the
    first 0.5 m of the edge, the spot of an edge image its neighbours within 0.5 m; the
    middle of the edge is near no place. Checked against a loop over pairs."""
    graph = TourGraph((Location("A", (0,)), Location("B", (1,))), (_edge(0, 1, range(2, 23)),))
    layout = image_layout(graph)
    along = layout.along
    ns, nt = layout.near_places(0.5)
    assert along[2:].tolist() == pytest.approx(np.arange(21) * 0.1)
    spot = spot_mask(np.arange(graph.n_images), graph.image_state, along, ns, nt, 0.5)
    naive = np.zeros_like(spot)
    for i in range(graph.n_images):
        for k in range(graph.n_images):
            same_state = graph.image_state[i] == graph.image_state[k]
            close = same_state and abs(along[i] - along[k]) <= 0.5
            places = {ns[i], nt[i]} - {-1}
            naive[i, k] = close or bool(places & ({ns[k], nt[k]} - {-1}))
    np.testing.assert_array_equal(spot, naive)
    assert spot[0].tolist()[:8] == [True, False, True, True, True, True, True, True]
    assert not spot[0, 12] and spot[1, -1] and not spot[12, 0]


def test_edge_images_are_sampled_by_distance_and_the_others_interpolated() -> None:
    graph = TourGraph((Location("A", (0,)), Location("B", (1,))), (_edge(0, 1, range(2, 23)),))
    picks = sample_images(image_layout(graph), 0.5)
    assert picks.tolist() == [0, 1, 2, 7, 12, 17, 22]


def test_a_tour_of_places_only_samples_its_spin_images() -> None:
    """A tour with one place and no path yet (the first mark of a teaching run) has no edge
    images: every spin image is sampled and nothing else."""
    graph = TourGraph((Location("A", (0, 1, 2)),), ())
    assert sample_images(image_layout(graph), 0.5).tolist() == [0, 1, 2]


def test_parameters_are_checked() -> None:
    with pytest.raises(ValueError, match="sharpness"):
        DistinctivenessParams(sharpness=0.0)
