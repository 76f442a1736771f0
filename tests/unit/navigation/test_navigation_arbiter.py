"""The arbiter's order of precedence (a table test) and obstacle avoidance's guarantees."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from navigation_testkit import observation, runtime

from server.belief.model import Action
from server.motion import MotionParams
from server.navigation.arbiter import PRECEDENCE, Avoid, NoProposal, arbitrate
from server.navigation.command import Command, Proposal


def proposal(name: str) -> Proposal:
    return Proposal(Command(0.0, 0.0, Action.do_nothing(), None, name), f"{name} says so")


# (behaviours proposing, winner): the order of precedence written out
TABLE = [
    ({"backoff", "place-dock", "unstick", "find-edge", "follow", "explore", "stand"}, "backoff"),
    ({"place-dock", "unstick", "find-edge", "follow", "stand"}, "place-dock"),
    ({"unstick", "find-edge", "follow", "explore", "stand"}, "unstick"),
    ({"find-edge", "follow", "explore", "stand"}, "find-edge"),
    ({"follow", "explore", "stand"}, "follow"),
    ({"explore", "stand"}, "explore"),
    ({"stand"}, "stand"),
    ({"backoff", "stand"}, "backoff"),
    ({"unstick", "stand"}, "unstick"),
]


@pytest.mark.parametrize(("proposing", "winner"), TABLE)
def test_the_first_behaviour_in_precedence_with_a_proposal_wins(
    proposing: set[str], winner: str
) -> None:
    proposals = {n: (proposal(n) if n in proposing else None) for n in PRECEDENCE}
    name, chosen = arbitrate(proposals)
    assert name == winner and chosen.command.behaviour == winner


def test_every_pair_is_ordered_as_written() -> None:
    for high, low in itertools.combinations(PRECEDENCE, 2):
        assert arbitrate({high: proposal(high), low: proposal(low)})[0] == high


def test_no_proposal_and_unknown_behaviours_are_errors() -> None:
    with pytest.raises(NoProposal, match="'stand' always should"):
        arbitrate({n: None for n in PRECEDENCE})
    with pytest.raises(ValueError, match="no place in PRECEDENCE"):
        arbitrate({"dance": proposal("dance")})


depths = st.lists(st.floats(0.05, 6.0) | st.just(float("inf")), min_size=3, max_size=31)


@given(
    depth=depths,
    v=st.floats(-0.4, 0.4),
    w=st.floats(-1.0, 1.0),
    side=st.sampled_from([-1, 0, 1]),
)
def test_avoidance_never_drives_forward_into_a_near_obstacle_and_stays_in_limits(
    depth: list[float], v: float, w: float, side: int
) -> None:
    mp = MotionParams()
    avoid = Avoid(mp)
    avoid.side = side
    obs = observation(runtime(), depth=depth)
    avoid.look(obs)
    out = avoid.apply(Command(v, w, Action.navigate(0)), obs)
    assert abs(out.v) <= max(abs(v), 0.0) + 1e-12 and abs(out.w) <= mp.max_w + 1e-12
    if min(depth) <= mp.avoid_full_m:
        assert out.v <= 0.0
    if v <= 0:
        assert (out.v, out.w) == (v, w)  # turning on the spot and backing are left alone


def test_avoidance_keeps_turning_the_way_it_chose_while_the_obstacle_stays() -> None:
    mp = MotionParams()
    avoid = Avoid(mp)
    rt = runtime()
    left_open = [2.0] * 10 + [0.4] * 11 + [1.5] * 10  # left a little more open
    avoid.look(observation(rt, depth=left_open))
    assert avoid.side == 1
    right_open = [1.6] * 10 + [0.4] * 11 + [1.8] * 10  # now the right is a little more open
    avoid.look(observation(rt, depth=right_open))
    assert avoid.side == 1  # not by avoid_switch_m: it keeps its side
    avoid.look(observation(rt, depth=[6.0] * 31))
    assert avoid.side == 0
    assert np.isfinite(avoid.apply(Command(0.3, 0.0, Action.navigate(0)), observation(rt)).v)
