"""Localisation figures of ``teachrepeat bench localize`` beyond recall (docs/ambiguity.md): how
soon the tracker is rightly "localised" from its uniform start and how often it claims a wrong
place.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from server.bench.localize import GroundTruth


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


def figures(
    query: Sequence[int],
    localised: Sequence[tuple[int, ...] | None],
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
    return out
