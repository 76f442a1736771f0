"""The localisation judge of a navigation trial and the figures bench navigate gives."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from robot_client.judge_localisation import LocalisationJudge
from robot_client.sim import load_plan
from server import schemas
from server.bench.nav_ambiguity import localisation_summary

PLAN = Path(__file__).resolve().parents[2] / "data" / "plans" / "two_rooms.json"


def _tour() -> schemas.TourGraphPublic:
    """desk (1.8, 1.75) -> sofa (6.2, 1.75): edge 7, taught facing east along y = 1.75."""
    edge = schemas.EdgePublic(
        id=7,
        source=1,
        target=2,
        source_name="desk",
        target_name="sofa",
        image_count=5,
        duration_s=4.0,
        first_image_id=1,
        last_image_id=5,
        poses=[[1.8 + k, 1.75, 0.0] for k in range(5)],
    )
    return schemas.TourGraphPublic(id=1, name="home", locations=[], edges=[edge])


def _answer(state: schemas.StateProbability | None) -> schemas.NavigationFrameResult:
    return schemas.NavigationFrameResult(
        mode="navigating",
        command=schemas.MotionCommand(v=0.0, w=0.0, ttl_s=0.5, action="navigate"),
        task=None,
        belief=schemas.BeliefPublic(
            top=[], entropy=0.0, localised=state is not None, localised_state=state
        ),
        votes={},
    )


DESK = schemas.StateProbability(kind="location", id=1, name="desk", probability=0.9)
SOFA = schemas.StateProbability(kind="location", id=2, name="sofa", probability=0.9)
EDGE = schemas.StateProbability(kind="edge", id=7, name="desk -> sofa", probability=0.9)


def test_claims_are_judged_against_the_true_pose() -> None:
    judge = LocalisationJudge(load_plan(PLAN), _tour())
    assert judge.right(DESK, 2.5, 1.75, 0.0) and judge.right(DESK, 3.5, 0.5, 0.0)  # its room
    assert not judge.right(SOFA, 3.5, 0.5, 0.0) and judge.right(SOFA, 4.5, 1.75, 0.0)
    assert judge.right(EDGE, 3.9, 2.2, 0.3)  # near the taught path, facing its way
    assert not judge.right(EDGE, 3.9, 1.75, math.pi)  # facing back: the other edge
    assert not judge.right(EDGE, 3.9, 3.0, 0.0)  # 1.25 m beside it
    other = schemas.StateProbability(kind="edge", id=8, name="sofa -> desk", probability=1.0)
    assert judge.right(other, 3.9, 1.75, 0.0) is None  # no taught poses: not judged


def test_first_right_claim_and_wrong_claims() -> None:
    judge = LocalisationJudge(load_plan(PLAN), _tour())
    frames = [
        (10.0, None),
        (10.1, SOFA),  # wrong: the robot is at the desk
        (10.2, SOFA),
        (10.3, None),
        (10.4, SOFA),  # a second wrong claim
        (10.5, DESK),  # right, 0.5 s after the start
    ]
    for t, state in frames:
        judge.observe(t, 1.8, 1.75, 0.0, _answer(state))
    s = judge.summary()
    assert s["first_correct_s"] == pytest.approx(0.5)
    assert (s["wrong_claims"], s["wrong_claim_frames"]) == (2, 3)


def test_summaries_of_a_group_of_trials() -> None:
    rows = [
        {"first_correct_s": 4.0, "wrong_claims": 0},
        {"first_correct_s": None, "wrong_claims": 2},
        {"first_correct_s": 2.0, "wrong_claims": 1},
    ]
    s = localisation_summary(rows)
    assert s["median_first_correct_s"] == 4.0 and s["mean_first_correct_s"] == 3.0
    assert (s["never_correct"], s["wrong_claims"], s["trials_with_wrong_claims"]) == (1, 3, 2)
    assert localisation_summary(rows[1:2])["median_first_correct_s"] is None
