"""A small synthetic tour and synthetic observations, to test behaviours one at a time."""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "vision"))
from vision_testkit import scene

from server.belief.model import Action, ActionKind
from server.belief.tracker import BeliefSummary
from server.domain import Edge, Location, TourGraph
from server.navigation import NavigationParams, TourRuntime
from server.navigation.command import Command, Proposal
from server.navigation.geometry import EdgePath, compose
from server.navigation.observation import Observation, Outcome, Views
from server.navigation.pathtrack import PathEstimate, PathTracker, TopometricParams
from server.policy.voting import Decision
from server.vision.features import FeatureParams, ImageFeatures, extract
from server.vision.index import Similarity

A, B, C, D = range(4)


def tour() -> TourGraph:
    """A <-> B <-> C, ten images per edge, four spin images per place; D has no edges. Image
    ids are the seeds of their synthetic scenes, all distinct."""
    ids = iter(range(1000))
    locs = tuple(Location(name, tuple(next(ids) for _ in range(4))) for name in "ABCD")

    def edge(s: int, t: int) -> Edge:
        n = 10
        return Edge(
            s,
            t,
            tuple(next(ids) for _ in range(n)),
            np.arange(n) * 0.5,
            np.full(n, 0.3),
            np.zeros(n),
        )

    return TourGraph(locs, (edge(A, B), edge(B, A), edge(B, C), edge(C, B)))


GRAPH = tour()
FEATURES = [extract(scene(int(i))) for i in GRAPH.image_ids]


def runtime(**changes: object) -> TourRuntime:
    """The synthetic tour's runtime, able to read its taught pixels as the server's is (the
    scenes are rendered again on demand; read only with ``dock_taught_zooms``)."""
    params = replace(NavigationParams(), **changes)  # type: ignore[arg-type]
    return with_pixels(TourRuntime(GRAPH, FEATURES, params))


def with_pixels(rt: TourRuntime) -> TourRuntime:
    """``rt`` able to read its taught images' pixels (each graph image id is the seed of its
    synthetic scene), as the server's runtimes are."""
    rt.taught_pixels = lambda k: scene(int(rt.graph.image_ids[k]))
    return rt


def observation(
    rt: TourRuntime,
    *,
    action: Action | None = None,
    active_edge: int | None = None,
    target_image: int | None = None,
    t: float = 10.0,
    dt: float = 0.1,
    v: float = 0.0,
    w: float = 0.0,
    depth: list[float] | None = None,
    similarity: np.ndarray | None = None,
    map_state: int = A,
    goal: int = B,
    at_goal: bool = False,
    goal_ambiguity: float | None = None,
    views: Views | None = None,
    previous: Outcome | None = None,
) -> Observation:
    """An observation with the given fields and bland defaults (every image 0.1 similar)."""
    g = rt.graph
    action = action if action is not None else Action.do_nothing()
    image_sim = np.full(g.n_images, 0.1) if similarity is None else np.asarray(similarity)
    state = np.zeros(g.n_states)
    state[map_state] = 1.0
    summary = BeliefSummary(
        belief=rt.model.prior,
        state=state,
        row_edge=np.zeros(0, np.int64),
        edge_offsets=np.zeros(1, np.int64),
        top_states=((map_state, 1.0),),
        best_image=np.zeros(g.n_edges, np.int64),
        entropy=0.0,
        localised=True,
        localised_state=map_state,
    )
    votes = {k: float(k == action.kind) for k in ActionKind}
    return Observation(
        t=t,
        dt=dt,
        v=v,
        w=w,
        depth=None if depth is None else np.asarray(depth, np.float64),
        features=FEATURES[0],
        similarity=Similarity(
            image=image_sim,
            state=np.full(g.n_states, 0.1),
            best_image=np.zeros(g.n_states, np.int64),
            candidates=np.zeros(0, np.int64),
            first_pass_ms=0.0,
            second_pass_ms=0.0,
        ),
        summary=summary,
        decision=Decision(action, target_image, votes, active_edge),
        goal=goal,
        steps=10,
        at_goal=at_goal,
        goal_ambiguity=goal_ambiguity,
        views=views if views is not None else Views(),
        previous=previous,
    )


def outcome(
    command: Command, winner: str = "follow", events: frozenset[str] = frozenset()
) -> Outcome:
    """The last frame's outcome: ``winner`` proposed ``command`` and it was chosen as is."""
    proposal = Proposal(command, f"{winner} says so")
    return Outcome(command, winner, proposal.reason, {winner: proposal}, events)


FOV = 90.0
"""The depth profiles' field of view in these tests, degrees (the simulated robot's)."""
RAYS = 31


def room_profile(
    x: float, y: float, th: float, *, walls: list[tuple[float, float, float, float]]
) -> np.ndarray:
    """Ranges from pose (x, y, th) to line segments ``walls`` (x0, y0, x1, y1): a ray caster."""
    half = math.radians(FOV) / 2
    out = np.full(RAYS, np.inf)
    for i, a in enumerate(np.linspace(half, -half, RAYS)):
        d = np.array([math.cos(th + a), math.sin(th + a)])
        for x0, y0, x1, y1 in walls:
            e = np.array([x1 - x0, y1 - y0])
            m = np.array([[d[0], -e[0]], [d[1], -e[1]]])
            if abs(np.linalg.det(m)) < 1e-12:
                continue
            t, u = np.linalg.solve(m, [x0 - x, y0 - y])
            if t > 0 and 0 <= u <= 1:
                out[i] = min(out[i], t)
    return out


WALLS = [  # a room 4 x 3 m with a cupboard
    (0, 0, 4, 0),
    (4, 0, 4, 3),
    (4, 3, 0, 3),
    (0, 3, 0, 0),
    (3.0, 2.2, 3.6, 2.2),
    (3.0, 2.2, 3.0, 3.0),
]


def path_estimate(
    *,
    edge: int = 0,
    along: float = 0.5,
    lateral: float = 0.0,
    heading: float = 0.0,
    sigma_along: float = 0.02,
    locked: bool = True,
    since_fix_s: float = 0.0,
    image: int = 0,
    index: int = 0,
    length_m: float = 5.0,
) -> PathEstimate:
    """A path tracker's estimate on ``edge`` (an edge running straight along +x), ``along``
    metres along it and ``lateral`` to its left; standard deviations 0.02 m across, 0.01 rad."""
    return PathEstimate(
        edge=edge,
        pose=np.array([along, lateral, heading]),
        cov=np.diag([sigma_along**2, 0.02**2, 0.01**2]),
        along_m=along,
        lateral_m=lateral,
        heading_error=heading,
        sigma_lateral=0.02,
        sigma_along=sigma_along,
        sigma_heading=0.01,
        locked=locked,
        fixes=2,
        image=image,
        index=index,
        length_m=length_m,
        since_fix_s=since_fix_s,
    )


NO_FEATURES = ImageFeatures(
    keypoints=np.zeros((0, 2), np.float32),
    descriptors=np.zeros((0, FeatureParams().descriptor_bytes), np.uint8),
    signature=np.zeros(0, np.float32),
)
"""A frame or taught image in which the camera found nothing (the depth profiles alone)."""


def taught_edge(
    start: np.ndarray, n: int = 80, *, walls: list[tuple[float, float, float, float]]
) -> tuple[EdgePath, list[np.ndarray]]:
    """A straight taught edge of ``n`` images 0.05 m apart from world pose ``start``, and the
    depth profile taught with each image in the room ``walls``."""
    edge = Edge(0, 1, tuple(range(n)), np.arange(n) * 0.2, np.full(n, 0.25), np.zeros(n))
    path = EdgePath.of(edge)
    depths = [room_profile(*compose(start, pose), walls=walls) for pose in path.poses]
    return path, depths


def depth_tracker(
    path: EdgePath, depths: list[np.ndarray], params: TopometricParams
) -> PathTracker:
    """A tracker of the one edge ``path`` whose images show no features, with the depth
    profiles ``depths`` taught along it."""
    return PathTracker(
        (path,), (NO_FEATURES,) * path.n_images, np.array([0]), params, depth=lambda k: depths[k]
    )
