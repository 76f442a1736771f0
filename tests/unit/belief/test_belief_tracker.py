"""Tracker scenarios: aliasing, kidnapping, an erratic best match, the localised flag, smoothing."""

from __future__ import annotations

import numpy as np
import pytest
from belief_testkit import corridors_graph, fine_of, house_graph, observe

from server.belief.model import Action, BeliefModel
from server.belief.tracker import Tracker, TrackerParams
from server.domain import Location, TourGraph

ALIAS = {1: 0}  # corridor C -> D (edge 1) looks exactly like A -> B (edge 0)


def test_one_image_cannot_tell_identical_corridors_apart_but_a_sequence_can() -> None:
    graph = corridors_graph(30)
    model = BeliefModel(graph)
    L = graph.n_locations
    rng = np.random.default_rng(0)
    # one image in the corridor, from the uniform prior: a coin toss between the two corridors
    s = Tracker(model).step(
        Action.do_nothing(), observe(graph, fine_of(graph, 0, 10), rng, alias=ALIAS), v=0, dt=0.5
    )
    assert s.state[L + 0] == pytest.approx(s.state[L + 1], rel=0.2)
    assert not s.localised
    # the sequence "at A, turn into the corridor, drive along it" decides: it is A -> B
    for start, corridor in ((0, 0), (2, 1)):
        tracker = Tracker(model)
        for _ in range(3):
            tracker.step(Action.do_nothing(), observe(graph, start, rng, alias=ALIAS), v=0, dt=0.5)
        tracker.step(
            Action.rotate(corridor),
            observe(graph, fine_of(graph, corridor, 0), rng, alias=ALIAS),
            v=0,
            dt=0.5,
        )
        for k in range(1, 25):
            truth = fine_of(graph, corridor, k)
            s = tracker.step(
                Action.navigate(corridor), observe(graph, truth, rng, alias=ALIAS), v=0.25, dt=0.5
            )
            assert s.map_state == L + corridor
            assert abs(int(s.best_image[corridor]) - k) <= 2
        assert s.state[L + corridor] > 0.95
        assert s.localised and s.localised_state == L + corridor


def _drive_then_kidnap(seed: int, background: float, noise: float) -> tuple[int, int]:
    """Track 20 frames on hall -> kitchen, then jump to office -> bedroom image 5 and keep
    driving. Returns (frames until the MAP state is right, longest wrong-localised streak)."""
    graph = house_graph()
    model = BeliefModel(graph)
    L = graph.n_locations
    rng = np.random.default_rng(seed)
    tracker = Tracker(model)

    def frame(j: int, k: int) -> np.ndarray:
        return observe(graph, fine_of(graph, j, k), rng, background=background, noise=noise)

    for k in range(20):
        s = tracker.step(Action.navigate(0), frame(0, k), v=0.25, dt=0.5)
    assert s.localised and s.localised_state == L + 0
    recovered, streak, worst = 0, 0, 0
    for t in range(20):  # images 5..24 of 30: still inside the edge at the end
        s = tracker.step(Action.navigate(0), frame(4, 5 + t), v=0.25, dt=0.5)
        if not recovered and s.map_state == L + 4 and abs(int(s.best_image[4]) - (5 + t)) <= 2:
            recovered = t + 1
        streak = streak + 1 if s.localised and s.localised_state != L + 4 else 0
        worst = max(worst, streak)
    assert s.localised and s.localised_state == L + 4
    return recovered, worst


@pytest.mark.parametrize(("background", "noise", "bound"), [(0.15, 0.05, 8), (0.3, 0.1, 12)])
def test_kidnapping_is_recovered_and_never_claims_the_wrong_state_for_long(
    background: float, noise: float, bound: int
) -> None:
    for seed in range(5):
        recovered, worst = _drive_then_kidnap(seed, background, noise)
        assert 0 < recovered <= bound, seed
        assert worst <= 5, seed  # the benchmark's robustness requirement


def test_best_match_jumping_along_the_edge_does_not_drag_the_belief() -> None:
    """001 Section 6: every other frame the best-matching image is 15 images away."""
    graph = house_graph()
    model = BeliefModel(graph)
    L = graph.n_locations
    rng = np.random.default_rng(7)
    tracker = Tracker(model)
    j = 7  # hall -> office, 40 images
    for k in range(36):
        if k >= 6 and k % 2 == 0:
            outlier = k - 15 if k >= 15 else k + 15
            lik = observe(graph, fine_of(graph, j, outlier), rng)
        else:
            lik = observe(graph, fine_of(graph, j, k), rng)
        s = tracker.step(Action.navigate(j), lik, v=0.25, dt=0.5)
        if k >= 4:
            assert s.map_state == L + j
            assert abs(int(s.best_image[j]) - k) <= 2, (k, s.best_image[j])
    assert s.localised


def test_localised_stays_off_while_the_belief_is_split() -> None:
    graph = corridors_graph(30)
    model = BeliefModel(graph)
    rng = np.random.default_rng(1)
    tracker = Tracker(model)
    # driving along an aliased corridor from an unknown start: never localised
    for k in range(5, 25):
        lik = observe(graph, fine_of(graph, 0, k), rng, alias=ALIAS)
        s = tracker.step(Action.navigate(), lik, v=0.25, dt=0.5)
        assert not s.localised
        assert s.localised_state is None


def test_localised_needs_sustained_mass() -> None:
    graph = house_graph()
    model = BeliefModel(graph)
    rng = np.random.default_rng(2)
    tracker = Tracker(model, TrackerParams(localised_steps=3))
    flags = []
    for _ in range(5):
        s = tracker.step(Action.do_nothing(), observe(graph, 1, rng), v=0, dt=0.5)
        flags.append(s.localised)
    assert flags[0] is False and flags[1] is False  # not yet sustained for 3 steps
    assert flags[-1] is True and s.localised_state == 1


def test_smoother_reestimates_the_start_of_an_aliased_corridor() -> None:
    """Filtering along the aliased corridors stays split; arriving at B (distinct) tells the
    smoother that the whole recent trajectory was on A -> B (seeds 000 / 003)."""
    graph = corridors_graph(12)
    model = BeliefModel(graph)
    L = graph.n_locations
    rng = np.random.default_rng(3)
    tracker = Tracker(model, TrackerParams(smoother_lag=12))
    filtered = []
    for k in range(3, 11):
        lik = observe(graph, fine_of(graph, 0, k), rng, alias=ALIAS)
        s = tracker.step(Action.navigate(), lik, v=0.25, dt=0.5)
        filtered.append(s.state[L + 0])
    assert max(filtered) < 0.75  # the filter cannot decide
    for _ in range(3):
        s = tracker.step(Action.navigate(), observe(graph, 1, rng, alias=ALIAS), v=0.25, dt=0.5)
    assert s.map_state == 1
    smooth = tracker.smoothed()
    assert smooth is not None
    # the frames in the corridor (all but the last 3 and the prior) are now on edge 0
    in_corridor = slice(len(smooth.state) - 3 - 8, len(smooth.state) - 3)
    assert np.all(smooth.state[in_corridor] == L + 0)
    assert np.all(smooth.state_prob[in_corridor] > 0.8)
    assert np.all(smooth.image[in_corridor] >= 0)
    assert smooth.oldest.sum() == pytest.approx(1.0)
    # the smoothed estimate of the last step is the filter's
    assert smooth.state[-1] == s.map_state


def test_smoother_disabled_and_window_bounded() -> None:
    graph = corridors_graph(6)
    model = BeliefModel(graph)
    assert Tracker(model, TrackerParams(smoother_lag=0)).smoothed() is None
    tracker = Tracker(model, TrackerParams(smoother_lag=4))
    for _ in range(10):
        tracker.step(Action.do_nothing(), np.ones(graph.n_fine), v=0, dt=0.5)
    smooth = tracker.smoothed()
    assert smooth is not None and len(smooth.state) == 4


def test_all_zero_frame_is_treated_as_no_information() -> None:
    graph = corridors_graph(6)
    tracker = Tracker(BeliefModel(graph))
    before = tracker.belief
    tracker.step(Action.do_nothing(), np.zeros(graph.n_fine), v=0, dt=0.5)
    np.testing.assert_allclose(tracker.belief, before)


@pytest.mark.parametrize("background", [0.15, 0.4])
def test_spinning_at_a_location_stays_there_until_the_edge_is_seen(background: float) -> None:
    """While the camera still sees the location, spinning must not drift the belief into the
    edge (else the policy would Navigate). Once the robot sees the edge's start and drives onto
    it (the motion layer then reports Navigate), the belief follows within a few frames."""
    graph = house_graph()
    model = BeliefModel(graph)
    L = graph.n_locations
    rng = np.random.default_rng(4)
    tracker = Tracker(model)
    for _ in range(5):
        tracker.step(
            Action.do_nothing(), observe(graph, 0, rng, background=background), v=0, dt=0.5
        )
    for _ in range(10):
        s = tracker.step(
            Action.rotate(0), observe(graph, 0, rng, background=background), v=0, dt=0.5
        )
        assert s.map_state == 0
    for k in range(4):
        lik = observe(graph, fine_of(graph, 0, k), rng, background=background)
        s = tracker.step(Action.navigate(0), lik, v=0.3, dt=0.1)
    assert s.map_state == L + 0
    assert s.best_image[0] <= 4


def test_graph_without_edges() -> None:
    graph = TourGraph((Location("a", (1, 2)), Location("b", (3,))))
    tracker = Tracker(BeliefModel(graph))
    s = tracker.step(Action.navigate(), np.array([0.2, 0.9]), v=0.3, dt=0.2)
    assert s.map_state == 1 and s.along_edge == () and s.best_image.shape == (0,)
