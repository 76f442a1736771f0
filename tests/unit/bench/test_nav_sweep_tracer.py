"""The trace a traced ``bench navigate`` trial writes (``nav_sweep.tracer``): the path
estimate next to the judge's truth, how far from its path and from where it puts the robot."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from robot_client.trial import TaughtTruth
from server.bench.nav_sweep import tracer

TRUTH = TaughtTruth({5: np.array([[0.0, 0.0, 0.0], [4.0, 0.0, 0.0]])})


def result(along: float, lateral: float) -> SimpleNamespace:
    command = SimpleNamespace(
        action="navigate",
        behaviour="follow",
        reason="tracking",
        edge=5,
        target_image_id=12,
        v=0.3,
        w=0.0,
    )
    path = SimpleNamespace(
        edge=5,
        along_m=along,
        lateral_m=lateral,
        heading_error=0.0,
        sigma_along_m=0.05,
        sigma_lateral_m=0.03,
        sigma_heading=0.02,
        locked=True,
    )
    belief = SimpleNamespace(
        top=[SimpleNamespace(name="hall -> den", probability=0.9)],
        appearance=[1.0],
        light_change=0.0,
    )
    return SimpleNamespace(command=command, path=path, belief=belief)


def test_the_trace_says_how_far_the_estimate_puts_the_robot_from_where_it_is() -> None:
    robot = SimpleNamespace(pose=SimpleNamespace(x=1.0, y=0.2, theta=0.0), now=lambda: 3.0)
    rows: list[dict] = []
    hook = tracer(robot, rows, TRUTH)
    hook(1, result(1.0, 0.2))  # right
    hook(2, result(3.0, 0.2))  # 2 m wrong along the path, as near to it
    hook(3, result(1.0, -0.3))  # 0.5 m wrong across it
    errors = [(r["path"]["true_error"], r["path"]["estimate_error"]) for r in rows]
    assert errors == [pytest.approx((0.2, 0.0)), pytest.approx((0.2, 2.0)), (0.2, 0.5)]
    untold: list[dict] = []
    tracer(robot, untold)(1, result(1.0, 0.2))  # no truth: neither
    assert untold[0]["path"]["true_error"] is None
    assert untold[0]["path"]["estimate_error"] is None
