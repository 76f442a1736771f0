"""At the tracked end of the path into the goal, the depth straight ahead against what was taught
there (``TopometricParams.end_depth``, :func:`server.navigation.docking.seen_further`): a robot
that sees further than the taught spot did stands short of it and creeps on."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from navigation_testkit import FOV, RAYS, B, observation, path_estimate, room_profile, runtime

from server.belief.model import Action
from server.navigation.command import Command
from server.navigation.docking import Docking, seen_further
from server.navigation.pathtrack import TopometricParams
from server.navigation.runtime import TourRuntime

REACH = 3.9
CORRIDOR = [(-10.0, -0.8, 20.0, -0.8), (-10.0, 0.8, 20.0, 0.8), (3.5, -0.8, 3.5, 0.8)]
"""A corridor 1.6 m wide along +x, its end wall 3.5 m from the taught spot at the origin."""


def naive(
    depth: np.ndarray, taught: np.ndarray, turn: float, half_angle: float, reach: float
) -> float | None:
    """Ray by ray: each ray near straight ahead against the taught rays either side of its
    direction (interpolated when both saw a surface, else the nearer one's)."""
    n, m = len(depth), len(taught)
    half = math.radians(FOV) / 2
    step = 2 * half / (m - 1)

    def seen(r: float) -> bool:
        return bool(np.isfinite(r) and r < reach)

    diffs = []
    for i in range(n):
        a = half - i * (2 * half / (n - 1))
        at = (half - (a + turn)) / step
        if abs(a) > half_angle or not -0.5 < at < m - 0.5:
            continue
        lo = min(max(math.floor(at), 0), m - 2)
        f = min(max(at - lo, 0.0), 1.0)
        if seen(taught[lo]) and seen(taught[lo + 1]):
            then = (1 - f) * taught[lo] + f * taught[lo + 1]
        else:
            j = min(max(round(at), 0), m - 1)
            if not seen(taught[j]):
                continue
            then = taught[j]
        diffs.append(depth[i] - then if seen(depth[i]) else math.inf)
    return None if len(diffs) < 3 else float(np.median(diffs))


ranges = st.one_of(st.floats(0.1, 5.0), st.just(math.inf))


@settings(max_examples=200, deadline=None)
@given(
    depth=st.lists(ranges, min_size=RAYS, max_size=RAYS),
    taught=st.lists(ranges, min_size=RAYS, max_size=RAYS),
    turn=st.floats(-1.0, 1.0),
    half_angle=st.floats(0.05, 0.8),
)
def test_equals_the_ray_by_ray_reference(
    depth: list[float], taught: list[float], turn: float, half_angle: float
) -> None:
    d, t = np.array(depth), np.array(taught)
    got = seen_further(d, t, turn, fov_deg=FOV, half_angle_rad=half_angle, max_range_m=REACH)
    want = naive(d, t, turn, half_angle, REACH)
    assert (got is None) == (want is None)
    if got is not None and want is not None:
        assert got == pytest.approx(want)


def further(x: float, th: float = 0.0, taught_th: float = 0.0) -> float | None:
    """A robot at ``x`` along the corridor, facing ``th``, against the view taught at 0."""
    now = room_profile(x, 0.0, th, walls=CORRIDOR)
    was = room_profile(0.0, 0.0, taught_th, walls=CORRIDOR)
    return seen_further(
        now, was, th - taught_th, fov_deg=FOV, half_angle_rad=0.15, max_range_m=REACH
    )


@pytest.mark.parametrize("turn", [0.0, 0.05, -0.08])
def test_in_a_corridor_it_reads_how_far_short_of_the_spot(turn: float) -> None:
    """The end wall 3.5 m ahead of the taught spot: 0.3 m short reads about 0.3 m; on the spot
    about 0; 0.5 m past, about -0.5; so far back that the wall is beyond reach, ``inf``. The
    rays compared look the same way, so a robot facing a little off reads the same (facing
    further off, the rays ahead meet the corridor's sides, which look alike from anywhere
    along it: :func:`test_rays_on_the_sides_cannot_tell`)."""
    assert further(0.0, turn) == pytest.approx(0.0, abs=0.02)
    assert further(-0.3, turn) == pytest.approx(0.3, abs=0.05)
    assert further(0.5, turn) == pytest.approx(-0.5, abs=0.05)
    assert further(-1.0, turn) == math.inf


def test_rays_on_the_sides_cannot_tell() -> None:
    """Facing 0.3 rad off, the rays ahead meet the corridor's side wall, the same from 0.3 m
    back: short of the spot or on it, the same reading (0)."""
    assert further(-0.3, 0.3) == pytest.approx(0.0, abs=0.02)


def test_it_cannot_tell_where_the_taught_view_saw_nothing_ahead() -> None:
    open_ahead = [(-10.0, -0.8, 20.0, -0.8), (-10.0, 0.8, 20.0, 0.8)]
    now = room_profile(-1.0, 0.0, 0.0, walls=open_ahead)
    was = room_profile(0.0, 0.0, 0.0, walls=open_ahead)
    assert seen_further(now, was, 0.0, fov_deg=FOV, half_angle_rad=0.15, max_range_m=REACH) is None
    # facing so far off that no ray ahead has a taught ray looking its way
    was = room_profile(0.0, 0.0, 0.0, walls=CORRIDOR)
    assert seen_further(was, was, 1.5, fov_deg=FOV, half_angle_rad=0.15, max_range_m=REACH) is None


def at_the_end(rt: TourRuntime, *, x: float, depth: bool = True) -> tuple[Docking, object]:
    """Docking on B, approached along edge 0 (A -> B, along +x), the tracker locked at its end;
    the taught arrival view of edge 0 saw the corridor's end wall 3.5 m ahead; the robot stands
    ``x`` metres along the corridor from the taught spot."""
    path = rt.paths[0]
    k = rt.arrival[0]
    rt.taught_depth[rt.edge_image(0, k)] = room_profile(0.0, 0.0, 0.0, walls=CORRIDOR).astype(
        np.float32
    )
    docking = Docking(rt, B)
    docking.approach.done, docking.approach.edge = True, 0
    est = path_estimate(along=path.length, image=rt.edge_image(0, k), index=k, length_m=path.length)
    obs = observation(
        rt,
        action=Action.navigate(0),
        active_edge=0,
        goal=B,
        at_goal=True,
        depth=list(room_profile(x, 0.0, 0.0, walls=CORRIDOR)) if depth else None,
    )
    return docking, replace(obs, path=est)


def test_short_of_the_spot_by_its_depth_it_creeps_on_until_it_sees_what_was_taught() -> None:
    """The tracker says "at the end" (the place's depth finds no spot in a corridor) while the
    robot stands 2 m short, seeing nothing where the taught view saw the end wall: it creeps on
    the way taught, and arrives once what it sees ahead is as far as taught (within 0.2 m)."""
    rt = runtime()
    docking, obs = at_the_end(rt, x=-2.0)
    for _ in range(5):  # the place's depth profiles are given their frames first
        proposal, arrived = docking.confirm(obs, False)
        if proposal is None or proposal.command.v > 0:
            break
    assert not arrived and proposal is not None
    assert proposal.command.v > 0 and "short of the goal: sees nothing ahead" in proposal.reason
    x = -2.0
    for _ in range(400):
        x += proposal.command.v * obs.dt
        _, here = at_the_end(rt, x=x)
        proposal, arrived = docking.confirm(here, False)
        if arrived:
            break
    assert arrived and -0.25 <= x <= 0.0, x
    # there it stays, though the tracker, short by what the robot crept, puts the end 0.5 m
    # beside it (it drove the robot back there, and the arrival was never counted)
    _, here = at_the_end(rt, x=x)
    assert here.path is not None
    aside = replace(here.path, lateral_m=0.5, pose=np.array([here.path.pose[0], -0.5, 0.0]))
    assert docking.confirm(replace(here, path=aside), False) == (None, True)
    # until the robot moves on: the next approach checks afresh
    docking.track(Command(0.0, 0.5, Action.rotate(2), None, "search"), here.dt, None)
    docking.approach.done, docking.approach.edge = True, 0
    proposal, arrived = docking.confirm(at_the_end(rt, x=-2.0)[1], False)
    assert not arrived


def test_on_the_spot_or_without_depth_it_has_arrived() -> None:
    rt = runtime()
    for x in (0.0, -0.1, 0.3):  # on it, a little short, past: arrived
        docking, obs = at_the_end(rt, x=x)
        assert docking.confirm(obs, False) == (None, True)
    docking, obs = at_the_end(rt, x=-2.0, depth=False)
    assert docking.confirm(obs, False) == (None, True)


def test_switched_off_it_arrives_where_the_tracker_says() -> None:
    rt = runtime(topometric=replace(TopometricParams(), end_depth=False))
    docking, obs = at_the_end(rt, x=-2.0)
    assert docking.confirm(obs, False) == (None, True)


def test_the_creep_is_bounded_by_the_depth_s_reach() -> None:
    """Nothing ahead ever comes as near as taught (the end wall taught, gone now): it creeps
    at most the depth's reach, as commanded, then arrives."""
    rt = runtime()
    docking, obs = at_the_end(rt, x=-2.0)
    gone = replace(obs, depth=np.full(RAYS, np.inf))
    moved = 0.0
    for _ in range(1000):
        proposal, arrived = docking.confirm(gone, False)
        if arrived:
            break
        assert proposal is not None
        moved += proposal.command.v * gone.dt
    assert arrived and moved == pytest.approx(REACH, abs=0.05)
