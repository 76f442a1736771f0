"""When to ask (server.belief.questions): the two detectors against naive references written
from their docstrings, properties over random belief sequences, and the parameter checks."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.belief.questions import (
    NewPathDetector,
    QuestionParams,
    SamePlaceDetector,
    Traversal,
)

N_LOC = 3  # locations 0..2, then edges 3..4


def mass(state: int, p: float = 1.0, n_states: int = 5) -> np.ndarray:
    """All of ``p`` at ``state``, the rest spread evenly over the others."""
    m = np.full(n_states, (1.0 - p) / (n_states - 1))
    m[state] = p
    return m


def naive_same_place(
    seq: list[tuple[int | None, np.ndarray]], params: QuestionParams, start: int, skip: set[int]
) -> list[tuple[int, int]]:
    """(frame, location) at which a question is due: the frame ends a run of at least
    ``same_place_steps`` frames localised at the same location (not ``start``) with at least
    ``same_place_mass`` there; skipped locations are never asked."""
    out = []
    for t, (loc, _) in enumerate(seq):
        if loc is None or not 0 <= loc < N_LOC or loc == start or loc in skip:
            continue
        run = 0
        for u in range(t, -1, -1):
            lu, mu = seq[u]
            if lu == loc and mu[loc] >= params.same_place_mass:
                run += 1
            else:
                break
        if run >= params.same_place_steps:
            out.append((t, loc))
    return out


states = st.one_of(st.none(), st.integers(0, 4))
probs = st.sampled_from([0.3, 0.85, 0.95, 1.0])


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.tuples(states, probs), min_size=1, max_size=30),
    st.integers(0, N_LOC - 1),
    st.sets(st.integers(0, N_LOC - 1), max_size=1),
)
def test_same_place_matches_the_naive_reference(
    raw: list[tuple[int | None, float]], start: int, skip: set[int]
) -> None:
    params = QuestionParams(same_place_steps=3)
    seq = [(s, mass(s if s is not None else 4, p)) for s, p in raw]
    det = SamePlaceDetector(params)
    got = []
    for t, (loc, m) in enumerate(seq):
        hit = det.step(m, N_LOC, localised_state=loc, start=start, skip=frozenset(skip))
        if hit is not None:
            assert hit[0] != start and hit[0] not in skip and hit[1] >= params.same_place_mass
            got.append((t, hit[0]))
    assert got == naive_same_place(seq, params, start, skip)


def test_same_place_asks_after_three_confident_frames_and_never_at_the_start() -> None:
    det = SamePlaceDetector(QuestionParams())
    step = det.step
    assert step(mass(1), N_LOC, localised_state=1, start=1) is None  # the path's own start
    assert step(mass(2), N_LOC, localised_state=2, start=1) is None
    assert step(mass(2), N_LOC, localised_state=2, start=1) is None
    assert step(mass(2, 0.95), N_LOC, localised_state=2, start=1) == (2, 0.95)
    det.reset()
    assert step(mass(2), N_LOC, localised_state=None, start=1) is None  # not localised
    assert step(mass(3), N_LOC, localised_state=3, start=1) is None  # an edge, not a place


def naive_new_paths(
    seq: list[tuple[int | None, np.ndarray, float]], params: QuestionParams
) -> list[Traversal]:
    """Every stretch between a frame localised at location A and the next frame localised at
    a location B != A, when no frame strictly between them has an edge with
    ``new_path_edge_mass`` and evidence ``new_path_evidence``, and there are between
    ``new_path_min_frames`` and ``new_path_max_frames`` of them."""
    out = []
    at = [(t, loc) for t, (loc, _, _) in enumerate(seq) if loc is not None and 0 <= loc < N_LOC]
    for (t0, a), (t1, b) in itertools.pairwise(at):
        between = range(t0 + 1, t1)
        clean = all(
            float(seq[u][1][N_LOC:].max()) < params.new_path_edge_mass
            or seq[u][2] < params.new_path_evidence
            for u in between
        )
        n = len(between)
        if a != b and clean and params.new_path_min_frames <= n <= params.new_path_max_frames:
            out.append(Traversal(a, b, tuple(between), float(seq[t1][1][b])))
    return out


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(states, probs, st.sampled_from([0.5, 0.9])), min_size=1, max_size=40))
def test_new_paths_match_the_naive_reference(raw: list[tuple[int | None, float, float]]) -> None:
    params = QuestionParams(new_path_min_frames=2, new_path_max_frames=6)
    seq = []
    for s, p, evidence in raw:
        # a frame localised nowhere holds its mass on the state drawn (edges 3, 4 or none)
        m = mass(s, p) if s is not None else np.full(5, 0.2)
        seq.append((s if s is not None and s < N_LOC else None, m, evidence))
    det = NewPathDetector(params)
    got = []
    for t, (loc, m, evidence) in enumerate(seq):
        found = det.step(t, m, N_LOC, localised_state=loc, evidence=evidence)
        assert set(det.frames) <= set(range(t + 1))
        if found is not None:
            got.append(found)
    assert got == naive_new_paths(seq, params)


def test_a_traversal_along_a_taught_edge_is_not_new() -> None:
    det = NewPathDetector(QuestionParams(new_path_min_frames=2))
    flat = np.full(5, 0.2)
    assert det.step(0, mass(0), N_LOC, localised_state=0) is None
    for t in (1, 2, 3):
        assert det.step(t, flat, N_LOC, localised_state=None) is None
    assert det.frames == (1, 2, 3)
    found = det.step(4, mass(2, 0.9), N_LOC, localised_state=2)
    assert found == Traversal(0, 2, (1, 2, 3), 0.9)
    # from 2, one frame on edge 3 spoils the way to 1
    det.step(5, flat, N_LOC, localised_state=None)
    det.step(6, mass(3, 0.7), N_LOC, localised_state=None, evidence=0.5)  # images disagree
    assert det.frames == (5, 6)
    det.step(7, mass(3, 0.7), N_LOC, localised_state=None, evidence=0.9)
    assert det.frames == ()
    det.step(8, flat, N_LOC, localised_state=None)
    assert det.step(9, mass(1), N_LOC, localised_state=1) is None


@pytest.mark.parametrize(
    "bad",
    [
        {"expiry_s": 0.0},
        {"expiry_s": float("nan")},
        {"same_place_mass": 0.0},
        {"new_path_edge_mass": 1.5},
        {"new_path_evidence": 0.0},
        {"same_place_steps": 0},
        {"new_path_min_frames": 5, "new_path_max_frames": 4},
    ],
)
def test_bad_parameters_are_refused(bad: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        QuestionParams(**bad)  # type: ignore[arg-type]
