"""Place docking with a depth sensor: the robot docks on a place by its depth profiles only
and otherwise turns, then hands over to the round trip (the views' scale settled 1.4-2 m off
on floors whose texture repeats); without depth the views' scale docks as before."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from navigation_testkit import B, D, observation, runtime

from server.belief.model import Action
from server.navigation.command import Command
from server.navigation.docking import Docking
from server.navigation.observation import Observation, ViewRequest, Views
from server.vision.homing import ScaleResult

LINED_UP = ScaleResult(scale=1.0, rotation=0.0, inliers=40, n_matches=60, offset=0.0)
"""A spin view in sight, lined up, at the taught scale: the views' scale would dock here."""
FLAT = [3.0] * 31
"""A depth profile the synthetic tour's places have no profiles for: the depth finds no spot."""


def looking(depth: list[float] | None, rad: float = 0.0) -> tuple[Docking, Observation]:
    """Place docking looking, ``rad`` turned so far, every spin view of the goal lined up."""
    rt = runtime()
    docking = Docking(rt, B)
    docking.placing.start("look")
    docking.placing.rad = docking.placing.turned = rad
    fits = {int(i): LINED_UP for i in rt.spin_images[B]}
    views = Views(zoomed=fits, taught_zoomed=fits)
    return docking, observation(rt, goal=B, at_goal=True, depth=depth, views=views)


@pytest.mark.parametrize("rad", [0.0, 1.0, 7.0, 8.0])
def test_with_depth_the_robot_turns_for_the_depth_until_its_budget(rad: float) -> None:
    docking, obs = looking(FLAT, rad)
    proposal = docking.place(obs)
    if rad < 2 * math.pi * docking.p.place_dock_turns:
        assert proposal is not None and proposal.command.w != 0.0
        assert proposal.command.v == 0.0 and docking.placing.phase == "look"
        assert "depth" in proposal.reason
    else:  # nothing found in the turns allowed: the round trip takes over
        assert proposal is None and docking.placing.phase == "off"


def test_the_budget_counts_every_turn_since_docking_started() -> None:
    """A spot found and lost again starts the look afresh (its ``rad`` at 0): the turns before
    still count, and the round trip takes over (a robot turned for 75 s at the couch)."""
    docking, obs = looking(FLAT)
    docking.placing.turned = 2 * math.pi * docking.p.place_dock_turns
    assert docking.place(obs) is None and docking.placing.phase == "off"


def test_without_depth_the_views_scale_docks() -> None:
    docking, obs = looking(None)
    proposal = docking.place(obs)
    assert proposal is not None and docking.placing.phase == "creep"


def test_looking_by_the_depth_asks_for_no_spin_view_and_reads_none() -> None:
    """The look reads no spin view with depth, so it asks for none (no zooms made): the frame
    runs on no views at all and turns (a view read unasked would raise)."""
    docking, obs = looking(FLAT)
    assert docking.wants(obs) == ViewRequest()
    proposal = docking.place(replace(obs, views=Views()))
    assert proposal is not None and docking.placing.phase == "look"


def test_a_goal_with_no_round_trip_is_docked_on_before_it_counts_as_arrived() -> None:
    """D has no taught edge: its approach is waived (no round trip to come in by). The belief
    at D no longer says "arrived" alone: place docking looks for D's views first (a robot
    carried into a corridor "arrived" at a dead-end office 5.2 m away on the belief alone).
    Had the robot come in along an edge, docking along that edge would decide instead."""
    rt = runtime()
    docking = Docking(rt, D)
    assert not docking.needs_approach and docking.approach.done
    fits = {int(i): LINED_UP for i in rt.spin_images[D]}
    obs = observation(rt, goal=D, at_goal=True, views=Views(zoomed=fits, taught_zoomed=fits))
    proposal = docking.place(obs)
    assert proposal is not None and docking.placing.phase != "idle"
    assert docking.confirm(obs, placing=True) == (None, False)
    came_in = Docking(rt, D)
    came_in.approach.edge = 0  # (an edge of the synthetic tour; D's own would do the same)
    assert came_in.place(obs) is None and came_in.placing.phase == "idle"


def test_a_goal_with_no_round_trip_docks_afresh_after_the_robot_has_moved_on() -> None:
    """Place docking at D given up (``off``) lets the belief's word stand while the robot
    stays; once it has driven elsewhere, the next stay at D docks afresh (kept, the belief at
    a dead-end office for four frames said "arrived" 4 m from it, 160 frames after a docking
    given up in the corridor, ``bench carried`` seed 4). Standing still keeps the verdict."""
    rt = runtime()
    docking = Docking(rt, D)
    fits = {int(i): LINED_UP for i in rt.spin_images[D]}
    obs = observation(rt, goal=D, at_goal=True, views=Views(zoomed=fits, taught_zoomed=fits))
    docking.placing.phase = "off"
    assert docking.confirm(obs, placing=False) == (None, True)
    docking.track(Command(0.0, 0.0, Action.do_nothing()), 0.1)
    assert docking.placing.phase == "off"
    docking.track(Command(0.2, 0.0, Action.navigate(0)), 0.1)
    assert docking.placing.phase == "idle"
    proposal = docking.place(obs)
    assert proposal is not None and docking.placing.phase != "idle"
    assert docking.confirm(obs, placing=True) == (None, False)
