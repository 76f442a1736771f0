"""Localisation figures of ``teachrepeat bench navigate`` (docs/ambiguity.md): how soon each
trial's belief was rightly "localised" from its uniform start and its wrong claims, from the
rows the judge wrote (:mod:`robot_client.judge_localisation`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def localisation_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per group of trial rows: the median robot seconds to the first right "localised" (a
    trial never rightly localised counts as infinitely late: ``None`` when half of them
    were), how many never were, the wrong claims (runs of frames localised on a wrong state),
    the trials with any and their frames."""
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
    }
