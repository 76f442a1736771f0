"""Docking asks only for the views its frame will read: none during a quarter turn that the
frame does not end, the target only while creeping (a frame that asks for nothing zooms
nothing: four corner extractions saved)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from navigation_testkit import B, observation, outcome, runtime

from server.belief.model import Action
from server.navigation.command import Command
from server.navigation.docking import Docking
from server.navigation.observation import Observation, ViewRequest, Views


def turning(
    rad: float, w: float, at_goal: bool, away_rad: float = 0.0
) -> tuple[Docking, Observation]:
    rt = runtime()
    docking = Docking(rt, B)
    docking.placing.start("turn")
    docking.placing.rad, docking.placing.away_rad = rad, away_rad
    turn = Command(0.0, w, Action.do_nothing(), None, "place-dock")
    obs = observation(rt, goal=B, at_goal=at_goal, previous=outcome(turn, "place-dock"))
    return docking, obs


@settings(max_examples=40, deadline=None)
@given(
    rad=st.floats(0.0, 2.0),
    w=st.floats(0.0, 1.5),
    at_goal=st.booleans(),
    away=st.floats(0.0, 4.0),
)
def test_a_turn_this_frame_does_not_end_reads_no_view(
    rad: float, w: float, at_goal: bool, away: float
) -> None:
    """Reference: the frame's place and confirm run on no views at all whenever wants asks
    for none (ViewNotRequested otherwise); and wants asks for none exactly when the quarter
    turn goes on."""
    docking, obs = turning(rad, w, at_goal, away)
    request = docking.wants(obs)
    ends = not rad + w * 0.1 < math.pi / 2
    assert (request == ViewRequest()) == (not ends)
    if request == ViewRequest():
        obs = replace(obs, views=Views())
        placing = docking.place(obs)
        assert docking.confirm(obs, placing is not None) == (None, False)


def test_creeping_asks_for_its_target_only() -> None:
    rt = runtime()
    docking = Docking(rt, B)
    docking.placing.start("creep")
    docking.placing.target = int(rt.spin_images[B][1])
    obs = observation(rt, goal=B, at_goal=True)
    assert docking.wants(obs) == ViewRequest(zoomed=frozenset({docking.placing.target}))


def test_looking_still_asks_for_the_spin_views() -> None:
    rt = runtime()
    docking = Docking(rt, B)
    docking.placing.start("look")
    obs = observation(rt, goal=B, at_goal=True, similarity=np.linspace(0, 1, rt.graph.n_images))
    assert docking.wants(obs).zoomed >= set(int(i) for i in rt.spin_images[B][-3:])
