"""Learned transitions (server.belief.learning): naive forward-backward reference, properties, and
a synthetic tour where a robot drives faster than it was taught."""

from __future__ import annotations

import numpy as np
import pytest
from belief_testkit import corridors_graph, fine_of, observe

from server.belief.learning import (
    FilterStep,
    TransitionCounts,
    TransitionLearnParams,
    advance_scale,
    expected_motion_counts,
)
from server.belief.model import Action, BeliefModel
from server.belief.tracker import Tracker, TrackerParams
from server.domain import TourGraph


def _drive(
    model: BeliefModel, rng: np.random.Generator, *, speed: float, frames: int, edge: int = 0
) -> tuple[list[FilterStep], float]:
    """Drive ``edge`` from image 0 at ``speed`` images per frame while odometry says one
    image per frame; noisy images. Returns the run and the mean error (images)."""
    graph = model.graph
    tracker = Tracker(model, TrackerParams(keep_run=10_000, smoother_lag=0))
    n = graph.edges[edge].n_images
    errs = []
    for t in range(frames):
        k = min(round(speed * t), n - 1)
        lik = observe(graph, fine_of(graph, edge, k), rng, background=0.3, width=2.0, noise=0.2)
        s = tracker.step(Action.navigate(edge), lik, v=0.25, dt=0.5)
        errs.append(abs(int(s.best_image[edge]) - k) if s.map_state == 4 + edge else n)
    return tracker.run(), float(np.mean(errs))


def _naive_counts(model: BeliefModel, run: list[FilterStep]) -> TransitionCounts:
    """Dense matrices and loops over states and steps, straight from the module doc."""
    g: TourGraph = model.graph
    L, F = model.n_locations, model.n_fine
    n = len(run)
    beta = [np.ones(F) for _ in range(n)]
    for t in range(n - 1, 0, -1):
        r = run[t]
        T = r.op.to_csr().toarray()  # type: ignore[union-attr]
        dense = (1 - r.eps) * T + r.eps * np.outer(np.ones(F), model.prior)
        b = dense @ (r.likelihood * beta[t])  # type: ignore[operator]
        beta[t - 1] = b / b.max()
    gam = [run[t].alpha * beta[t] / (run[t].alpha @ beta[t]) for t in range(n)]
    c = TransitionCounts.zeros(g.n_edges)
    for t in range(1, n):
        op = run[t].op
        assert op is not None and op.motion is not None
        for e in range(g.n_edges):
            lo, hi = L + int(g.edge_offsets[e]), L + int(g.edge_offsets[e + 1])
            m0, m1 = gam[t - 1][lo:hi].sum(), gam[t][lo:hi].sum()
            p0 = int(np.argmax(gam[t - 1][lo:hi]))
            p1 = int(np.argmax(gam[t][lo:hi]))
            wts = op.motion.weights[e]
            k = sum(wts[j] * (op.motion.lo + j) for j in range(len(wts)))
            w = min(m0, m1) if min(m0, m1) >= 0.5 else 0.0
            c.steps[e] += w
            c.moved[e] += w * (p1 - p0)
            c.taught[e] += w * k
    return c


def test_counts_match_a_naive_forward_backward() -> None:
    graph = corridors_graph(8)
    model = BeliefModel(graph)
    run, _ = _drive(model, np.random.default_rng(3), speed=1.5, frames=6)
    fast = expected_motion_counts(model, run)
    slow = _naive_counts(model, run)
    for name in ("steps", "moved", "taught"):
        np.testing.assert_allclose(getattr(fast, name), getattr(slow, name), atol=1e-9)
    assert fast.steps[0] > 1.0  # the run drove edge 0


def test_zero_evidence_gives_the_taught_model_exactly() -> None:
    graph = corridors_graph(10)
    scale = advance_scale(TransitionCounts.zeros(graph.n_edges))
    assert np.array_equal(scale, np.ones(graph.n_edges))
    taught, learned = BeliefModel(graph), BeliefModel(graph, advance_scale=scale)
    for v in (0.0, 0.1, 0.25, 0.4):
        a = taught.expected_advance(v=v, dt=0.5)
        assert np.array_equal(a, learned.expected_advance(v=v, dt=0.5))
        x = taught.operator(Action.navigate(0), advance=a).to_csr()
        y = learned.operator(Action.navigate(0), advance=a).to_csr()
        assert (x != y).nnz == 0
    # a run of only the start holds no evidence either
    start = Tracker(taught, TrackerParams(keep_run=5)).run()
    assert np.array_equal(advance_scale(expected_motion_counts(taught, start)), np.ones(4))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_learned_rows_stay_stochastic_and_scale_is_bounded(seed: int) -> None:
    rng = np.random.default_rng(seed)
    graph = corridors_graph(12)
    counts = TransitionCounts(
        rng.random(4) * 20, rng.random(4) * 200 - 20, rng.random(4) * 30
    )  # a wild run, even negative net motion
    p = TransitionLearnParams()
    scale = advance_scale(counts, p)
    assert np.all((scale >= p.min_scale) & (scale <= p.max_scale))
    model = BeliefModel(graph, advance_scale=scale)
    adv = model.expected_advance(v=0.25, dt=0.5)
    for action in (Action.navigate(0), Action.explore(), Action.rotate(1)):
        rows = np.asarray(model.operator(action, advance=adv).to_csr().sum(axis=1)).ravel()
        np.testing.assert_allclose(rows, 1.0, atol=1e-12)


def test_counts_add_and_round_trip() -> None:
    a = TransitionCounts(np.arange(3.0), np.ones(3), np.full(3, 2.0))
    b = TransitionCounts.from_bytes(a.to_bytes(), 3)
    assert np.array_equal(a.plus(b).moved, np.full(3, 2.0))
    with pytest.raises(ValueError, match="edges"):
        TransitionCounts.from_bytes(a.to_bytes(), 4)
    with pytest.raises(ValueError, match="advance_scale"):
        BeliefModel(corridors_graph(5), advance_scale=np.zeros(4))


def test_learning_on_one_run_tracks_another_better() -> None:
    """The robot drives 1.6 images per frame where the taught pace says 1: learn on one run,
    measure on another (other noise); the learned scale is near 1.6 and the error drops."""
    graph = corridors_graph(80)
    taught = BeliefModel(graph)
    run, _ = _drive(taught, np.random.default_rng(10), speed=1.6, frames=45)
    counts = expected_motion_counts(taught, run)
    scale = advance_scale(counts, TransitionLearnParams(prior_images=10.0))
    assert 1.35 < scale[0] < 1.8
    assert scale[1] == pytest.approx(scale[0], rel=0.2)  # unseen edges follow the tour's rate
    learned = BeliefModel(graph, advance_scale=scale)
    _, before = _drive(taught, np.random.default_rng(11), speed=1.6, frames=45)
    _, after = _drive(learned, np.random.default_rng(11), speed=1.6, frames=45)
    assert after < 0.5 * before, (before, after)


def test_counts_of_a_run_on_a_learned_model_stay_relative_to_the_taught_one() -> None:
    """A second run filtered with the learned model adds counts on the same scale: its own
    estimate is again ~1.6, not ~1.6 / 1.5."""
    graph = corridors_graph(80)
    taught = BeliefModel(graph)
    run, _ = _drive(taught, np.random.default_rng(10), speed=1.6, frames=45)
    p = TransitionLearnParams(prior_images=10.0)
    first = expected_motion_counts(taught, run)
    learned = BeliefModel(graph, advance_scale=advance_scale(first, p))
    again, _ = _drive(learned, np.random.default_rng(12), speed=1.6, frames=45)
    second = expected_motion_counts(learned, again)
    assert 1.4 < advance_scale(second, p)[0] < 1.8
    assert 1.4 < advance_scale(first.plus(second), p)[0] < 1.8
