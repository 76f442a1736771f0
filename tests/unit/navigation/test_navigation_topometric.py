"""Topometric repeat's behaviours on synthetic observations: following the taught path by the
pose relative to it, facing the goal's taught heading, retracing, and the policy's vote taken
at the tracked image."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from navigation_testkit import GRAPH, A, B, C, observation, path_estimate, runtime
from vision_testkit import scene

from server.belief.model import Action, ActionKind
from server.domain import Edge, Location, TourGraph
from server.navigation import NavigationParams
from server.navigation.behaviours import FindEdge, Follow, Retrace
from server.navigation.command import Command
from server.navigation.docking import Docking
from server.navigation.observation import committed, held_mass
from server.navigation.pathtrack import PathEstimate
from server.navigation.runtime import TourRuntime
from server.vision.features import extract


def estimate(
    rt: TourRuntime,
    *,
    edge: int = 0,
    along: float = 0.5,
    lateral: float = 0.0,
    heading: float = 0.0,
    locked: bool = True,
    since_fix_s: float = 0.0,
) -> PathEstimate:
    """The tracker's estimate on ``edge`` (the synthetic edges run straight along +x)."""
    path = rt.paths[edge]
    k = path.image_at(along)
    return path_estimate(
        edge=edge,
        along=along,
        lateral=lateral,
        heading=heading,
        locked=locked,
        since_fix_s=since_fix_s,
        image=rt.edge_image(edge, k),
        index=k,
        length_m=path.length,
    )


def test_a_locked_tracker_follows_the_path_back_from_its_side() -> None:
    rt = runtime()
    obs = observation(rt, action=Action.navigate(0), active_edge=0, goal=B)
    beside = replace(obs, path=estimate(rt, lateral=0.3))
    proposal = Follow(rt).propose(beside)
    assert proposal is not None and "tracking the path" in proposal.reason
    c = proposal.command
    assert c.behaviour == "follow" and c.action == Action.navigate(0)
    assert c.v > 0 and c.w < 0  # 0.3 m to the left of the path: steers right, back onto it
    # not locked: homing as before (it reads the views it asked for)
    loose = replace(obs, path=estimate(rt, locked=False))
    assert Follow(rt).wants(loose).offsets
    # locked on another edge than the policy asks for: not its to follow
    other = replace(obs, path=estimate(rt, edge=2))
    assert Follow(rt).wants(other).offsets


def test_at_the_end_of_the_route_it_turns_to_the_taught_heading_then_stands() -> None:
    rt = runtime()
    end = rt.paths[0].length
    obs = observation(rt, action=Action.navigate(0), active_edge=0, goal=B)
    turned = replace(obs, path=estimate(rt, along=end, heading=0.5))
    proposal = Follow(rt).propose(turned)
    assert proposal is not None and proposal.command.v == 0 and proposal.command.w < 0
    facing = replace(obs, path=estimate(rt, along=end, heading=0.01))
    still = Follow(rt).propose(facing)
    assert still is not None and (still.command.v, still.command.w) == (0.0, 0.0)
    # at the end but beside it: it drives onto the end (turning toward it first)
    beside = Follow(rt).propose(replace(obs, path=estimate(rt, along=end, lateral=-0.3)))
    assert beside is not None and "to the end of the path 0.30 m away" in beside.reason
    assert beside.command.w > 0  # the end lies to its left


def test_a_robot_facing_away_from_where_an_edge_sets_off_is_told_by_the_spin_views() -> None:
    ids = iter(range(2000, 3000))
    a, b = (Location(name, tuple(next(ids) for _ in range(12))) for name in "AB")
    n = 10
    path = Edge(
        A, B, tuple(next(ids) for _ in range(n)), np.arange(n) * 0.5, np.full(n, 0.3), np.zeros(n)
    )
    graph = TourGraph((a, b), (path,))
    seeds = [int(i) for i in graph.image_ids]
    # the edge sets off the way spin image 3 of A (a quarter of the turn is three of them) faced
    first = seeds.index(path.image_ids[0])
    seeds[first] = a.image_ids[3]
    rt = TourRuntime(graph, [extract(scene(s)) for s in seeds], NavigationParams())
    assert rt.departure_spin(0) == 3
    for seen, faces in ((3, True), (5, True), (0, True), (6, True), (7, False), (9, False)):
        similarity = np.full(graph.n_images, 0.1)
        similarity[rt.spin_images[A][seen]] = 0.9
        assert rt.faces_departure(similarity, 0) == faces, seen
    # fewer than 8 spin images: it cannot tell
    assert runtime().faces_departure(np.full(GRAPH.n_images, 0.1), 0)


def test_a_tracker_that_joined_the_sought_edge_takes_over_from_the_search() -> None:
    rt = runtime()
    est = estimate(rt, along=0.2, lateral=0.4)
    similarity = np.full(rt.graph.n_images, 0.1)
    similarity[est.image] = 0.9  # the view looks like the taught one there
    obs = observation(rt, action=Action.rotate(0), goal=B, similarity=similarity)
    joined = replace(obs, path=est)
    assert FindEdge(rt).propose(joined) is None
    assert FindEdge(rt).wants(joined).offsets == frozenset()
    proposal = Follow(rt).propose(joined)
    assert proposal is not None and proposal.command.action == Action.navigate(0)
    # locked, but the view does not look like the taught one there (facing the other way
    # down a corridor that looks alike both ways): the search goes on
    unlike = replace(observation(rt, action=Action.rotate(0), goal=B), path=est)
    assert FindEdge(rt).wants(unlike).offsets
    assert Follow(rt).propose(unlike) is None


def test_a_lost_tracker_drives_back_along_its_trace_once() -> None:
    rt = runtime()
    retrace = Retrace(rt)
    route = tuple(np.array([x, 0.3 * (x - 0.6) / 0.6, 0.0]) for x in (1.2, 1.0, 0.8, 0.6))
    lost = estimate(rt, along=1.2, lateral=0.3, locked=False, since_fix_s=3.0)
    obs = replace(
        observation(rt, action=Action.navigate(0), active_edge=0), path=lost, retrace=route
    )
    proposal = retrace.propose(obs)
    assert proposal is not None and proposal.command.behaviour == "retrace"
    assert proposal.command.v < 0  # backwards: the camera keeps facing the way the path goes
    assert retrace.events() == {"retracing"}
    # lost only a moment ago: no retracing yet
    fresh = replace(obs, path=replace(lost, since_fix_s=0.5))
    assert Retrace(rt).propose(fresh) is None
    # back where it was locked: it stands, and does not retrace to the same place again
    back = replace(obs, path=replace(lost, pose=np.array([0.6, 0.0, 0.0])))
    arrived = retrace.propose(back)
    assert arrived is not None and (arrived.command.v, arrived.command.w) == (0.0, 0.0)
    assert retrace.propose(obs) is None
    # a trace longer than retrace_max_m is not driven back along
    far = tuple(np.array([x, 0.0, 0.0]) for x in np.linspace(4.0, 0.0, 20))
    assert Retrace(rt).propose(replace(obs, retrace=far)) is None


def test_the_vote_is_taken_at_the_tracked_image_while_the_belief_holds_the_edge() -> None:
    rt = runtime()
    g = rt.graph
    # the belief split between edge 0 (A -> B) and edge 2 (B -> C), the vote for edge 2
    belief = np.zeros(g.n_fine)
    lo0 = g.n_locations + int(g.edge_offsets[0])
    lo2 = g.n_locations + int(g.edge_offsets[2])
    belief[lo0 + 3] = 0.4
    belief[lo2 + 3] = 0.6
    asked = observation(rt, action=Action.navigate(2), active_edge=2, goal=B).decision
    est = estimate(rt, edge=0, along=0.5)
    none = np.zeros(g.n_images)
    kept = committed(rt, belief, asked, B, est, hold_goal=True, similarity=none)
    assert kept.action == Action.navigate(0) and kept.active_edge == 0
    # the belief barely holds the tracked edge: the policy's decision stands
    weak = belief.copy()
    weak[lo0 + 3], weak[lo2 + 3] = 0.1, 0.9
    assert committed(rt, weak, asked, B, est, hold_goal=True, similarity=none) == asked
    # not locked, or at the end of the edge (the next edge is the policy's), or Explore
    assert (
        committed(rt, belief, asked, B, replace(est, locked=False), hold_goal=True, similarity=none)
        == asked
    )
    end = replace(est, along_m=est.length_m - 0.1)
    assert committed(rt, belief, asked, B, end, hold_goal=True, similarity=none) == asked
    explore = replace(asked, action=Action.explore())
    assert (
        committed(rt, belief, explore, B, est, hold_goal=True, similarity=none).action.kind
        == ActionKind.EXPLORE
    )


def test_at_the_end_of_an_edge_the_route_goes_on_through_the_place() -> None:
    rt = runtime()
    g = rt.graph
    L = g.n_locations
    lo0 = L + int(g.edge_offsets[0])
    # the tracker locked at the end of A -> B, the belief still on that edge's last images
    # (the robot has not reached B in its eyes): going to C, the route goes on along B -> C
    belief = np.zeros(g.n_fine)
    belief[lo0 + 9], belief[lo0 + 8], belief[B] = 0.6, 0.2, 0.2
    asked = observation(rt, action=Action.navigate(0), active_edge=0, goal=C).decision
    end = estimate(rt, edge=0, along=rt.paths[0].length - 0.1)
    none = np.zeros(g.n_images)
    on = committed(rt, belief, asked, C, end, hold_goal=True, similarity=none)
    assert on.action == Action.navigate(2) and on.active_edge == 2 and on.target_image == 1
    # into the goal, not locked, or the belief elsewhere: the decision stands
    assert committed(rt, belief, asked, B, end, hold_goal=True, similarity=none) == asked
    loose = replace(end, locked=False)
    assert committed(rt, belief, asked, C, loose, hold_goal=True, similarity=none) == asked
    elsewhere = np.zeros(g.n_fine)
    elsewhere[L + int(g.edge_offsets[3]) + 5] = 1.0
    assert committed(rt, elsewhere, asked, C, end, hold_goal=True, similarity=none) == asked
    # once through B, at the start of B -> C: the belief at the end of A -> B still holds it
    # (the robot is as much at the end of the edge it came by), and the vote is B -> C's
    start = estimate(rt, edge=2, along=0.2)
    kept = committed(rt, belief, asked, C, start, hold_goal=True, similarity=none)
    assert kept.action == Action.navigate(2) and kept.active_edge == 2
    # further along B -> C the edge it came by no longer counts
    later = estimate(rt, edge=2, along=2.0)
    assert committed(rt, belief, asked, C, later, hold_goal=True, similarity=none) == asked


def test_at_the_tracked_end_of_the_path_into_the_goal_it_has_arrived_facing_any_way() -> None:
    """A guide that turned on the spot at the end of the path taught an end heading 180
    degrees from the way it drove in: the robot turning to face it lost the tracker's lock on
    the way round and was sent on along the next edge. Arrival is where the robot stands."""
    rt = runtime()
    end = rt.paths[0].length
    docking = Docking(rt, B)
    docking.approach.done, docking.approach.edge = True, 0
    obs = observation(rt, action=Action.navigate(0), active_edge=0, goal=B, at_goal=True)
    for heading in (0.0, 1.0, -3.0):
        there = replace(obs, path=estimate(rt, along=end - 0.05, heading=heading))
        assert docking.confirm(there, False) == (None, True)
    short = replace(obs, path=estimate(rt, along=end - 0.5))
    proposal, arrived = docking.confirm(short, False)
    assert not arrived and proposal is not None and proposal.command.v > 0


def test_a_tracker_lost_short_of_the_goal_the_policy_holds_turns_the_robot_to_look() -> None:
    """The belief holds the goal (DoNothing) while the tracker on the edge in, lost, puts the
    robot metres short of its end: no arrival, and the robot turns on the spot for fresh views
    (it stood still, nothing else moving it, until the unstick gave up waiting). While the
    policy moves the robot itself, docking leaves it to the policy."""
    rt = runtime()
    docking = Docking(rt, B)
    docking.approach.done, docking.approach.edge = True, 0
    lost = estimate(rt, along=0.2, locked=False, since_fix_s=5.0)
    held = observation(rt, action=Action.do_nothing(), goal=B, at_goal=True)
    proposal, arrived = docking.confirm(replace(held, path=lost), False)
    assert not arrived and proposal is not None
    assert proposal.command.v == 0 and proposal.command.w != 0
    assert proposal.command.action.kind == ActionKind.DO_NOTHING
    moving = observation(rt, action=Action.navigate(0), active_edge=0, goal=B, at_goal=True)
    assert docking.confirm(replace(moving, path=lost), False) == (None, False)


def test_a_robot_docked_on_the_spot_stays_approached_while_the_lock_on_the_edge_in_is_lost() -> (
    None
):
    """A path taught by hand ends with a turn on the spot. Place docking put the robot on the
    taught spot; the tracker locked on the edge in again, then let go for a few frames 0.1 m
    from the goal; the approach started again, and the goal, not yet approached, sent the
    robot out on its round trip, over and over (the end-to-end teach-by-driving test's "go
    to", failed after 2824 frames). Docked on the spot, following the edge in without the lock
    leaves the approach done; without that docking, a lost lock starts it again, as does a
    search either way."""
    rt = runtime()
    follow = Command(0.2, 0.0, Action.navigate(0), 1, "follow")
    search = Command(0.0, 0.5, Action.rotate(2), None, "search")
    dt = 0.1
    # approached by following the edge in with the lock: a lost lock starts it again
    docking = Docking(rt, B)
    a = docking.approach
    assert docking.needs_approach and not a.done
    for _ in range(11):
        docking.track(follow, dt, estimate(rt, along=1.0))
    assert a.done and a.edge == 0 and not a.on_spot
    docking.track(follow, dt, estimate(rt, along=1.1, locked=False))
    assert not a.done and a.seconds == 0.0
    # docked on the spot by the place's own depth or views (as place docking leaves it)
    a.docked_on_spot()
    for _ in range(3):
        docking.track(follow, dt, estimate(rt, along=1.1))  # locked again: counts
    for _ in range(5):
        docking.track(follow, dt, estimate(rt, along=1.1, locked=False))
    assert a.done and a.on_spot
    # a search (the robot looked round) starts it again, and it is no longer on the spot
    docking.track(search, dt, None)
    assert not a.done and not a.on_spot and a.seconds == 0.0 and a.edge is None


def test_held_mass_equals_the_sum_over_the_edges_states_naively() -> None:
    rt = runtime()
    g = rt.graph
    rng = np.random.default_rng(3)
    chain_m = rt.params.topometric.chain_m
    for edge in range(g.n_edges):
        for along in (0.0, chain_m / 2, chain_m + 1.0):
            belief = rng.dirichlet(np.ones(g.n_fine))
            est = replace(estimate(rt, edge=edge, along=min(along, 4.5)), along_m=along)
            e = g.edges[edge]
            naive = sum(
                float(p)
                for s, p in zip(g.fine_state, belief, strict=True)
                if s in (e.source, e.target, g.n_locations + edge)
                or (
                    along <= chain_m
                    and s >= g.n_locations
                    and g.edges[s - g.n_locations].target == e.source
                )
            )
            assert held_mass(rt, belief, est) == pytest.approx(naive, abs=1e-12)
