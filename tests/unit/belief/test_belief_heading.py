"""The heading kept at each place: naive references, properties, and a spin that tells a place
from its look-alike."""

from __future__ import annotations

import math

import numpy as np
import pytest
from belief_testkit import edge, location

from server.belief.heading import (
    HeadingParams,
    SpinLayout,
    consistency,
    predict_heading,
    update_heading,
)
from server.belief.model import Action, BeliefModel
from server.belief.tracker import (
    InvalidLikelihoodError,
    Tracker,
    TrackerParams,
    fine_likelihood,
)
from server.domain import TourGraph

N_SPIN = 36  # the guide's spin: about 10 degrees apart
N_PLACES_SPIN = 2 * N_SPIN + 5  # places_graph()'s spin images
ON = TrackerParams(heading=HeadingParams(enabled=True))  # off by default


def places_graph(counts: tuple[int, ...] = (N_SPIN, N_SPIN, 0, 5)) -> TourGraph:
    """Places with ``counts`` spin images (one with none), joined by edges of 6 images."""
    locs = tuple(location(f"p{k}", n) for k, n in enumerate(counts))
    edges = tuple(edge(k, (k + 1) % len(counts), 6) for k in range(len(counts)))
    return TourGraph(locs, edges)


def wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def naive_predict(
    q: np.ndarray, headings: list[np.ndarray], turn: float, p: HeadingParams
) -> np.ndarray:
    out, start = [], 0
    for h in headings:
        n = len(h)
        sd = math.hypot(max(p.spread_rad, math.pi / n), p.turn_noise * abs(turn))
        part = np.zeros(n)
        for i in range(n):
            k = [math.exp(-0.5 * (wrap(h[j] - h[i] - turn) / sd) ** 2) for j in range(n)]
            for j in range(n):
                part[j] += q[start + i] * k[j] / sum(k)
        out.append((1 - p.forget) * part + p.forget / n)
        start += n
    return np.concatenate(out)


def naive_consistency(
    q: np.ndarray, s: np.ndarray, counts: tuple[int, ...], p: HeadingParams
) -> np.ndarray:
    out, start = [], 0
    for n in counts:
        if n == 0:
            continue
        qq, ss = q[start : start + n], s[start : start + n]
        r = [max(p.least_weight, x / qq.max()) for x in qq]
        out.append(max(a * b for a, b in zip(r, ss, strict=True)) / ss.max())
        start += n
    return np.array(out) / max(out)


def random_q(layout: SpinLayout, rng: np.random.Generator) -> np.ndarray:
    q = rng.random(layout.n_spin)
    total = layout.spread(layout.per_place(q, np.add))
    return q / total


@pytest.mark.parametrize("turn", [0.0, 0.05, -0.4, 3.0])
def test_prediction_against_a_naive_loop(turn: float) -> None:
    graph = places_graph()
    layout = SpinLayout.of(graph)
    p = HeadingParams()
    q = random_q(layout, np.random.default_rng(1))
    counts = [len(loc.image_ids) for loc in graph.locations if loc.image_ids]
    headings = [2 * np.pi * np.arange(n) / n for n in counts]
    assert predict_heading(q, layout, turn, p) == pytest.approx(
        naive_predict(q, headings, turn, p), abs=1e-12
    )


def test_consistency_against_a_naive_loop_and_eq2_when_nothing_is_known() -> None:
    graph = places_graph()
    layout = SpinLayout.of(graph)
    p = HeadingParams()
    rng = np.random.default_rng(2)
    q, s = random_q(layout, rng), rng.random(layout.n_spin)
    counts = tuple(len(loc.image_ids) for loc in graph.locations)
    assert consistency(q, s, layout, p) == pytest.approx(naive_consistency(q, s, counts, p))
    # nothing known of the heading: 001 eq. 2 (the best spin image) unchanged
    assert consistency(layout.uniform(), s, layout, p) == pytest.approx(1.0)
    assert list(layout.places) == [0, 1, 3]


@pytest.mark.parametrize("seed", range(5))
def test_each_places_distribution_sums_to_one_and_stays_positive(seed: int) -> None:
    layout = SpinLayout.of(places_graph())
    rng = np.random.default_rng(seed)
    q = layout.uniform()
    for _ in range(30):
        q = predict_heading(q, layout, float(rng.normal(0, 0.3)), HeadingParams())
        q = update_heading(q, rng.random(layout.n_spin) + 1e-3, layout)
        assert layout.per_place(q, np.add) == pytest.approx(1.0)
        assert np.all(q > 0)
        factor = consistency(q, rng.random(layout.n_spin), layout, HeadingParams())
        assert np.all((factor >= HeadingParams().least_weight - 1e-12) & (factor <= 1 + 1e-12))
        assert factor.max() == pytest.approx(1.0)  # the most consistent place: eq. 2 as it was


def test_taught_headings_are_used_when_every_spin_image_of_the_place_has_one() -> None:
    graph = places_graph((4, 4))
    pose = np.full((graph.n_images, 3), np.nan)
    pose[:4, 2] = [0.5, 1.0, 1.5, 2.0]  # place 0: its own odometry; place 1: none
    layout = SpinLayout.of(TourGraph(graph.locations, graph.edges, image_pose=pose))
    assert layout.heading[:4] == pytest.approx([0.5, 1.0, 1.5, 2.0])
    assert layout.heading[4:] == pytest.approx(2 * np.pi * np.arange(4) / 4)


def spin_views(n: int, start: int, frames: int, step: int, rng: np.random.Generator) -> np.ndarray:
    """``(frames, n)`` the similarities of a place's ``n`` spin images to a robot turning one
    image (``step``) per frame there from image ``start``: high at the image it faces."""
    s = 0.05 * rng.random((frames, n))
    for t in range(frames):
        s[t, (start + step * t) % n] = 0.9
    return s


def test_a_spin_at_the_place_keeps_its_likelihood_and_a_look_alike_loses_it() -> None:
    """Two places whose spin images match every view of a turning robot equally well (the max
    of 001 eq. 2 cannot tell them apart): at one the matches come round as the odometry turns,
    at the look-alike they jump about. The belief ends at the first."""
    graph = places_graph((N_SPIN, N_SPIN))
    model = BeliefModel(graph)
    rng = np.random.default_rng(3)
    frames, turn = 40, 2 * np.pi / N_SPIN  # one spin image per frame, anticlockwise
    here = spin_views(N_SPIN, 7, frames, 1, rng)
    alike = 0.05 * rng.random((frames, N_SPIN))
    alike[np.arange(frames), rng.integers(0, N_SPIN, frames)] = 0.9  # the best jumps about
    beliefs = {}
    for name, spin in (("heading", True), ("eq2", False)):
        tracker = Tracker(model, ON)
        for t in range(frames):
            image = np.concatenate([here[t], alike[t], np.full(graph.n_images - 2 * N_SPIN, 0.05)])
            lik = fine_likelihood(image, graph)
            spins = image[: 2 * N_SPIN] if spin else None
            s = tracker.step(Action.do_nothing(), lik, v=0.0, w=turn / 0.1, dt=0.1, spin=spins)
        beliefs[name] = s.state[:2]
    assert beliefs["eq2"][0] == pytest.approx(beliefs["eq2"][1], rel=0.05)
    assert beliefs["heading"][0] > 0.9
    assert beliefs["heading"][1] < 0.05


def test_off_or_without_spin_similarities_the_tracker_is_as_before() -> None:
    graph = places_graph()
    model = BeliefModel(graph)
    rng = np.random.default_rng(4)
    off = Tracker(model, TrackerParams(heading=HeadingParams(enabled=False)))
    plain, given = Tracker(model, ON), Tracker(model, ON)
    for _ in range(10):
        image = rng.random(graph.n_images)
        lik = fine_likelihood(image, graph)
        a = plain.step(Action.do_nothing(), lik, v=0.0, w=0.5, dt=0.1)
        b = off.step(Action.do_nothing(), lik, v=0.0, w=0.5, dt=0.1, spin=image[:N_PLACES_SPIN])
        given.step(Action.do_nothing(), lik, v=0.0, w=0.5, dt=0.1, spin=image[:N_PLACES_SPIN])
        assert a.belief == pytest.approx(b.belief, abs=1e-15)
    assert not np.allclose(given.belief, plain.belief)


def test_spin_similarities_of_the_wrong_shape_or_value_are_refused() -> None:
    graph = places_graph()
    tracker = Tracker(BeliefModel(graph), ON)
    lik = fine_likelihood(np.full(graph.n_images, 0.5), graph)
    before = tracker.belief
    with pytest.raises(InvalidLikelihoodError, match="spin has shape"):
        tracker.step(Action.do_nothing(), lik, v=0.0, dt=0.1, spin=np.ones(10))
    with pytest.raises(InvalidLikelihoodError, match="finite"):
        tracker.step(Action.do_nothing(), lik, v=0.0, dt=0.1, spin=np.full(N_PLACES_SPIN, np.nan))
    assert tracker.belief == pytest.approx(before)  # refused frames changed nothing
