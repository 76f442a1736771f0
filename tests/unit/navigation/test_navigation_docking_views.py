"""Docking asks only for the views its frame will read: none during a quarter turn that the
frame does not end, the target only while creeping (a frame that asks for nothing zooms
nothing: four corner extractions saved)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from navigation_testkit import WALLS, B, observation, outcome, room_profile, runtime

from server.belief.model import Action
from server.navigation.command import Command
from server.navigation.docking import Docking
from server.navigation.observation import Observation, ViewRequest, Views
from server.vision.homing import ScaleResult


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


def creeping_on(depth_ahead: float | None, scale: float) -> tuple[float, str]:
    """Place docking creeping on a spin view whose scale reads ``scale`` (many inliers), the
    frame's depth profile taken ``depth_ahead`` m ahead of where the view's was (``None``: no
    depth): the command's speed and its reason."""
    rt = runtime()
    target = int(rt.spin_images[B][1])
    taught = np.array([1.2, 1.4, 0.1])
    rt.taught_depth[target] = room_profile(*taught, walls=WALLS).astype(np.float32)
    docking = Docking(rt, B)
    docking.placing.start("creep")
    docking.placing.target = target
    fit = ScaleResult(scale=scale, rotation=0.0, inliers=60, n_matches=80, offset=0.0)
    depth = None
    if depth_ahead is not None:
        x, y, th = taught + depth_ahead * np.array([math.cos(0.1), math.sin(0.1), 0.0])
        depth = list(room_profile(x, y, th, walls=WALLS))
    obs = observation(rt, goal=B, at_goal=True, depth=depth, views=Views(zoomed={target: fit}))
    proposal = docking.place(obs)
    assert proposal is not None
    return proposal.command.v, proposal.reason


def test_a_view_that_says_there_does_not_settle_where_the_depth_says_it_is_not() -> None:
    """A floor that repeats every 2 m showed the taught scale (1.00, 34-79 inliers) 2 m off
    the spot: the depth profiles keep docking going; where the scale says short or past, or
    the depth agrees within ``dock_depth_m``, the scale decides."""
    v, why = creeping_on(-0.8, scale=1.0)
    assert v > 0 and "smaller" in why
    v, why = creeping_on(0.7, scale=1.0)
    assert v < 0 and "larger" in why
    v, why = creeping_on(0.1, scale=1.0)
    assert v == 0.0 and "agree" in why
    v, _ = creeping_on(0.0, scale=1.3)
    assert v > 0


def test_without_depth_the_views_scale_decides() -> None:
    v, _ = creeping_on(None, scale=1.3)
    assert v > 0
    v, why = creeping_on(None, scale=1.0)
    assert v == 0.0 and "agree" in why
