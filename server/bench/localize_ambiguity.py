"""Localisation figures of ``teachrepeat bench localize`` beyond recall (docs/ambiguity.md): how
soon the tracker is rightly "localised" from its uniform start, how often it claims a wrong
place, and, with ``--mcl``, Monte-Carlo localisation (seed 002) along the replayed route.

The replay has no metric ground truth, so the taught route is laid on a line: reference frame
``k`` at ``k * METRES_PER_FRAME`` metres (the bench teaches at 1 m/s and 10 frames/s), facing
along it; the particle filter is driven by that same odometry, weighted by the engine's scores,
and its error is the distance along the line to the nearest reference frame the ground truth
lists for the query frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from server.belief.mcl import MonteCarloLocaliser
    from server.bench.localize import GroundTruth, Tour

METRES_PER_FRAME = 0.1
"""Metres between two reference frames of the bench's tour (1 m/s at 10 frames/s)."""


def wrong(frames: tuple[int, ...] | None, q: int, gt: GroundTruth, tolerance: int) -> bool:
    """A "localised" claim on a state with reference ``frames`` is wrong for query ``q``."""
    return (
        frames is not None and gt.has_truth(q) and min(gt.error(q, f) for f in frames) > tolerance
    )


def first_right_claim(
    query: Sequence[int],
    localised: Sequence[tuple[int, ...] | None],
    gt: GroundTruth,
    tolerance: int,
) -> int | None:
    """Index (frames since the uniform start) of the first frame "localised" on a right state,
    ``None`` when none is."""
    for i, (q, frames) in enumerate(zip(query, localised, strict=True)):
        if frames is not None and gt.has_truth(q) and not wrong(frames, q, gt, tolerance):
            return i
    return None


def wrong_claims(
    query: Sequence[int],
    localised: Sequence[tuple[int, ...] | None],
    gt: GroundTruth,
    tolerance: int,
) -> int:
    """Runs of consecutive frames "localised" on a wrong state."""
    runs, before = 0, False
    for q, frames in zip(query, localised, strict=True):
        now = wrong(frames, q, gt, tolerance)
        runs += now and not before
        before = now
    return runs


def line_poses(tour: Tour) -> npt.NDArray[np.float64]:
    """``(n_images, 3)`` the tour's images laid on a line, frame k at ``k * METRES_PER_FRAME``."""
    x = tour.image_frame.astype(np.float64) * METRES_PER_FRAME
    return np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])


def localiser(tour: Tour) -> MonteCarloLocaliser:
    from server.belief.mcl import MclParams, MonteCarloLocaliser

    return MonteCarloLocaliser(line_poses(tour), MclParams(enabled=True))


def mcl_errors(
    query: Sequence[int], x: Sequence[float], y: Sequence[float], gt: GroundTruth
) -> list[float]:
    """Per query frame with a truth: metres from the estimate to the nearest listed reference."""
    out = []
    for q, xe, ye in zip(query, x, y, strict=True):
        if gt.has_truth(q):
            along = gt.error(q, xe / METRES_PER_FRAME) * METRES_PER_FRAME  # type: ignore[arg-type]
            out.append(float(np.hypot(along, ye)))
    return out


def figures(
    query: Sequence[int],
    localised: Sequence[tuple[int, ...] | None],
    mcl_xy: Sequence[tuple[float, float]],
    gt: GroundTruth,
    tolerance: int,
    frame_dt: float,
) -> dict[str, Any]:
    """The entries :func:`server.bench.localize.direction_summary` adds."""
    first = first_right_claim(query, localised, gt, tolerance)
    out: dict[str, Any] = {
        "first_right_localised_frame": first,
        "first_right_localised_s": None if first is None else first * frame_dt,
        "wrong_claims": wrong_claims(query, localised, gt, tolerance),
    }
    if mcl_xy:
        err = mcl_errors(query, [p[0] for p in mcl_xy], [p[1] for p in mcl_xy], gt)
        out["mcl"] = {
            "median_error_m": float(np.median(err)),
            "p90_error_m": float(np.percentile(err, 90)),
            "frames": len(err),
        }
    return out
