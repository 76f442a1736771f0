"""The tour runtime's appearance inputs: which states share a place, and the change evidence
a frame gives the tracker (server/navigation/runtime.py)."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
from navigation_testkit import FEATURES, GRAPH, runtime

from server.navigation.params import two_appearance_models
from server.navigation.runtime import related_states
from server.vision.features import extract
from server.vision.index import CHANGED_WEIGHTS, EngineParams
from server.vision.learning import learn_weights


def _places(state: int) -> set[int]:
    """The places a state touches, the naive way."""
    if state < GRAPH.n_locations:
        return {state}
    e = GRAPH.edges[state - GRAPH.n_locations]
    return {e.source, e.target}


def test_related_states_are_those_that_share_a_place() -> None:
    rel = related_states(GRAPH)
    assert rel.shape == (GRAPH.n_states, GRAPH.n_states)
    for a, b in itertools.product(range(GRAPH.n_states), repeat=2):
        assert rel[a, b] == bool(_places(a) & _places(b)), (a, b)
    assert np.array_equal(rel, rel.T) and rel.diagonal().all()
    assert rel[3].sum() == 1  # D has no edges: related to itself only


def test_a_taught_view_is_familiar_and_a_single_model_gives_no_familiarity() -> None:
    from vision_testkit import scene

    two = runtime(engine=two_appearance_models())
    assert two.params.engine.changed_weights == CHANGED_WEIGHTS
    two.index.set_weights(learn_weights(two.index, params=two.params.engine))
    taught = FEATURES[7]
    sims, lik = two.observe(taught)
    assert lik.shape == (2, GRAPH.n_fine)
    assert two.familiarity(sims) == 0.0
    unseen = [two.familiarity(two.observe(extract(scene(s)))[0]) for s in range(5000, 5010)]
    assert all(0.0 <= q <= 1.0 for q in unseen) and np.mean(unseen) > 0.2  # unseen scenes
    one = runtime(engine=replace(EngineParams(), changed_weights=None))
    assert np.isnan(one.familiarity(one.observe(taught)[0]))


def test_error_levels_are_kept_until_the_weights_change() -> None:
    rt = runtime()
    first = rt.error_levels()
    assert rt.error_levels() is first  # computed once
    rt.index.set_weights(np.r_[1.0, np.zeros(len(rt.index.weights) - 1)])
    again = rt.error_levels()
    assert again is not first and len(again) == len(first)
