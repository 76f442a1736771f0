"""When to ask (server.belief.questions): the two detectors against naive references written
from their docstrings, properties over random belief sequences, and the parameter checks."""

from __future__ import annotations

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


Frame = tuple[int | None, np.ndarray, float, float]  # localised place, mass, evidence, v


def naive_new_paths(seq: list[Frame], params: QuestionParams, dt: float) -> list[Traversal]:
    """From the rule in NewPathDetector's docstring: first the origin of every frame (a frame
    on a taught edge forgets it, a frame localised at another place replaces it), then, for
    every frame localised at a place B other than the origin before it, the frames after the
    origin began, back to its last standing frame, that moved (the last max_frames)."""
    origin: list[int | None] = []
    current: int | None = None
    for loc, m, evidence, _ in seq:
        if float(m[N_LOC:].max()) >= params.new_path_edge_mass and (
            evidence >= params.new_path_evidence
        ):
            current = None
        elif loc is not None and loc != current:
            current = loc
        origin.append(current)
    out = []
    for t, (loc, m, _, _) in enumerate(seq):
        before = origin[t - 1] if t else None
        if loc is None or before is None or loc == before or origin[t] != loc:
            continue
        kept: list[int] = []
        u = t - 1
        while u >= 1 and origin[u] == before and origin[u - 1] == before:
            lu, _, _, vu = seq[u]
            if abs(vu) < params.still_v:
                if lu == before:
                    break
            else:
                kept.append(u)
            u -= 1
        kept = sorted(kept)[-params.new_path_max_frames :]
        metres = sum(abs(seq[k][3]) * dt for k in kept)
        if len(kept) >= params.new_path_min_frames and metres >= params.new_path_min_m:
            out.append(Traversal(before, loc, tuple(kept), float(m[loc])))
    return out


@settings(max_examples=300, deadline=None)
@given(
    st.lists(
        st.tuples(states, probs, st.sampled_from([0.5, 0.9]), st.sampled_from([0.0, 0.5])),
        min_size=1,
        max_size=40,
    )
)
def test_new_paths_match_the_naive_reference(
    raw: list[tuple[int | None, float, float, float]],
) -> None:
    params = QuestionParams(new_path_min_frames=2, new_path_min_m=1.0, new_path_max_frames=6)
    seq: list[Frame] = []
    for s, p, evidence, v in raw:
        # a frame localised nowhere holds its mass on the state drawn (edges 3, 4 or none)
        m = mass(s, p) if s is not None else np.full(5, 0.2)
        seq.append((s if s is not None and s < N_LOC else None, m, evidence, v))
    det = NewPathDetector(params)
    got = []
    for t, (loc, m, evidence, v) in enumerate(seq):
        found = det.step(t, m, N_LOC, localised_state=loc, evidence=evidence, v=v, dt=1.0)
        assert set(det.frames) <= set(range(t + 1))
        if found is not None:
            got.append(found)
    assert got == naive_new_paths(seq, params, dt=1.0)


def test_the_way_starts_where_the_robot_stood_and_a_taught_edge_spoils_it() -> None:
    det = NewPathDetector(QuestionParams(new_path_min_frames=2, new_path_min_m=0.5))
    flat = np.full(5, 0.2)

    def step(t: int, m: np.ndarray, at: int | None, v: float = 0.3, e: float = 0.5) -> object:
        return det.step(t, m, N_LOC, localised_state=at, evidence=e, v=v, dt=1.0)

    assert step(0, mass(0), 0, v=0.0) is None  # standing at place 0
    assert step(1, mass(0), 0) is None  # crossing the room: still "at 0"
    assert step(2, mass(0), 0, v=0.0) is None  # stood again: the way starts here
    for t in (3, 4, 5):
        assert step(t, mass(0) if t == 3 else flat, 0 if t == 3 else None) is None
    assert det.frames == (3, 4, 5)
    assert step(6, mass(2, 0.9), 2) == Traversal(0, 2, (3, 4, 5), 0.9)
    # from 2: a frame on edge 3 with images that disagree is not on it; one that agrees is
    step(7, flat, None)
    step(8, mass(3, 0.7), None, e=0.5)
    assert det.frames == (7, 8)
    step(9, mass(3, 0.7), None, e=0.9)
    assert det.frames == ()
    step(10, flat, None)
    assert step(11, mass(1), 1) is None  # no origin since the edge
    step(12, flat, None)  # too short a way from 1
    assert step(13, mass(2), 2) is None


@pytest.mark.parametrize(
    "bad",
    [
        {"expiry_s": 0.0},
        {"expiry_s": float("nan")},
        {"same_place_mass": 0.0},
        {"new_path_edge_mass": 1.5},
        {"new_path_evidence": 0.0},
        {"new_path_min_m": -1.0},
        {"still_v": float("inf")},
        {"same_place_steps": 0},
        {"new_path_min_frames": 5, "new_path_max_frames": 4},
    ],
)
def test_bad_parameters_are_refused(bad: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        QuestionParams(**bad)  # type: ignore[arg-type]
