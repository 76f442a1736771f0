"""TaughtTruth (the judge's taught paths): the distance from a path and where a path
estimate puts the robot, against hand-computed points."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robot_client.trial import TaughtTruth

# an L: 2 m east, a turn on the spot to face north, 1 m north
POSES = np.array(
    [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [2.0, 0.0, 0.0],
        [2.0, 0.0, math.pi / 2],
        [2.0, 1.0, math.pi / 2],
    ]
)
TRUTH = TaughtTruth({3: POSES, 4: POSES[:1]})


@pytest.mark.parametrize(
    ("along", "lateral", "point"),
    [
        (0.0, 0.0, (0.0, 0.0)),
        (1.5, 0.0, (1.5, 0.0)),
        (1.5, 0.4, (1.5, 0.4)),  # left of east is north
        (1.5, -0.4, (1.5, -0.4)),
        (2.5, 0.3, (1.7, 0.5)),  # north leg: left is west
        (9.0, 0.0, (2.0, 1.0)),  # clamped to the end
        (-1.0, 0.0, (0.0, 0.0)),  # and to the start
    ],
)
def test_locate_puts_the_estimate_on_the_true_path(
    along: float, lateral: float, point: tuple[float, float]
) -> None:
    assert TRUTH.locate(3, along, lateral) == pytest.approx(point)


def test_locate_on_a_path_without_length_uses_the_heading_taught_there() -> None:
    assert TRUTH.locate(4, 0.0, 0.5) == pytest.approx((0.0, 0.5))
    assert TRUTH.locate(99, 0.0, 0.0) is None


def test_a_located_estimate_is_as_far_from_the_path_as_its_lateral_offset() -> None:
    rng = np.random.default_rng(3)
    for along, lateral in zip(rng.uniform(0.1, 1.9, 20), rng.uniform(-0.5, 0.5, 20), strict=True):
        x, y = TRUTH.locate(3, float(along), float(lateral))
        assert TRUTH.error(3, x, y) == pytest.approx(abs(lateral), abs=1e-9)
