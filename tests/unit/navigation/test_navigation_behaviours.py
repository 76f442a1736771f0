"""Each behaviour alone, on synthetic observations."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np
import pytest
from navigation_testkit import FEATURES, GRAPH, A, observation, outcome, runtime

from server.belief.model import Action, ActionKind
from server.navigation.behaviours import (
    Backoff,
    Escape,
    Explore,
    FindEdge,
    Follow,
    Stand,
    Unstick,
    follow_views,
)
from server.navigation.command import Command
from server.navigation.observation import ViewNotRequested, Views, match_views
from server.vision.homing import HomingResult

FORWARD = Command(0.3, 0.0, Action.navigate(0), None, "follow")


def homing(offset: float, n: int = 20) -> HomingResult:
    return HomingResult(offset=offset, n_matches=n, offset_px=offset * 320)


# -- follow -------------------------------------------------------------------------------------


def test_follow_homes_on_the_target_image_only_when_the_policy_navigates() -> None:
    rt = runtime()
    follow = Follow(rt)
    assert follow.propose(observation(rt, action=Action.rotate(0))) is None
    assert follow.wants(observation(rt, action=Action.explore())).offsets == frozenset()
    obs = observation(rt, action=Action.navigate(0), active_edge=0, target_image=5)
    wanted = follow.wants(obs)
    target = rt.edge_image(0, 5)
    assert wanted.offsets == {target}
    views = Views(offsets={target: homing(0.0)})  # the frame lines up with the target
    proposal = follow.propose(
        observation(rt, action=Action.navigate(0), active_edge=0, target_image=5, views=views)
    )
    assert proposal is not None
    c = proposal.command
    assert c.behaviour == "follow" and c.action == Action.navigate(0) and c.target_image == target
    assert c.v == pytest.approx(0.3) and c.w == pytest.approx(0.0)
    # the target's features a fifth of an image to the right: turns toward them
    views = Views(offsets={target: homing(0.2)})
    turned = follow.propose(
        observation(rt, action=Action.navigate(0), active_edge=0, target_image=5, views=views)
    )
    assert turned is not None and turned.command.w == pytest.approx(1.5 * 0.2)


def test_reading_a_view_not_asked_for_is_a_bug_that_fails_loudly() -> None:
    rt = runtime()
    obs = observation(rt, action=Action.navigate(0), active_edge=0, target_image=5)
    with pytest.raises(ViewNotRequested, match="not requested in wants"):
        Follow(rt).propose(obs)  # views left empty


# -- find edge ----------------------------------------------------------------------------------


def search_obs(rt, *, edge: int = 0, t: float, offset: float | None, sim: float = 0.9, **kw):
    """The robot at A turning to find ``edge``; its departure view is ``sim`` similar and
    homes at ``offset`` (None: no match)."""
    finder_views = follow_views(rt, edge, 1) | follow_views(rt, edge, 2)
    similarity = np.full(GRAPH.n_images, 0.1)
    similarity[rt.edge_image(edge, 0)] = sim
    offsets = {
        i: (None if offset is None else homing(offset))
        for i in finder_views.offsets | {rt.edge_image(edge, 0)}
    }
    scales = dict.fromkeys(finder_views.scales)
    return observation(
        rt,
        action=Action.rotate(edge),
        t=t,
        similarity=similarity,
        map_state=A,
        views=Views(offsets=offsets, scales=scales),
        **kw,
    )


def test_find_edge_spins_until_the_departure_view_lines_up_then_leaves_along_it() -> None:
    rt = runtime()
    finder = FindEdge(rt)
    spin = finder.propose(search_obs(rt, t=1.0, offset=None))
    assert spin is not None and spin.command.behaviour == "search"
    assert spin.command.v == 0 and spin.command.w == rt.params.motion.spin_w
    toward = finder.propose(search_obs(rt, t=1.1, offset=0.15))
    assert toward is not None and toward.command.behaviour == "search"
    assert 0 < toward.command.w < rt.params.motion.spin_w  # slows down toward the view
    found = finder.propose(search_obs(rt, t=1.2, offset=0.0))
    assert found is not None and found.command.behaviour == "leave"
    assert found.command.action.kind == ActionKind.NAVIGATE and finder.leaving is not None


def test_find_edge_forgets_its_search_when_the_policy_stops_asking() -> None:
    rt = runtime()
    finder = FindEdge(rt)
    finder.propose(search_obs(rt, t=1.0, offset=0.0))
    assert finder.leaving is not None
    assert finder.propose(observation(rt, action=Action.navigate(0), active_edge=0)) is None
    assert finder.leaving is None and finder.searched_rad == 0.0


def test_find_edge_explores_after_a_fruitless_turn_then_searches_afresh() -> None:
    rt = runtime()
    mp = rt.params.motion
    finder = FindEdge(rt)
    turns = math.ceil(2 * math.pi * mp.find_turns / (mp.spin_w * 0.1))
    t = 0.0
    for _ in range(turns - 1):
        t += 0.1
        assert finder.propose(search_obs(rt, t=t, offset=None)).command.behaviour == "search"
    t += 0.1
    explore = finder.propose(search_obs(rt, t=t, offset=None))
    assert explore.command.behaviour == "unstick" and explore.command.action == Action.explore()
    # it explores for unstick_s whatever the policy says, then searches from nothing
    steps = round(mp.unstick_s / 0.1)
    for _ in range(steps - 1):
        t += 0.1
        navigating = observation(rt, action=Action.navigate(0), active_edge=0, t=t)
        assert finder.propose(navigating).command.behaviour == "unstick"
    t += 0.2
    again = finder.propose(search_obs(rt, t=t, offset=None))
    assert again.command.behaviour == "search" and finder.searched_rad < 0.1


def test_find_edge_forgets_where_it_was_leaving_after_an_unstick() -> None:
    rt = runtime()
    finder = FindEdge(rt)
    finder.propose(search_obs(rt, t=1.0, offset=0.0))
    assert finder.leaving is not None
    unstuck = outcome(
        Command(0.15, 0.0, Action.explore(), None, "unstick"), "unstick", frozenset({"unsticking"})
    )
    finder.propose(search_obs(rt, t=1.1, offset=None, previous=unstuck))
    assert finder.leaving is None


def _asked_for(finder: FindEdge, rt, edge: int, similarity: np.ndarray):
    """The frame after ``finder`` lined up with edge 0 and began to leave along it: the policy
    now asks for ``edge``. Edge 0's views home dead ahead, ``edge``'s a fifth of the image to
    the side (seen, not lined up: the robot has moved on since)."""
    base = search_obs(rt, edge=edge, t=1.1, offset=0.0)
    obs = replace(base, similarity=replace(base.similarity, image=similarity))
    wanted = finder.wants(obs)
    on_0 = {rt.edge_image(0, k) for k in range(GRAPH.edges[0].n_images)}
    views = Views(
        offsets={i: homing(0.0 if i in on_0 else 0.2) for i in wanted.offsets},
        scales=dict.fromkeys(wanted.scales),
    )
    return finder.propose(replace(obs, views=views))


@pytest.mark.parametrize(
    ("alike_departures", "alike", "leaves_along"),
    [(True, True, 0), (True, False, None), (False, True, None)],
)
def test_find_edge_carries_on_when_the_vote_flips_to_a_look_alike_edge(
    alike_departures: bool, alike: bool, leaves_along: int | None
) -> None:
    """Leaving along edge 0, the policy asks for edge 2 instead (a split belief's vote
    flipping between look-alike rooms' doors). The robot carries on along edge 0 only when the
    option is on and the frame looks like edge 2's departure as well; otherwise it searches
    for edge 2 (today's behaviour)."""
    params = runtime().params
    rt = runtime(ambiguity=replace(params.ambiguity, alike_departures=alike_departures))
    finder = FindEdge(rt)
    found = finder.propose(search_obs(rt, t=1.0, offset=0.0))
    assert found.command.behaviour == "leave" and finder.leaving is not None
    similarity = np.full(GRAPH.n_images, 0.1)
    similarity[[rt.edge_image(0, k) for k in range(4)]] = 0.9  # still on edge 0's departure
    seen = rt.params.motion.found_similarity + (0.05 if alike else -0.05)
    similarity[[rt.edge_image(2, k) for k in range(4)]] = seen
    out = _asked_for(finder, rt, 2, similarity)
    if leaves_along is None:
        assert out.command.action == Action.rotate(2) and out.command.behaviour == "search"
        assert finder.leaving is None
    else:
        assert out.command.behaviour == "leave" and "looks alike" in out.reason
        assert out.command.action == Action.navigate(leaves_along)
        assert finder.leaving is not None and finder.leaving[0] == leaves_along


def _drive_along(finder: FindEdge, rt, *, t: float, seconds: float) -> float:
    """Frames of the robot driving along edge 0 (the policy navigating), then one searching."""
    leaving = outcome(Command(0.2, 0.0, Action.navigate(0), None, "leave"), "find-edge")
    for _ in range(round(seconds / 0.1)):
        t += 0.1
        navigating = observation(rt, action=Action.navigate(0), active_edge=0, t=t)
        finder.propose(replace(navigating, previous=leaving))
    return t


def test_find_edge_breaks_a_loop_of_departures_that_lose_the_edge() -> None:
    rt = runtime()
    p = rt.params
    finder = FindEdge(rt)
    searched = outcome(Command(0.0, 0.5, Action.rotate(0), None, "search"), "find-edge")
    t = 0.0
    for _ in range(p.search_departures):  # each departure lines up, drives on, loses the edge
        t += 0.1
        found = finder.propose(search_obs(rt, t=t, offset=0.0, previous=searched))
        assert found.command.behaviour == "leave"
        t = _drive_along(finder, rt, t=t, seconds=p.departure_min_s + 0.3)
        t += 0.1  # a search frame, then a flicker of the vote (shorter than departure_min_s)
        finder.propose(search_obs(rt, t=t, offset=None, previous=searched))
        t = _drive_along(finder, rt, t=t, seconds=p.departure_min_s / 2)
    t += 0.1
    looped = finder.propose(search_obs(rt, t=t, offset=0.0, previous=searched))
    assert looped.command.behaviour == "unstick" and "lost the edge" in looped.reason
    assert finder.rounds == 1 and finder.departures[0] == 0


def test_find_edge_explores_longer_each_fruitless_round_then_gives_up() -> None:
    rt = runtime(search_rounds=2)
    mp = rt.params.motion
    finder = FindEdge(rt)
    turns = math.ceil(2 * math.pi * mp.find_turns / (mp.spin_w * 0.1))
    t, explored = 0.0, []
    for _ in range(3):
        while True:
            t += 0.1
            out = finder.propose(search_obs(rt, t=t, offset=None))
            if out.command.behaviour == "unstick":
                break
        events = finder.events()
        begun = t
        while finder.propose(search_obs(rt, t=t + 0.1, offset=None)).command.behaviour == "unstick":
            t += 0.1
        explored.append(t - begun)
        if finder.rounds > rt.params.search_rounds:
            break
        assert not events
    assert turns > 0 and finder.rounds == 3
    assert explored[1] > explored[0] + mp.unstick_s / 2  # each round explores longer
    assert any(e.startswith("failed: lost") for e in events)


# -- escape -------------------------------------------------------------------------------------


def _held(rt, escape, *, depth, v=0.0, wanted=FORWARD, frames=100, t=0.0):
    """Frames of a robot whose winning behaviour wants ``wanted``; returns the proposals."""
    out = []
    previous = outcome(wanted)
    for _ in range(frames):
        t += 0.1
        proposal = escape.propose(observation(rt, t=t, v=v, depth=depth, previous=previous))
        out.append(proposal)
        chosen = proposal.command if proposal is not None else wanted
        winner = "escape" if proposal is not None else "follow"
        previous = outcome(chosen, winner, escape.events())
    return out


def test_a_robot_held_still_while_wanting_to_drive_escapes_back_turn_go() -> None:
    rt = runtime()
    p = rt.params
    depth = [3.0] * 15 + [0.2] * 16  # blocked ahead-right, open to the left
    out = _held(rt, Escape(rt), depth=depth, frames=150)
    first = next(i for i, x in enumerate(out) if x is not None)
    assert abs((first + 1) * 0.1 - p.escape_s) <= 0.11
    phases = [x.command for x in out[first:] if x is not None]
    backing = list(itertools.takewhile(lambda c: c.v < 0, phases))
    assert len(backing) == round(p.motion.backoff_s / 0.1)
    assert all(c.w > 0 for c in backing)  # toward the open side
    assert any(c.v > 0 for c in phases)  # then drives into open space
    assert all(c.behaviour == "escape" for c in phases)


def test_escape_leaves_a_moving_robot_and_docking_alone() -> None:
    rt = runtime()
    assert not any(_held(rt, Escape(rt), depth=[3.0] * 31, v=0.2))
    turning = Command(0.0, 0.5, Action.rotate(0), None, "search")
    assert not any(_held(rt, Escape(rt), depth=[3.0] * 31, wanted=turning))
    escape, t, docking = (
        Escape(rt),
        0.0,
        outcome(FORWARD, "place-dock", frozenset({"docking on purpose"})),
    )
    for _ in range(100):
        t += 0.1
        assert escape.propose(observation(rt, t=t, v=0.0, previous=docking)) is None


def test_too_many_escapes_fail_the_task_as_stuck_and_driving_on_forgives_them() -> None:
    rt = runtime(escape_tries=2)
    escape = Escape(rt)
    previous, t, escapes, failed_at = outcome(FORWARD), 0.0, 0, None
    for k in range(600):  # boxed in: nothing it does moves it
        t += 0.1
        proposal = escape.propose(observation(rt, t=t, v=0.0, depth=[0.2] * 31, previous=previous))
        escapes += proposal is not None and previous.winner != "escape"
        if any(e.startswith("failed: stuck") for e in escape.events()):
            failed_at = k
            break
        chosen = (proposal.command, "escape") if proposal is not None else (FORWARD, "follow")
        previous = outcome(*chosen, escape.events())
    assert escapes == 2 and failed_at is not None  # two escapes, then it gives up
    rt2 = runtime(escape_tries=2)
    forgiving = Escape(rt2)
    _held(rt2, forgiving, depth=[0.2] * 31, frames=60)
    assert forgiving.tries == 1
    _held(rt2, forgiving, depth=[3.0] * 31, v=0.3, frames=80, t=10.0)  # free, 0.6 m after it
    assert forgiving.tries == 0


def test_a_bump_back_off_counts_as_an_escape_try() -> None:
    rt = runtime(escape_tries=1)
    escape = Escape(rt)
    bumped = outcome(
        Command(-0.1, 0.5, Action.do_nothing(), None, "backoff"), "backoff", frozenset({"bumped"})
    )
    escape.propose(observation(rt, t=0.1, previous=bumped))
    assert escape.tries == 1 and not escape.events()
    escape.propose(observation(rt, t=0.2, previous=bumped))
    assert any(e.startswith("failed: stuck") for e in escape.events())


# -- explore, stand --------------------------------------------------------------------------------


def test_explore_heads_for_open_space_only_when_the_policy_explores() -> None:
    rt = runtime()
    assert Explore(rt).propose(observation(rt, action=Action.rotate(0))) is None
    depth = [0.5] * 15 + [3.0] * 16  # open to the right
    p = Explore(rt).propose(observation(rt, action=Action.explore(), depth=depth))
    assert p is not None and p.command.behaviour == "explore"
    assert p.command.v > 0 and p.command.w < 0


def test_stand_always_proposes_standing_with_the_policy_s_action() -> None:
    rt = runtime()
    p = Stand(rt).propose(observation(rt, action=Action.do_nothing()))
    assert p is not None and (p.command.v, p.command.w) == (0.0, 0.0)
    assert p.command.action == Action.do_nothing()


# -- unstick -------------------------------------------------------------------------------------


def test_the_stall_watchdog_explores_after_stall_s_with_little_driven_then_stops() -> None:
    rt = runtime()
    p = rt.params
    watchdog = Unstick(rt)
    t, fired = 0.0, None
    for k in range(int(p.stall_s / 0.1) + 5):
        t += 0.1
        out = watchdog.propose(observation(rt, t=t, v=0.0))
        if out is not None:
            fired = k
            break
    assert fired is not None and abs((fired + 1) * 0.1 - p.stall_s) <= 0.11
    assert out.command.behaviour == "unstick" and "unsticking" in watchdog.events()
    for _ in range(round(p.motion.unstick_s / 0.1) - 1):
        t += 0.1
        assert watchdog.propose(observation(rt, t=t, v=0.15)) is not None
    t += 0.2
    assert watchdog.propose(observation(rt, t=t, v=0.15)) is None


def test_the_stall_watchdog_leaves_a_moving_robot_alone_and_forgives_backing_off() -> None:
    rt = runtime()
    watchdog = Unstick(rt)
    for k in range(400):
        assert watchdog.propose(observation(rt, t=0.1 * (k + 1), v=0.2)) is None
    still = Unstick(rt)
    bumped = outcome(
        Command(-0.1, 0.5, Action.do_nothing(), None, "backoff"), "backoff", frozenset({"bumped"})
    )
    for k in range(400):  # standing still, but each frame after a bump restarts the window
        assert still.propose(observation(rt, t=0.1 * (k + 1), v=0.0, previous=bumped)) is None


# -- back off ------------------------------------------------------------------------------------


def test_a_robot_pressed_against_something_backs_off_toward_the_open_side() -> None:
    rt = runtime()
    p = rt.params
    reflex = Backoff(rt)
    depth = [3.0] * 15 + [0.6] * 16  # open to the left
    t, fired = 0.0, None
    for k in range(30):
        t += 0.1
        out = reflex.propose(observation(rt, t=t, v=0.0, depth=depth, previous=outcome(FORWARD)))
        if out is not None:
            fired = k
            break
    assert fired is not None and abs((fired + 1) * 0.1 - p.bump_s) <= 0.11
    assert "bumped" in reflex.events()
    assert out.command.v == -p.motion.backoff_v and out.command.w > 0
    backing = outcome(out.command, "backoff")
    for _ in range(round(p.motion.backoff_s / 0.1) - 1):
        t += 0.1
        again = reflex.propose(observation(rt, t=t, v=-0.1, depth=depth, previous=backing))
        assert again is not None and again.command.behaviour == "backoff"
        assert "bumped" not in reflex.events()


def test_no_bump_while_the_robot_was_not_told_to_drive_forward() -> None:
    rt = runtime()
    reflex = Backoff(rt)
    turning = outcome(Command(0.0, 0.5, Action.rotate(0), None, "search"), "find-edge")
    for k in range(50):
        assert reflex.propose(observation(rt, t=0.1 * (k + 1), v=0.0, previous=turning)) is None


def test_follow_views_are_exactly_what_follow_reads() -> None:
    rt = runtime()
    for edge in range(GRAPH.n_edges):
        for k in range(GRAPH.edges[edge].n_images):
            image = np.zeros((240, 320, 3), np.uint8)
            views = match_views(rt, image, FEATURES[0], follow_views(rt, edge, k))
            obs = observation(
                rt, action=Action.navigate(edge), active_edge=edge, target_image=k, views=views
            )
            assert Follow(rt).propose(obs) is not None
