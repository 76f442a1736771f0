"""``bench localize --learn-transitions``: learned transitions (001 s10.1) measured on frames
they were not learned on.

Protocol (two-fold, per direction): the query traversal is split into its halves. For each
half H, the tracker alone replays H from the prior on the taught model (the engine's answers
are those of the main replay, so the figures differ by the transitions only), the run's
expected motion counts give a learned advance scale (:mod:`server.belief.learning`, default
:class:`TransitionLearnParams`), and the whole traversal is replayed with it; only the frames
of the *other* half are scored from that replay. Every frame is thus scored by a model learned
without it, and the learned figures are compared with the main replay's on the same frames.
``ir_only`` does not depend on the transitions (it is repeated unchanged).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from server.bench.localize import DirectionRun, RunSettings

PROTOCOL = (
    "two-fold over the query's halves: learn on one half (tracker replayed alone from the "
    "prior on the taught model), replay the whole traversal with the learned scale, score only "
    "the other half; every frame is scored by a model not learned on it"
)


def learned_figures(
    d: DirectionRun, settings: RunSettings, tolerances: Sequence[int]
) -> dict[str, Any]:
    """The ``learned_transitions`` entry of one direction (module doc)."""
    from server.belief.learning import TransitionLearnParams, advance_scale
    from server.belief.learning import expected_motion_counts as counts_of
    from server.belief.model import build_model
    from server.bench.localize import errors, recall_at, replay

    qf = d.plan.qry_frames
    n = len(qf)
    obs = d.replay.observations
    blank = [np.zeros((0, 0), np.uint8)] * n
    halves = {"first": np.arange(n // 2), "second": np.arange(n // 2, n)}
    learned = {m: np.array(d.errors[m], copy=True) for m in ("tracker", "smoother")}
    scales: dict[str, Any] = {}
    model = build_model(d.tour.graph, settings.transitions)
    for name, learn_on in halves.items():
        score_on = halves["second" if name == "first" else "first"]
        if len(learn_on) < 2 or len(score_on) == 0:
            continue
        tracker = dataclasses.replace(settings.tracker, keep_run=len(learn_on))
        common = {
            "transitions": settings.transitions,
            "action_mode": settings.action,
            "progress": False,
        }
        taught = replay(
            d.tour,
            d.index,
            [qf[i] for i in learn_on],
            blank[: len(learn_on)],
            tracker_params=tracker,
            observations=[obs[i] for i in learn_on],
            **common,  # type: ignore[arg-type]
        )
        scale = advance_scale(counts_of(model, taught.run), TransitionLearnParams())
        full = replay(
            d.tour,
            d.index,
            qf,
            blank,
            tracker_params=settings.tracker,
            observations=obs,
            advance_scale=scale,
            **common,  # type: ignore[arg-type]
        )
        for m in learned:
            learned[m][score_on] = errors(full.query, getattr(full, m), d.plan.gt)[score_on]
        valid = scale[[e.n_images > 0 for e in d.tour.graph.edges]]
        scales[f"learned_on_{name}"] = {
            "min": float(valid.min()),
            "median": float(np.median(valid)),
            "max": float(valid.max()),
        }
    baseline = {m: d.errors[m] for m in ("ir_only", "tracker", "smoother")}
    return {
        "protocol": PROTOCOL,
        "prior_images": TransitionLearnParams().prior_images,
        "advance_scale": scales,
        "taught": recall_at(baseline, tolerances),
        "learned": recall_at({"ir_only": baseline["ir_only"], **learned}, tolerances),
    }


def print_figures(name: str, f: dict[str, Any]) -> None:
    """One line per tolerance: tracker and smoother recall@1, taught -> learned."""
    scales = ", ".join(
        f"{k} {v['min']:.2f}/{v['median']:.2f}/{v['max']:.2f}"
        for k, v in f["advance_scale"].items()
    )
    print(f"  learned transitions ({name}; advance scale min/median/max: {scales})")
    for tol, taught in f["taught"].items():
        learned = f["learned"][tol]
        cells = ", ".join(
            f"{m} {taught[m]['recall@1']:.3f} -> {learned[m]['recall@1']:.3f}"
            for m in ("tracker", "smoother")
        )
        print(f"    tol {tol}: {cells}")
