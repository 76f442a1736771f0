"""What a frame, a task and a tour become in a recording: the JSON of each channel.

The recorder writes these messages and ``teachrepeat replay`` builds them again from the steps
it replays, with the same functions, then compares them (:func:`compared`): one definition of
what a step recorded.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from server import schemas
from server.domain import TourGraph
from server.layout import GraphLayout, fine_position, graph_layout
from server.motion import ray_angles
from server.recording import topics
from server.session import StepRecord

Message = tuple[str, dict[str, Any]]
"""(topic, JSON payload)."""


def stamp(seconds: float) -> dict[str, int]:
    """Foxglove's time ``{sec, nsec}`` of ``seconds`` (>= 0)."""
    ns = max(0, round(seconds * 1e9))
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def finite(x: float) -> float | None:
    """``x``, or ``None`` when it is NaN or infinite (JSON has neither)."""
    return float(x) if math.isfinite(x) else None


def tour_fingerprint(graph: TourGraph) -> str:
    """A hash of what a tour taught: its places (names, number of spin images), its paths
    (ends, and the timestamp and motion of every image). The same tour taught into another
    database (as the benchmark's workers do) has the same fingerprint; storage ids do not
    count."""
    h = hashlib.sha256()
    for loc in graph.locations:
        h.update(f"L{loc.name}\x00{len(loc.image_ids)}\n".encode())
    for e in graph.edges:
        h.update(f"E{e.source},{e.target},{e.n_images}\n".encode())
        for values in (e.timestamps, e.v, e.w):
            h.update(np.ascontiguousarray(values, dtype=np.float64).tobytes())
    return h.hexdigest()[:32]


def tour_message(graph: TourGraph, tour_id: int, name: str) -> dict[str, Any]:
    """The tour as ``/tour`` holds it: GET /tours/{id}'s graph with image ids and the
    fingerprint (states in the core's order: places, then paths)."""
    locations = [
        {"id": loc.id, "name": loc.name, "image_ids": list(loc.image_ids)}
        for loc in graph.locations
    ]
    edges = []
    for e in graph.edges:
        src, dst = graph.locations[e.source], graph.locations[e.target]
        edges.append(
            {
                "id": e.id,
                "source": src.id,
                "target": dst.id,
                "source_name": src.name,
                "target_name": dst.name,
                "image_ids": list(e.image_ids),
                "duration_s": e.duration,
            }
        )
    return {
        "id": tour_id,
        "name": name,
        "fingerprint": tour_fingerprint(graph),
        "locations": locations,
        "edges": edges,
    }


def log_message(wall: float, robot: str, text: str, *, level: int = 2) -> Message:
    """A ``foxglove.Log`` line (level 2: info, 3: warning)."""
    return topics.LOG, {
        "timestamp": stamp(wall),
        "level": level,
        "message": text,
        "name": robot,
        "file": "",
        "line": 0,
    }


def camera_messages(jpeg: bytes, meta: schemas.FrameMeta, *, depth_fov_deg: float) -> list[Message]:
    """The frame as the robot sent it: camera, odometry and depth profile."""
    out: list[Message] = [
        (
            topics.CAMERA,
            {
                "timestamp": stamp(meta.timestamp),
                "frame_id": "camera",
                "data": jpeg,
                "format": "jpeg",
            },
        ),
        (topics.ODOMETRY, {"timestamp": meta.timestamp, "v": meta.v, "w": meta.w}),
    ]
    if meta.depth:
        angles = ray_angles(len(meta.depth), depth_fov_deg)
        out.append(
            (
                topics.DEPTH,
                {
                    "timestamp": stamp(meta.timestamp),
                    "frame_id": "robot",
                    "pose": _pose(0.0, 0.0, 0.0),
                    "start_angle": float(angles[0]),
                    "end_angle": float(angles[-1]),
                    "ranges": list(meta.depth),
                    "intensities": [],
                },
            )
        )
    return out


def belief_message(
    step: StepRecord, result: schemas.NavigationFrameResult, graph: TourGraph
) -> dict[str, Any]:
    """``/belief``: the answer's belief summary, b(s) of every state, the best-matching taught
    image (storage id) and the most likely position (a place, or an image along a path)."""
    summary = step.summary
    best_state, best_image, best_similarity = step.best_match()
    fine = int(np.argmax(summary.belief)) if len(summary.belief) else 0
    state = int(graph.fine_state[fine]) if fine < len(graph.fine_state) else 0
    along = None
    if state >= graph.n_locations:
        along = fine - graph.n_locations - int(graph.edge_offsets[state - graph.n_locations])
    return {
        "timestamp": step.timestamp,
        **result.belief.model_dump(),
        "states": [float(p) for p in summary.state],
        "best": {
            "state": best_state,
            "image_id": None if best_image is None else int(graph.image_ids[best_image]),
            "similarity": None if best_similarity is None else finite(best_similarity),
        },
        "position": {"fine": fine, "state": state, "along": along},
        "appearance": [float(a) for a in summary.appearance],
    }


def path_message(step: StepRecord, result: schemas.NavigationFrameResult) -> dict[str, Any]:
    """``/path``: the path tracker's estimate (topometric repeat), or ``tracking`` false."""
    path = result.path
    if path is None:
        return {"timestamp": step.timestamp, "tracking": False}
    return {
        "timestamp": step.timestamp,
        "tracking": True,
        "edge": path.edge,
        "along_m": path.along_m,
        "lateral_m": path.lateral_m,
        "heading_error": path.heading_error,
        "sigma_lateral_m": path.sigma_lateral_m,
        "sigma_along_m": path.sigma_along_m,
        "sigma_heading": path.sigma_heading,
        "locked": path.locked,
    }


def votes_message(
    step: StepRecord, result: schemas.NavigationFrameResult, graph: TourGraph
) -> dict[str, Any]:
    """``/votes``: the vote mass of every action and the path the vote is about."""
    edge = None if step.decision is None else step.decision.active_edge
    return {
        "timestamp": step.timestamp,
        "votes": dict(result.votes),
        "active_edge": None if edge is None else graph.edges[edge].id,
    }


@dataclass(frozen=True)
class FrameMessages:
    """One navigation frame's messages, in the order they are written (``/frame`` last)."""

    messages: tuple[Message, ...]

    def compared(self) -> dict[str, Any]:
        """What replay compares: :data:`topics.COMPARED` and the task's state."""
        return compared(dict(self.messages))


def compared(by_topic: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The compared part of a frame, from its messages by topic."""
    out = {topic.strip("/"): by_topic.get(topic) for topic in topics.COMPARED}
    frame = by_topic.get(topics.FRAME) or {}
    out["task_state"] = frame.get("task_state")
    return out


def navigation_frame(
    step: StepRecord,
    result: schemas.NavigationFrameResult,
    graph: TourGraph,
    meta: schemas.FrameMeta,
    *,
    index: int,
    wall: float,
    depth_fov_deg: float,
) -> FrameMessages:
    """Every message of one answered navigation frame (``index`` counts from 0 in its task;
    ``wall``: the server's clock when it came, Unix s)."""
    command = {"timestamp": step.timestamp, **result.command.model_dump()}
    frame = {
        "index": index,
        "timestamp": step.timestamp,
        "wall": wall,
        "kind": "navigate",
        "step_ms": finite(step.step_ms),
        "task_state": None if result.task is None else result.task.state,
    }
    return FrameMessages(
        (
            *camera_messages(step.jpeg, meta, depth_fov_deg=depth_fov_deg),
            (topics.BELIEF, belief_message(step, result, graph)),
            (topics.VOTES, votes_message(step, result, graph)),
            (topics.PATH, path_message(step, result)),
            (topics.COMMAND, command),
            (topics.FRAME, frame),
        )
    )


def teaching_frame(
    jpeg: bytes,
    meta: schemas.FrameMeta,
    *,
    index: int,
    wall: float,
    spin: bool,
    depth_fov_deg: float,
) -> tuple[Message, ...]:
    """The messages of one teaching image (a frame of the open path, or a spin image)."""
    frame = {
        "index": index,
        "timestamp": meta.timestamp,
        "wall": wall,
        "kind": "spin" if spin else "path",
        "step_ms": None,
        "task_state": None,
    }
    return (*camera_messages(jpeg, meta, depth_fov_deg=depth_fov_deg), (topics.FRAME, frame))


# --- the Foxglove scene ----------------------------------------------------------------------

_PLACE = {"r": 0.38, "g": 0.42, "b": 0.5, "a": 1.0}
_PATH = {"r": 0.58, "g": 0.64, "b": 0.72, "a": 1.0}
_ROBOT = {"r": 0.86, "g": 0.15, "b": 0.15, "a": 0.9}
_TEXT = {"r": 0.1, "g": 0.1, "b": 0.12, "a": 1.0}


def _pose(x: float, y: float, z: float) -> dict[str, Any]:
    return {
        "position": {"x": float(x), "y": float(y), "z": float(z)},
        "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
    }


def _entity(entity_id: str, wall: float, **parts: list[dict[str, Any]]) -> dict[str, Any]:
    kinds = ("arrows", "cubes", "spheres", "cylinders", "lines", "triangles", "texts", "models")
    return {
        "timestamp": stamp(wall),
        "frame_id": "map",
        "id": entity_id,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": False,
        "metadata": [],
        **{k: parts.get(k, []) for k in kinds},
    }


def _sphere(p: Any, size: float, color: dict[str, float]) -> dict[str, Any]:
    return {"pose": _pose(*p), "size": {"x": size, "y": size, "z": size}, "color": color}


class Scene:
    """The tour drawn for Foxglove's 3D panel (metres, from the taught odometry: the layout the
    dashboard draws) and the robot's most likely position on it, frame by frame."""

    def __init__(self, graph: TourGraph) -> None:
        self.graph = graph
        self.layout: GraphLayout = graph_layout(graph)
        self.radius = float(np.clip(0.035 * self.layout.extent, 0.05, 1.0))

    def tour(self, wall: float) -> dict[str, Any]:
        """``/scene``: the places (spheres and names) and the taught paths (lines)."""
        g, lay = self.graph, self.layout
        spheres = [_sphere(lay.places[k], 2 * self.radius, _PLACE) for k in range(g.n_locations)]
        texts = [
            {
                "pose": _pose(*(lay.places[k] + np.array([0.0, 0.0, 2.5 * self.radius]))),
                "billboard": True,
                "font_size": 14.0,
                "scale_invariant": True,
                "color": _TEXT,
                "text": loc.name,
            }
            for k, loc in enumerate(g.locations)
        ]
        lines = []
        for j, e in enumerate(g.edges):
            ends = [lay.places[e.source], *lay.edge_points[j], lay.places[e.target]]
            lines.append(
                {
                    "type": 0,  # LINE_STRIP
                    "pose": _pose(0.0, 0.0, 0.0),
                    "thickness": 3.0,
                    "scale_invariant": True,
                    "points": [{"x": float(p[0]), "y": float(p[1]), "z": 0.0} for p in ends],
                    "color": _PATH,
                    "colors": [],
                    "indices": [],
                }
            )
        entity = _entity("tour", wall, spheres=spheres, texts=texts, lines=lines)
        return {"deletions": [], "entities": [entity]}

    def robot(self, fine: int, wall: float) -> dict[str, Any] | None:
        """``/scene``: the robot's most likely position (fine state ``fine``) as a red ball."""
        p = fine_position(self.layout, self.graph, fine)
        if p is None:
            return None
        sphere = _sphere(p + np.array([0.0, 0.0, self.radius]), 2.6 * self.radius, _ROBOT)
        return {"deletions": [], "entities": [_entity("robot", wall, spheres=[sphere])]}
