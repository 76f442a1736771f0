"""The channels of a recording: topic, schema name and JSON Schema of each.

Every message is JSON (MCAP message encoding ``json``, schema encoding ``jsonschema``). Camera
frames, the depth profile, log lines and the 3D scene use Foxglove's well-known schemas
(``foxglove.CompressedImage``, ``foxglove.LaserScan``, ``foxglove.Log``,
``foxglove.SceneUpdate``: same names and fields as Foxglove's own JSON schemas), so Foxglove's
Image, 3D, Log and Plot panels show them as they are; the rest are teachrepeat's own, plain
JSON that Foxglove's Plot and Raw Messages panels read by field name (``/belief.entropy``,
``/votes.votes.navigate``, ``/command.v``).

A frame is written as its messages followed by its ``/frame`` message: a recording cut short
(the server killed mid-task) is read up to the last ``/frame``, the last whole frame.
"""

from __future__ import annotations

from typing import Any

CAMERA = "/camera"
ODOMETRY = "/odometry"
DEPTH = "/depth"
BELIEF = "/belief"
VOTES = "/votes"
COMMAND = "/command"
TASK = "/task"
LOG = "/log"
FRAME = "/frame"
TOUR = "/tour"
SCENE = "/scene"
START = "/start"
PATH = "/path"

COMPARED = (BELIEF, VOTES, COMMAND, PATH)
"""What ``teachrepeat replay`` compares frame by frame (with the task's state from ``/frame``)."""

_TIME: dict[str, Any] = {
    "type": "object",
    "title": "time",
    "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
    },
}
_VECTOR3 = {
    "type": "object",
    "properties": {k: {"type": "number"} for k in ("x", "y", "z")},
}
_QUATERNION = {
    "type": "object",
    "properties": {k: {"type": "number"} for k in ("x", "y", "z", "w")},
}
_POSE = {"type": "object", "properties": {"position": _VECTOR3, "orientation": _QUATERNION}}
_COLOR = {
    "type": "object",
    "properties": {k: {"type": "number", "minimum": 0, "maximum": 1} for k in "rgba"},
}
_ARRAY = {"type": "array", "items": {"type": "object"}}


def _object(title: str, description: str, **properties: Any) -> dict[str, Any]:
    return {
        "title": title,
        "description": description,
        "type": "object",
        "properties": properties,
    }


_STATE = {
    "type": "object",
    "properties": {
        "kind": {"type": "string", "enum": ["location", "edge"]},
        "id": {"type": "integer"},
        "name": {"type": "string"},
        "probability": {"type": "number"},
    },
}

SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    CAMERA: (
        "foxglove.CompressedImage",
        _object(
            "foxglove.CompressedImage",
            "The robot's camera frame, as it sent it",
            timestamp=_TIME,
            frame_id={"type": "string"},
            data={"type": "string", "contentEncoding": "base64"},
            format={"type": "string"},
        ),
    ),
    DEPTH: (
        "foxglove.LaserScan",
        _object(
            "foxglove.LaserScan",
            "The robot's depth profile (ranges in metres, leftmost ray first)",
            timestamp=_TIME,
            frame_id={"type": "string"},
            pose=_POSE,
            start_angle={"type": "number"},
            end_angle={"type": "number"},
            ranges={"type": "array", "items": {"type": "number"}},
            intensities={"type": "array", "items": {"type": "number"}},
        ),
    ),
    LOG: (
        "foxglove.Log",
        _object(
            "foxglove.Log",
            "What changed: the task's state, the behaviour that drives the robot and why",
            timestamp=_TIME,
            level={"type": "integer", "minimum": 0, "maximum": 5},
            message={"type": "string"},
            name={"type": "string"},
            file={"type": "string"},
            line={"type": "integer", "minimum": 0},
        ),
    ),
    SCENE: (
        "foxglove.SceneUpdate",
        _object(
            "foxglove.SceneUpdate",
            "The taught paths, the places and the robot's most likely position, in metres",
            deletions=_ARRAY,
            entities={
                "type": "array",
                "items": {
                    "type": "object",
                    "properties": {
                        "timestamp": _TIME,
                        "frame_id": {"type": "string"},
                        "id": {"type": "string"},
                        "lifetime": _TIME,
                        "frame_locked": {"type": "boolean"},
                        "metadata": _ARRAY,
                        **{
                            k: _ARRAY
                            for k in (
                                "arrows",
                                "cubes",
                                "spheres",
                                "cylinders",
                                "lines",
                                "triangles",
                                "texts",
                                "models",
                            )
                        },
                    },
                },
            },
        ),
    ),
    ODOMETRY: (
        "teachrepeat.Odometry",
        _object(
            "teachrepeat.Odometry",
            "The motion the robot reported with the frame",
            timestamp={"type": "number", "description": "robot clock, s"},
            v={"type": "number", "description": "m/s"},
            w={"type": "number", "description": "rad/s"},
        ),
    ),
    BELIEF: (
        "teachrepeat.Belief",
        _object(
            "teachrepeat.Belief",
            "Where the robot believes it is after the frame",
            timestamp={"type": "number", "description": "robot clock, s"},
            top={"type": "array", "items": _STATE},
            entropy={"type": "number", "description": "nats"},
            localised={"type": "boolean"},
            localised_state={"anyOf": [_STATE, {"type": "null"}]},
            states={
                "type": "array",
                "items": {"type": "number"},
                "description": "b(s) of every place then every path, in /tour order",
            },
            best={"type": "object", "description": "the best-matching taught image"},
            position={"type": "object", "description": "the most likely fine state"},
            appearance={"type": "array", "items": {"type": "number"}},
            light_change={
                "type": "number",
                "description": "0-1, how little the frame looks like the tour in its own light",
            },
        ),
    ),
    VOTES: (
        "teachrepeat.Votes",
        _object(
            "teachrepeat.Votes",
            "Vote mass of every action (the policy), and the path voted for",
            timestamp={"type": "number"},
            votes={"type": "object", "additionalProperties": {"type": "number"}},
            active_edge={"type": ["integer", "null"]},
        ),
    ),
    PATH: (
        "teachrepeat.Path",
        _object(
            "teachrepeat.Path",
            "Where the robot is relative to the taught path it tracks (topometric repeat): "
            "the path tracker's estimate and how sure it is; tracking false while it tracks none",
            timestamp={"type": "number", "description": "robot clock, s"},
            tracking={"type": "boolean"},
            edge={"type": ["integer", "null"], "description": "edge id"},
            along_m={"type": ["number", "null"]},
            lateral_m={"type": ["number", "null"], "description": "left of the path, m"},
            heading_error={"type": ["number", "null"], "description": "rad"},
            sigma_lateral_m={"type": ["number", "null"]},
            sigma_along_m={"type": ["number", "null"]},
            sigma_heading={"type": ["number", "null"]},
            locked={"type": ["boolean", "null"]},
        ),
    ),
    COMMAND: (
        "teachrepeat.Command",
        _object(
            "teachrepeat.Command",
            "The motion command sent back: speeds, action, behaviour and its reason",
            timestamp={"type": "number"},
            v={"type": "number"},
            w={"type": "number"},
            ttl_s={"type": "number"},
            action={"type": "string"},
            edge={"type": ["integer", "null"]},
            target_image_id={"type": ["integer", "null"]},
            behaviour={"type": "string"},
            reason={"type": ["string", "null"]},
        ),
    ),
    TASK: (
        "teachrepeat.Task",
        _object(
            "teachrepeat.Task",
            "The task, each time its state changes (GET /robots/{robot}/state's task)",
            id={"type": "integer"},
            tour={"type": "integer"},
            goal={"type": "string"},
            state={"type": "string"},
            reason={"type": ["string", "null"]},
            started_at={"type": "number"},
            ended_at={"type": ["number", "null"]},
            steps={"type": "integer"},
        ),
    ),
    FRAME: (
        "teachrepeat.Frame",
        _object(
            "teachrepeat.Frame",
            "Closes one frame: its number, clocks, the step's time and the task's state",
            index={"type": "integer"},
            timestamp={"type": "number", "description": "robot clock, s"},
            wall={"type": "number", "description": "server clock, Unix s"},
            kind={"type": "string", "enum": ["navigate", "path", "spin"]},
            step_ms={"type": ["number", "null"]},
            task_state={"type": ["string", "null"]},
        ),
    ),
    TOUR: (
        "teachrepeat.Tour",
        _object(
            "teachrepeat.Tour",
            "The tour's graph (GET /tours/{id}) with its fingerprint; at the start (and, for "
            "teaching, at the end)",
            id={"type": "integer"},
            name={"type": "string"},
            fingerprint={"type": "string"},
            locations={"type": "array", "items": {"type": "object"}},
            edges={"type": "array", "items": {"type": "object"}},
        ),
    ),
    START: (
        "teachrepeat.Start",
        _object(
            "teachrepeat.Start",
            "How the task started: the belief it started from when not the prior",
            resumed={"type": "boolean"},
            fresh={"type": "boolean"},
            belief={
                "type": ["string", "null"],
                "contentEncoding": "base64",
                "description": "(n_fine,) float64 little-endian, or null for the prior",
            },
            memory={
                "type": ["object", "null"],
                "description": "what the tracker remembered besides the belief (the belief "
                "over appearance models, the change gate's running familiarity, the evidence "
                "averages: server.belief.tracker.TrackerMemory), or null for the prior",
            },
        ),
    ),
}
"""topic -> (schema name, JSON Schema)."""
