"""Localisation figures of ``teachrepeat bench navigate`` (docs/ambiguity.md): how soon each
trial's belief was rightly "localised" from its uniform start, its wrong claims, and with
``--mcl`` the Monte-Carlo position error, from the rows the judge wrote
(:mod:`robot_client.judge_localisation`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

SETTLE_FRAMES = 100
"""Frames of a task (10 s at the robot's 10 frames a second) before its ``settled`` MCL errors
count."""


def localisation_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per group of trial rows: the median robot seconds to the first right "localised" (a
    trial never rightly localised counts as infinitely late: ``None`` when half of them
    were), how many never were, the wrong claims (runs of frames localised on a wrong state),
    the trials with any and their frames, and the frames spent disambiguating / separating."""
    firsts = [math.inf if r.get("first_correct_s") is None else r["first_correct_s"] for r in rows]
    median = float(np.median(firsts)) if firsts else math.nan
    finite = [f for f in firsts if math.isfinite(f)]
    return {
        "median_first_correct_s": median if math.isfinite(median) else None,
        "mean_first_correct_s": float(np.mean(finite)) if finite else None,
        "never_correct": sum(not math.isfinite(f) for f in firsts),
        "wrong_claims": sum(int(r.get("wrong_claims", 0)) for r in rows),
        "trials_with_wrong_claims": sum(int(r.get("wrong_claims", 0)) > 0 for r in rows),
        "wrong_claim_frames": sum(int(r.get("wrong_claim_frames", 0)) for r in rows),
        "disambiguating_frames": sum(int(r.get("disambiguating_frames", 0)) for r in rows),
        "separating_frames": sum(int(r.get("separating_frames", 0)) for r in rows),
    }


def mcl_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Monte-Carlo position error over every frame of every trial of the group (m): median,
    p90, and the same over the frames after the first :data:`SETTLE_FRAMES` of each task (a
    uniform start takes a while to settle), with the numbers of frames."""
    every: list[float] = []
    settled: list[float] = []
    for r in rows:
        errors = list(r.get("mcl_error_m", ()))
        every += errors
        settled += errors[SETTLE_FRAMES:]

    def q(values: list[float], p: float) -> float | None:
        return float(np.percentile(values, p)) if values else None

    return {
        "median_error_m": q(every, 50),
        "p90_error_m": q(every, 90),
        "frames": len(every),
        "settled_median_error_m": q(settled, 50),
        "settled_p90_error_m": q(settled, 90),
        "settled_frames": len(settled),
    }
