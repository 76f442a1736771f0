"""Settling on a place's taught spot after a departure from it lost its edge."""

from __future__ import annotations

import numpy as np
from navigation_testkit import GRAPH, A, B, observation, outcome, runtime

from server.belief.model import Action
from server.navigation.command import Command
from server.navigation.observation import Views
from server.navigation.settle import OFF_PLACE_FRAMES, Settle
from server.vision.homing import ScaleResult

LEFT_A = outcome(Command(0.2, 0.0, Action.navigate(0), 3, "leave"), "find-edge")
"""The last frame drove onto edge 0 (A -> B) from A."""
SEARCHED = outcome(Command(0.0, 0.5, Action.rotate(0), None, "search"), "find-edge")
"""The last frame turned, searching for edge 0."""


def depart(rt, settle: Settle, *, seconds: float, t: float = 0.0) -> float:
    """Frames driving along edge 0 from A for ``seconds`` (the policy navigating)."""
    for _ in range(round(seconds / 0.1)):
        t += 0.1
        driving = observation(rt, action=Action.navigate(0), active_edge=0, t=t, previous=LEFT_A)
        assert settle.propose(driving) is None
    return t


def fit(scale: float, offset: float = 0.0, inliers: int = 40) -> ScaleResult:
    return ScaleResult(scale=scale, rotation=0.0, inliers=inliers, n_matches=60, offset=offset)


def settle_obs(
    rt, settle: Settle, *, t: float, scale: float | None, previous=None, at: int = A, **kw
):
    """The policy wants edge 0 from A, the belief at ``at``; every spin view the settler asks
    for fits at ``scale`` (None: nothing fits)."""
    probe = observation(rt, action=Action.rotate(0), map_state=at, t=t, previous=previous, **kw)
    wanted = settle.wants(probe)
    zoomed = {i: (None if scale is None else fit(scale)) for i in wanted.zoomed}
    return observation(
        rt,
        action=Action.rotate(0),
        map_state=at,
        t=t,
        previous=previous,
        views=Views(zoomed=zoomed, taught_zoomed=zoomed),
        **kw,
    )


def test_no_settling_without_a_lost_departure_from_the_place() -> None:
    rt = runtime()
    settle = Settle(rt)
    assert settle.propose(settle_obs(rt, settle, t=1.0, scale=1.0)) is None
    t = depart(rt, settle, seconds=0.5, t=1.0)  # a flicker of the vote: not a departure
    assert settle.propose(settle_obs(rt, settle, t=t + 0.1, scale=1.3, previous=SEARCHED)) is None
    t = depart(rt, settle, seconds=1.5, t=t + 0.1)
    assert settle.departed == set()  # still driving along it
    assert settle.propose(settle_obs(rt, settle, t=t + 0.1, scale=1.3, previous=SEARCHED))


def test_after_a_lost_departure_it_creeps_onto_the_spot_then_hands_back() -> None:
    rt = runtime()
    p = rt.params
    settle = Settle(rt)
    t = depart(rt, settle, seconds=1.5)
    first = settle.propose(settle_obs(rt, settle, t=t + 0.1, scale=1.3, previous=SEARCHED))
    assert first is not None and first.command.behaviour == "settle"
    assert first.command.v == p.motion.dock_v  # the view looks smaller than taught: creep on
    assert first.command.target_image in set(rt.spin_images[A].tolist())
    assert {"settling", "docking on purpose"} <= settle.events()
    t, previous, moves = t + 0.1, outcome(first.command, "settle"), []
    for _ in range(5):  # fits at the taught scale: once three agree, settled
        t += 0.1
        out = settle.propose(settle_obs(rt, settle, t=t, scale=1.0, previous=previous))
        if out is None:
            break
        moves.append(out.command.v)
        previous = outcome(out.command, "settle")
    assert out is None and settle.place is None and not settle.events()


def test_it_looks_round_for_a_spin_view_and_gives_up_after_the_turns() -> None:
    rt = runtime()
    p = rt.params
    settle = Settle(rt)
    t, previous, frames = depart(rt, settle, seconds=1.5) + 0.1, SEARCHED, 0
    while True:
        out = settle.propose(settle_obs(rt, settle, t=t, scale=None, previous=previous))
        if out is None:
            break
        assert out.command.v == 0.0 and out.command.w == p.motion.spin_w
        previous, t, frames = outcome(out.command, "settle"), t + 0.1, frames + 1
    turned = frames * p.motion.spin_w * 0.1
    assert abs(turned - 2 * np.pi * p.place_dock_turns) <= p.motion.spin_w * 0.2


def test_settling_stops_when_the_belief_leaves_the_place_and_is_bounded_per_place() -> None:
    rt = runtime(settle_tries=1)
    settle = Settle(rt)
    t = depart(rt, settle, seconds=1.5)
    assert settle.propose(settle_obs(rt, settle, t=t + 0.1, scale=1.3, previous=SEARCHED))
    previous = outcome(Command(0.12, 0.0, Action.do_nothing(), None, "settle"), "settle")
    for k in range(OFF_PLACE_FRAMES + 1):
        elsewhere = settle_obs(rt, settle, t=t + 0.2 + 0.1 * k, scale=1.3, previous=previous, at=B)
        out = settle.propose(elsewhere)
    assert out is None and settle.place is None
    # a second lost departure from A: no more settling there in this task
    t = depart(rt, settle, seconds=1.5, t=9.0)
    assert settle.propose(settle_obs(rt, settle, t=t + 0.1, scale=1.3, previous=SEARCHED)) is None
    assert GRAPH.edges[0].source == A
