"""Junctions from shared prefixes (server.belief.junctions): a naive reference for the shared
prefix, properties of the refinement, synthetic forks, and the tracker and the voting policy
on a refined tour."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from belief_testkit import edge, fine_of, location, observe
from hypothesis import given, settings
from hypothesis import strategies as st

from server.belief.junctions import (
    Junction,
    JunctionParams,
    PairError,
    _prefix_of,
    find_junctions,
    junction_name,
    refine,
    shared_prefix,
)
from server.belief.model import Action, ActionKind, BeliefModel
from server.belief.tracker import Tracker, TrackerParams
from server.domain import Edge, TourGraph
from server.policy.costs import cost_to_goal
from server.policy.voting import decide


def naive_prefix(
    error: np.ndarray, max_error: float, max_step: int, max_stall: int, max_skip: int
) -> tuple[int, int, float] | None:
    """Every alignment by brute force (all step sequences): the furthest last match, then the
    least summed error; ``(i*, j*, summed error)``."""
    if not error[0, 0] <= max_error:
        return None
    n_a, n_b = error.shape
    best: tuple[int, float, int] = (0, float(error[0, 0]), 0)  # (j*, cost, i*)
    for steps in itertools.product(range(max_step + 1), repeat=n_b - 1):
        i, stall, miss, total = 0, 0, 0, float(error[0, 0])
        for j, step in enumerate(steps, start=1):
            i += step
            stall = stall + 1 if step == 0 else 0
            if i >= n_a or stall > max_stall:
                break
            miss = miss + 1 if error[i, j] > max_error else 0
            if miss > max_skip:
                break
            total += float(error[i, j])
            if miss == 0 and (j, -total) > (best[0], -best[1]):
                best = (j, total, i)
    return best[2], best[0], best[1]


@settings(max_examples=150, deadline=None)
@given(
    st.integers(1, 6),
    st.integers(1, 6),
    st.integers(1, 2),
    st.integers(0, 2),
    st.integers(0, 2),
    st.floats(0.2, 0.9),
    st.integers(0, 2**31),
)
def test_shared_prefix_equals_naive_reference(
    n_a: int, n_b: int, max_step: int, max_stall: int, max_skip: int, thr: float, seed: int
) -> None:
    error = np.random.default_rng(seed).random((n_a, n_b))
    got = shared_prefix(error, thr, max_step=max_step, max_stall=max_stall, max_skip=max_skip)
    want = naive_prefix(error, thr, max_step, max_stall, max_skip)
    if want is None:
        assert got is None
        return
    assert got is not None
    i, j, mapping = got
    assert j == want[1]
    assert mapping.shape == (j + 1,) and mapping[0] == 0 and mapping[-1] == i
    steps = np.diff(mapping)
    assert np.all((steps >= 0) & (steps <= max_step))
    assert error[i, j] <= thr
    assert error[mapping, np.arange(j + 1)].sum() == pytest.approx(want[2])


# --- synthetic tours: images carry a "where" code; equal codes look alike --------------------

P0 = JunctionParams(split_back_m=0.0)  # the junction at the last shared image


def coded_edge(source: int, target: int, codes: list[int], where: dict[int, int]) -> Edge:
    e = edge(source, target, len(codes))
    for image_id, c in zip(e.image_ids, codes, strict=True):
        where[image_id] = c
    return e


def similarity_of(where: dict[int, int]) -> PairError:
    """The error of two images: 0.3 when they show the same place (equal codes), else 0.8 (the
    default threshold is 0.45)."""

    def err(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        ca = np.array([where[int(i)] for i in a])
        cb = np.array([where[int(i)] for i in b])
        return np.where(ca[:, None] == cb[None, :], 0.3, 0.8)

    return err


def fork(shared: int, rest_a: int, rest_b: int, *, slow_b: bool = False) -> tuple[TourGraph, dict]:
    """S(0) -> A(1) and S(0) -> B(2), both down the same ``shared`` images first (b taught at
    half speed there: every image twice), plus the way back A -> S."""
    where: dict[int, int] = {}
    locs = (location("S"), location("A"), location("B"))
    corridor = list(range(shared))
    b_start = [c for c in corridor for _ in range(2)] if slow_b else corridor
    a = coded_edge(0, 1, corridor + list(range(100, 100 + rest_a)), where)
    b = coded_edge(0, 2, b_start + list(range(200, 200 + rest_b)), where)
    back = coded_edge(1, 0, list(range(300, 300 + rest_a + shared)), where)
    return TourGraph(locs, (a, b, back)), where


def test_a_fork_becomes_one_junction() -> None:
    graph, where = fork(12, 10, 8)
    found = find_junctions(graph, similarity_of(where), P0)
    assert len(found) == 1
    j = found[0]
    assert (j.keep_first, j.other_first) == (
        graph.edges[0].image_ids[0],
        graph.edges[1].image_ids[0],
    )
    assert (j.keep_shared, j.other_shared) == (12, 12)
    assert j.mapping == tuple(range(12))
    r = refine(graph, found)
    g = r.graph
    assert [loc.name for loc in g.locations] == ["S", "A", "B", junction_name(1)]
    assert g.locations[3].image_ids == (graph.edges[0].image_ids[11],)  # the last shared view
    assert g.locations[3].junction
    assert [(e.source, e.target, e.n_images) for e in g.edges] == [
        (0, 3, 11),
        (3, 1, 10),
        (3, 2, 8),
        (1, 0, 22),
    ]
    assert r.junctions == (3,) and r.applied == (True,)
    assert r.mapped == dict(
        zip(graph.edges[1].image_ids[:12], graph.edges[0].image_ids[:12], strict=True)
    )


def test_the_junction_goes_split_back_m_before_the_paths_part() -> None:
    """0.5 m at 0.125 m per image: 4 images back; both remainders start with shared views."""
    graph, where = fork(12, 10, 8)
    (j,) = find_junctions(graph, similarity_of(where))
    assert (j.keep_shared, j.other_shared) == (8, 8) and j.mapping == tuple(range(8))
    g = refine(graph, [j]).graph
    to_a, to_b = g.edges[1], g.edges[2]
    assert [where[i] for i in to_a.image_ids[:4]] == [8, 9, 10, 11]
    assert [where[i] for i in to_b.image_ids[:4]] == [8, 9, 10, 11]
    assert where[g.locations[3].image_ids[0]] == 7


def test_a_slower_teaching_run_still_shares_its_prefix() -> None:
    graph, where = fork(10, 6, 6, slow_b=True)
    (j,) = find_junctions(graph, similarity_of(where), P0)
    assert (j.keep_shared, j.other_shared) == (10, 20)
    assert j.mapping == tuple(k // 2 for k in range(20))


def test_no_junction_when_paths_differ_from_the_first_image() -> None:
    where: dict[int, int] = {}
    a = coded_edge(0, 1, list(range(20)), where)
    b = coded_edge(0, 2, [999, *list(range(1, 20))], where)
    graph = TourGraph((location("S"), location("A"), location("B")), (a, b))
    assert find_junctions(graph, similarity_of(where), P0) == []


def test_no_junction_for_a_short_share_or_a_path_that_does_not_go_on() -> None:
    p = JunctionParams(min_shared=8, min_remainder=3, split_back_m=0.0)
    graph, where = fork(7, 10, 10)  # shares 7 < 8
    assert find_junctions(graph, similarity_of(where), p) == []
    graph, where = fork(8, 10, 10)  # 8 images, but 0.875 m < 1 m
    assert find_junctions(graph, similarity_of(where), p) == []
    graph, where = fork(10, 10, 2)  # b goes on for 2 < 3
    assert find_junctions(graph, similarity_of(where), p) == []


def test_three_paths_down_one_corridor_give_two_junctions_in_a_row() -> None:
    where: dict[int, int] = {}
    locs = tuple(location(x) for x in "SABC")
    a = coded_edge(0, 1, [*list(range(20)), 100, 101, 102, 103], where)
    b = coded_edge(0, 2, [*list(range(20)), 200, 201, 202, 203], where)
    c = coded_edge(0, 3, [*list(range(10)), 300, 301, 302, 303], where)
    graph = TourGraph(locs, (a, b, c))
    found = find_junctions(graph, similarity_of(where), P0)
    assert [(j.keep_shared, j.other_shared) for j in found] == [(20, 20), (10, 10)]
    g = refine(graph, found).graph
    j1, j2 = 4, 5
    assert sorted((e.source, e.target, e.n_images) for e in g.edges) == sorted(
        [(0, j2, 9), (j2, j1, 9), (j1, 1, 4), (j1, 2, 4), (j2, 3, 4)]
    )


def test_a_junction_whose_edges_are_gone_is_skipped() -> None:
    graph, where = fork(12, 10, 8)
    stale = Junction(-5, graph.edges[1].image_ids[0], 12, 12, tuple(range(12)))
    (good,) = find_junctions(graph, similarity_of(where), P0)
    r = refine(graph, [stale, good])
    assert r.applied == (False, True)
    assert r.graph.n_locations == 4
    assert refine(graph, []).graph is graph


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(st.integers(0, 14), st.integers(1, 12)), min_size=2, max_size=4),
    st.integers(0, 3),
)
def test_refinement_keeps_every_image_once_or_mapped(
    paths: list[tuple[int, int]], n_back: int
) -> None:
    """Edges from S down one corridor, each sharing its first ``shared`` images, then its own
    ``rest``; with taught poses and entropies that must follow their images."""
    where: dict[int, int] = {}
    locs = tuple(location(f"p{k}") for k in range(len(paths) + 1))
    es = [
        coded_edge(0, k + 1, list(range(s)) + [1000 * (k + 1) + i for i in range(r)], where)
        for k, (s, r) in enumerate(paths)
    ]
    es += [
        coded_edge(k + 1, 0, [50_000 + 100 * k + i for i in range(5)], where) for k in range(n_back)
    ]
    base = TourGraph(locs, tuple(es))
    ids = base.image_ids
    graph = TourGraph(
        locs,
        tuple(es),
        image_pose=np.column_stack([ids, -ids, ids * 0.5]).astype(np.float64),
        image_entropy=ids.astype(np.float64) / 7,
    )
    p = JunctionParams(min_shared=2, min_shared_m=0.0, min_remainder=1, split_back_m=0.0)
    found = find_junctions(graph, similarity_of(where), p)
    r = refine(graph, found)
    g = r.graph
    assert all(r.applied) and len(r.junctions) == len(found)
    kept = [int(i) for i in g.image_ids]
    assert len(kept) == len(set(kept))
    assert set(kept).isdisjoint(r.mapped)
    assert set(kept) | set(r.mapped) == {int(i) for i in ids}
    assert all(v in set(kept) for v in r.mapped.values())
    assert all(where[k] == where[v] for k, v in r.mapped.items())  # mapped onto a look-alike
    # lengths add up; places keep their indices; one place and one edge per junction
    assert g.n_images + len(r.mapped) == graph.n_images
    assert g.n_locations == graph.n_locations + len(found)
    assert g.n_edges == graph.n_edges + len(found)
    assert g.locations[: graph.n_locations] == graph.locations
    assert g.image_pose is not None and g.image_entropy is not None
    np.testing.assert_array_equal(g.image_pose[:, 0], g.image_ids)
    np.testing.assert_array_equal(g.image_entropy, g.image_ids / 7)
    for e in g.edges:  # every refined edge is a contiguous piece of a taught one
        (orig,) = [o for o in graph.edges if e.image_ids[0] in o.image_ids]
        lo = orig.image_ids.index(e.image_ids[0])
        assert orig.image_ids[lo : lo + e.n_images] == e.image_ids
        np.testing.assert_array_equal(e.timestamps, orig.timestamps[lo : lo + e.n_images])
    # a junction never forms where no two paths share min_shared images
    shares = sorted(s for s, _ in paths)
    if len(shares) < 2 or shares[-2] < 2:
        assert found == []
    # and found on the refined graph: nothing more
    assert find_junctions(g, similarity_of(where), p) == []


# --- the belief and the policy on a refined tour --------------------------------------------


def test_tracker_and_voting_policy_drive_through_a_junction() -> None:
    """Drive S -> B on the refined fork: the belief follows the shared edge, the junction, the
    remainder; the policy says Navigate on the shared edge, picks B's remainder at the junction
    (not A's), and the goal says DoNothing."""
    graph, where = fork(12, 10, 8)
    g = refine(graph, find_junctions(graph, similarity_of(where), P0)).graph
    model = BeliefModel(g)
    goal = 2
    costs = cost_to_goal(g, goal)
    assert math.isfinite(costs[0]) and costs[3] < costs[0]
    tracker = Tracker(model, TrackerParams(smoother_lag=0))
    rng = np.random.default_rng(3)
    L = g.n_locations
    truth = [0] * 3 + [fine_of(g, 0, k) for k in range(11)] + [3] * 3
    truth += [fine_of(g, 2, k) for k in range(8)] + [goal] * 3
    action = Action.rotate(0)
    decisions = []
    for true_fine in truth:
        lik = observe(g, true_fine, rng)
        s = tracker.step(action, lik, v=0.25, dt=0.5)
        d = decide(g, tracker.belief, goal, costs)
        decisions.append((true_fine, int(s.map_state), d.action))
        action = d.action if d.action.kind is not ActionKind.DO_NOTHING else Action.do_nothing()
    on_shared = [d for t, _, d in decisions[3:14] if t >= L]
    assert sum(a.kind is ActionKind.NAVIGATE and a.edge == 0 for a in on_shared) >= 8
    at_junction = [a for t, _, a in decisions if t == 3]
    assert any(a.kind is ActionKind.ROTATE_AND_FIND_EDGE and a.edge == 2 for a in at_junction)
    assert not any(a.edge == 1 for _, _, a in decisions if a.kind is not ActionKind.EXPLORE)
    _final_true, final_map, final_action = decisions[-1]
    assert final_map == goal and final_action.kind is ActionKind.DO_NOTHING


@pytest.mark.parametrize(
    "bad",
    [
        dict(max_error=0.0),
        dict(min_shared=0),
        dict(max_skip=-1),
        dict(max_step=0),
        dict(split_back_m=1.0),
    ],
)
def test_params_are_checked(bad: dict) -> None:
    with pytest.raises(ValueError):
        JunctionParams(**bad)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 90), st.integers(1, 90), st.integers(0, 90), st.integers(0, 2**31))
def test_asking_for_a_growing_block_gives_the_whole_matrix_answer(
    n_a: int, n_b: int, shared: int, seed: int
) -> None:
    """The search asks the engine for the first 32, 64, ... images only while an alignment is
    alive; the answer is the one of the whole matrix."""
    rng = np.random.default_rng(seed)
    error = 0.6 + 0.2 * rng.random((n_a, n_b))  # no match but the planted ones
    i = 0
    for j in range(min(shared, n_b)):  # a matching alignment along the first `shared` images
        error[i, j] = 0.3
        i = min(n_a - 1, i + int(rng.integers(0, 3)))
    a, b = edge(0, 1, n_a), edge(0, 2, n_b)
    full = {
        (x, y): error[p, q] for p, x in enumerate(a.image_ids) for q, y in enumerate(b.image_ids)
    }
    asked: list[tuple[int, int]] = []

    def err(ids_a: np.ndarray, ids_b: np.ndarray) -> np.ndarray:
        asked.append((len(ids_a), len(ids_b)))
        return np.array([[full[(int(x), int(y))] for y in ids_b] for x in ids_a])

    p = JunctionParams()
    got = _prefix_of(a, b, err, p)
    want = shared_prefix(error, p.max_error, max_step=2, max_stall=2, max_skip=1)
    if want is None:
        assert got is None
    else:
        assert got is not None
        assert got[:2] == want[:2]
        np.testing.assert_array_equal(got[2], want[2])
    if shared < 20:
        assert asked == [(min(n_a, 2 * (min(n_b, 32) - 1) + 1), min(n_b, 32))]
