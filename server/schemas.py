"""Wire schemas: the pydantic models of every request and response body.

The single source of truth for what crosses HTTP, shared by the server and the robot client.
Importing this module pulls in pydantic and the standard library only.
"""

from __future__ import annotations

import re
from typing import Annotated, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    StringConstraints,
)

RobotName = Annotated[
    str,
    StringConstraints(pattern=r"^[a-z0-9][a-z0-9_-]{0,63}$"),
    Field(description="Lower-case letters, digits, '-' and '_', 1 to 64 characters."),
]
_SPACE = "\t\n\v\f\r \x85\xa0\u1680\u2000-\u200a\u2028\u2029\u202f\u205f\u3000\ufeff"
_CONTROL = "\\x00-\\x1f\\x7f"
TRIMMED = f"^[^{_SPACE}{_CONTROL}](?:[^{_CONTROL}]*[^{_SPACE}{_CONTROL}])?$"
"""No white space at either end and no control character anywhere (PostgreSQL's text cannot
hold U+0000, and no name needs a tab or a line break). The characters are listed, not
``\\s``: the OpenAPI document's regex (ECMAScript) and Python's disagree on what ``\\s`` is,
and then a name the document allows would be refused, or one it forbids taken."""
_TRIMMED = re.compile(TRIMMED)


def _trimmed(value: str) -> str:
    if not _TRIMMED.fullmatch(value):
        raise ValueError(
            "must not start or end with white space, nor hold a control character (U+0000 to "
            "U+001F, U+007F)"
        )
    return value


TourName = Annotated[
    str,
    StringConstraints(min_length=1, max_length=100),
    AfterValidator(_trimmed),
    Field(
        description="Unique name of the tour, 1 to 100 characters, no spaces at either end.",
        json_schema_extra={"pattern": TRIMMED},
    ),
]
LocationName = Annotated[
    str,
    StringConstraints(min_length=1, max_length=64),
    AfterValidator(_trimmed),
    Field(
        description="Name of the place, unique within its tour, 1 to 64 characters, no spaces "
        "at either end.",
        json_schema_extra={"pattern": TRIMMED},
    ),
]


HouseholdName = Annotated[
    str,
    StringConstraints(pattern=r"^[a-z0-9][a-z0-9_-]{0,63}$"),
    Field(description="Lower-case letters, digits, '-' and '_', 1 to 64 characters."),
]
Password = Annotated[
    str,
    StringConstraints(min_length=10, max_length=256),
    Field(description="10 to 256 characters."),
]

MAX_ID = 2**53 - 1
"""Largest id the API takes: the largest integer a JSON number (an IEEE double) holds exactly.
With SQLite's 2**63 - 1 as the bound, a validator that compares JSON numbers as doubles
finds 2**63 + 191 within it (the same double) and sends what the server refuses."""


def _json_integer(value: object) -> object:
    """A JSON integer only: lax pydantic would also take ``true`` and ``"1"`` for 1."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError("must be an integer")
    return value


DbId = Annotated[
    int, Field(ge=1, le=MAX_ID, description="A database id."), BeforeValidator(_json_integer)
]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class ErrorBody(_Model):
    """Every 4xx/5xx answer. 401: missing or unknown bearer token; 403: a robot token acting
    for another robot or as the admin; 404: unknown tour, place, robot or image; 405: a method
    the path does not have (``Allow`` lists those it has); 409: the step does not fit the
    robot's state (not teaching, still navigating, a path too short for an edge, a place
    without an image...); 413: an image over the byte or pixel limits; 415: a body that is not
    a JPEG; 422: a request that breaks the schema, or an image that cannot be decoded, is too
    small or goes back in time; 429: too many requests; 503: the database cannot be written."""

    detail: str = Field(description="What was wrong and what to do about it.")
    code: str = Field(description="Machine-readable error kind, e.g. 'not_found'.")


class ServiceIndex(_Model):
    """``GET /``: where to read about the API and where to watch the robots."""

    name: Literal["teachrepeat"] = "teachrepeat"
    version: str
    docs: str = Field(description="Interactive API documentation (Swagger UI, served offline).")
    openapi: str = Field(description="The OpenAPI document.")
    dashboard: str | None = Field(
        description="URL of the live dashboard; null when the server runs without one."
    )


# --- tours -------------------------------------------------------------------------------


class LearnedChange(_Model):
    """One thing a tour learned from a person's answer to a question (docs/learning.md);
    remove it with DELETE /tours/{tour}/learned/{id} to get the earlier behaviour back."""

    id: int
    tour: int
    kind: Literal["loop_closure", "look_alike", "new_path"] = Field(
        description="'loop_closure': a 'same_place' question answered yes, the taught path "
        "ended at a known place; 'look_alike': one answered no, the two views are marked as "
        "look-alikes; 'new_path': a 'new_path' question answered yes, an edge found by "
        "exploration"
    )
    created_at: float
    source: str = Field(description="Where it came from: the question, its robot and when.")
    summary: str
    images: int = Field(description="Images of the edge a loop closure or a new path added.")
    edge: int | None = Field(
        default=None, description="The edge a loop closure or a new path added (removed with it)."
    )


class QuestionPublic(_Model):
    """A question the robot asks a person (docs/learning.md); answer it with
    POST /robots/{robot}/questions/{id} before ``expires_at``."""

    id: int
    robot: str
    tour: int
    kind: Literal["same_place", "new_path"] = Field(
        description="'same_place': while teaching, is the robot at this known place? "
        "'new_path': keep the way exploration found from one known place to another?"
    )
    text: str = Field(description="The question as a person reads it.")
    location: str = Field(description="The place asked about (a new path's end).")
    source_location: str | None = Field(description="Where the open path or the new path starts.")
    image_id: int | None = Field(description="The frame the question was asked at, if stored.")
    match_image_id: int | None = Field(description="The known place's image it matched best.")
    frames: int = Field(description="Frames of a proposed new path (0 for 'same_place').")
    confidence: float = Field(description="The belief's mass at the place, 0..1.")
    created_at: float = Field(description="Unix time, s.")
    expires_at: float = Field(description="Unix time, s; afterwards an answer is refused (410).")
    state: Literal["open", "yes", "no", "expired", "withdrawn"]
    change: int | None = Field(
        description="The learned change the answer made (GET /tours/{tour}/learned)."
    )


class QuestionAnswer(_Model):
    answer: Literal["yes", "no"] = Field(description="'yes' or 'no'.")


class TourCreate(_Model):
    name: TourName


class TourSummary(_Model):
    id: int
    name: str
    locations: int
    edges: int
    images: int


_POSES = (
    "Where each image was taken, [x, y, heading] in metres and radians in the teaching robot's "
    "odometry frame (a simulated robot's true pose), in the order of the images; null unless "
    "every image has one."
)
_ENTROPY = (
    "Distinctiveness of each image, in the order of the images: the entropy (nats) of its "
    "retrieval scores against the whole tour; low = only this spot looks like it, high = "
    "look-alikes elsewhere (docs/ambiguity.md). Null until computed, a few seconds to minutes "
    "after teaching changed the tour."
)


class LocationPublic(_Model):
    id: int
    name: str
    image_count: int
    image_ids: list[int] = Field(description="Spin images, in the order they were taken.")
    poses: list[list[float]] | None = Field(default=None, description=_POSES)
    entropy: list[float] | None = Field(default=None, description=_ENTROPY)


class EdgePublic(_Model):
    id: int
    source: int = Field(description="Location id the path starts at.")
    target: int = Field(description="Location id the path ends at.")
    source_name: str
    target_name: str
    image_count: int
    duration_s: float = Field(description="Last image timestamp minus first, seconds.")
    length_m: float = Field(
        default=0.0, description="Distance driven while taught: sum of |v| dt, metres."
    )
    first_image_id: int
    last_image_id: int
    poses: list[list[float]] | None = Field(default=None, description=_POSES)
    entropy: list[float] | None = Field(default=None, description=_ENTROPY)


class TourGraphPublic(_Model):
    id: int
    name: str
    locations: list[LocationPublic]
    edges: list[EdgePublic]


# --- robots ------------------------------------------------------------------------------


class RobotCreate(_Model):
    name: RobotName
    household: HouseholdName | None = Field(
        default=None,
        description="Household the robot belongs to. A household login registers into its own "
        "(leave it out); the admin names one (default: 'default').",
    )


class RobotRegistered(_Model):
    name: str
    token: str = Field(description="Bearer token of the robot. Shown once; stored hashed.")


class WhoAmI(_Model):
    kind: Literal["admin", "robot", "household"]
    robot: str | None = Field(default=None, description="The robot's name for a robot token.")
    household: str | None = Field(
        default=None, description="The household of a robot token or a household login."
    )


class RobotPublic(_Model):
    """A robot as its household sees it; never its token."""

    name: str
    created_at: float
    household: str
    token_active: bool = Field(description="False once its token was revoked.")
    token_issued_at: float | None = Field(description="When the current token was issued.")


# --- teaching ----------------------------------------------------------------------------


RECORD_DESCRIPTION = (
    "Record this {what} to an MCAP file (GET /robots/{{robot}}/recordings lists them): true or "
    "false; null or absent = the server's setting (`serve --record DIR`)."
)


class TeachStart(_Model):
    tour: DbId = Field(description="Id of the tour to teach (create it with POST /tours).")
    record: bool | None = Field(
        default=None, description=RECORD_DESCRIPTION.format(what="teaching tour")
    )


class LocationMark(_Model):
    name: LocationName


class FinishTeaching(_Model):
    pass


class TeachingState(_Model):
    tour: int
    tour_name: str
    current_location: str | None = Field(
        description="The last place marked; the open path starts there."
    )
    open_path_images: int = Field(description="Frames uploaded since the last mark.")
    last_timestamp: float | None
    locations: int
    edges: int


class MarkResult(_Model):
    location: LocationPublic
    created: bool = Field(description="True when the place is new; false when it existed.")
    edge: EdgePublic | None = Field(description="The path this mark closed, if any.")
    teaching: TeachingState


class ImageStored(_Model):
    image_id: int
    width: int
    height: int


class TeachingEnded(_Model):
    tour: TourGraphPublic
    discarded_images: int = Field(description="Frames of the open path that were dropped.")


# --- frames and motion -------------------------------------------------------------------


MAX_TIMESTAMP_S = 1e10
"""Latest capture time accepted, seconds: Unix time until the year 2286, or any monotonic clock."""
MAX_LINEAR_SPEED = 5.0
"""Largest |v| a robot may report, m/s: beyond any home robot; more is a unit or sensor error."""
MAX_ANGULAR_SPEED = 20.0
"""Largest |w| a robot may report, rad/s (about 3 turns a second)."""
MAX_DEPTH_M = 1000.0
"""Largest depth range, metres; send it (or anything far) for a ray that saw nothing."""
MAX_POSE = 1e4
"""Largest |x|, |y| (m) and |heading| (rad) of a pose a frame may carry."""

DepthRange = Annotated[
    float,
    Field(ge=0.0, le=MAX_DEPTH_M, allow_inf_nan=False, description="Range of one ray, metres."),
]
PoseValue = Annotated[float, Field(ge=-MAX_POSE, le=MAX_POSE, allow_inf_nan=False)]


class FrameMeta(_Model):
    """Query parameters that come with every frame (the body is the JPEG). The bounds are
    physical: a value outside them is a unit or sensor error, refused with 422 before anything
    is stored."""

    timestamp: float = Field(
        ge=0.0,
        le=MAX_TIMESTAMP_S,
        allow_inf_nan=False,
        description="Capture time, seconds, non-decreasing per robot.",
    )
    v: float = Field(
        default=0.0,
        ge=-MAX_LINEAR_SPEED,
        le=MAX_LINEAR_SPEED,
        allow_inf_nan=False,
        description="Linear velocity being executed, m/s.",
    )
    w: float = Field(
        default=0.0,
        ge=-MAX_ANGULAR_SPEED,
        le=MAX_ANGULAR_SPEED,
        allow_inf_nan=False,
        description="Angular velocity being executed, rad/s.",
    )
    depth: list[DepthRange] | None = Field(
        default=None,
        max_length=256,
        description="Optional depth profile: ranges in metres, leftmost ray first "
        "(repeat the parameter: depth=1.2&depth=0.9...). Send the maximum (1000) for a ray "
        "that saw nothing; infinity and NaN are refused. Kept with a taught image, it lets "
        "navigation tell how far beside the taught path the robot stands.",
    )
    pose: list[PoseValue] | None = Field(
        default=None,
        min_length=3,
        max_length=3,
        description="Optional pose of the camera while teaching: x and y in metres and the "
        "heading in radians, in the robot's own odometry frame (pose=x&pose=y&pose=theta), "
        "for a robot with a better pose source than its speeds (its wheel odometry topic, its "
        "own SLAM): never a simulator's truth. When every taught image has one, the dashboard "
        "draws the taught paths where they were taken and GET /tours/{id} lists them; "
        "ignored while navigating.",
    )
    stream: bool = Field(
        default=False,
        description="True from a robot that streams frames all the time and lets the server "
        "decide what happens (the robot agent, `teachrepeat robot run`): while teaching, only "
        "the frames taken while a person drives it are kept on the open path, and after a new "
        "place is named the server spins the robot there and keeps the spin's frames as the "
        "place's images. False (a client that decides itself, e.g. `robot teach`): every "
        "frame sent while teaching is kept.",
    )


# --- navigation ----------------------------------------------------------------------------

ActionName = Literal["rotate_and_find_edge", "navigate", "explore", "do_nothing"]
TaskStateName = Literal["underway", "arrived", "failed", "cancelled"]


class GotoRequest(_Model):
    location: LocationName
    tour: DbId | None = Field(
        default=None,
        description="Tour to navigate in; defaults to the tour the robot last used.",
    )
    record: bool | None = Field(
        default=None, description=RECORD_DESCRIPTION.format(what="navigation task")
    )


class MotionCommand(_Model):
    """What the robot should do until its next frame is answered, or until ``ttl_s`` runs out
    (then it stops: a robot never drives on a stale command)."""

    v: float = Field(description="Linear velocity, m/s (forward positive).")
    w: float = Field(description="Angular velocity, rad/s (counter-clockwise positive).")
    ttl_s: float = Field(description="Seconds this command stays valid after it was sent.")
    action: ActionName
    edge: int | None = Field(default=None, description="Edge id the action is about.")
    target_image_id: int | None = Field(
        default=None, description="Image the robot is homing on (Navigate)."
    )
    behaviour: str = Field(
        default="stand",
        description="What the motion layer is doing: stand, follow, leave, search, explore, "
        "unstick, backoff, escape, settle, dock or place-dock (server.navigation.BEHAVIOURS); "
        "outside navigation, teleop (a person drives it) or spin (turning once at a new "
        "place to photograph it).",
    )
    reason: str | None = Field(
        default=None,
        description="Why the behaviour that won this frame chose the command (the arbiter's "
        "precedence: server.navigation.arbiter); none without a task underway.",
    )


class StateProbability(_Model):
    kind: Literal["location", "edge"]
    id: int = Field(description="Location or edge id.")
    name: str
    probability: float


class BeliefPublic(_Model):
    top: list[StateProbability] = Field(description="Most likely states, most likely first.")
    entropy: float = Field(description="Entropy of the belief over states, nats.")
    localised: bool
    localised_state: StateProbability | None = None
    appearance: list[float] = Field(
        default_factory=lambda: [1.0],
        description=(
            "Belief over the engine's appearance models, summing to 1: the tour's own light "
            "first, then changed light (season, lamps; see docs/localize.md)."
        ),
    )
    light_change: float = Field(
        default=1.0,
        ge=0.0,
        le=1.0,
        description=(
            "Evidence that the light changed since the tour, 0-1, from the last frames: 0 "
            "while they match the tour better than its images match its other places (the "
            "belief then uses the tour's own appearance model alone), 1 when they match it "
            "no better than most of those (the models compete); 1 with one appearance model "
            "(docs/localize.md)."
        ),
    )


class PathPublic(_Model):
    """Where the robot is relative to the taught path it follows (topometric repeat): the
    path tracking filter's estimate in the frame of the edge it tracks (docs/navigation.md)."""

    edge: int = Field(description="Id of the edge tracked.")
    along_m: float = Field(description="Metres along the taught path of the robot's nearest point.")
    lateral_m: float = Field(description="Metres to the left of the taught path (negative: right).")
    heading_error: float = Field(description="The robot's heading minus the path's, radians.")
    sigma_lateral_m: float = Field(description="Standard deviation of lateral_m, metres.")
    sigma_along_m: float = Field(description="Standard deviation of along_m, metres.")
    sigma_heading: float = Field(description="Standard deviation of the heading, radians.")
    locked: bool = Field(description="Sure enough to steer by.")
    length_m: float = Field(description="Length of the taught path, metres.")
    image_id: int = Field(description="The taught image nearest the estimate.")
    x: float = Field(description="The robot's position in the edge's frame (its first image), m.")
    y: float = Field(description="The robot's position in the edge's frame, metres (left).")
    theta: float = Field(description="The robot's heading in the edge's frame, radians.")


class TaskPublic(_Model):
    id: int
    tour: int
    goal: str
    state: TaskStateName
    reason: str | None = Field(default=None, description="Why it failed or was cancelled.")
    started_at: float
    ended_at: float | None = None
    steps: int = Field(description="Frames answered for this task.")


class NavigationFrameResult(_Model):
    """A frame taken while navigating (or tracking after a task ended): the next command."""

    mode: Literal["navigating"]
    command: MotionCommand
    task: TaskPublic | None
    belief: BeliefPublic
    votes: dict[str, float] = Field(description="Vote mass of every action.")
    path: PathPublic | None = Field(
        default=None,
        description="Where the robot is relative to the taught path it tracks (topometric "
        "repeat), while it tracks one.",
    )


class FrameResult(_Model):
    """A frame taken while teaching: kept on the open path (or, from a streaming robot, as a
    spin image, or not kept while it stands still), with the command to obey."""

    mode: Literal["teaching"]
    image: ImageStored | None = Field(
        default=None,
        description="The image as stored; null when the frame was not kept (a streaming robot "
        "standing still, or before the first place was named).",
    )
    open_path_images: int
    command: MotionCommand | None = Field(
        default=None,
        description="What to do until the next answer: drive as a person commands (behaviour "
        "'teleop'), spin at a new place ('spin') or stand ('stand'). Set in every answer of "
        "POST /robots/{robot}/frames.",
    )
    spin_images: int | None = Field(
        default=None,
        description="While the server spins the robot at a new place: the place's spin images "
        "so far (this frame included when it was kept as one).",
    )


class IdleFrameResult(_Model):
    """A frame from a robot that is neither teaching nor navigating: the command to obey (a
    person driving it, or stand)."""

    mode: Literal["idle"]
    command: MotionCommand


AnyFrameResult = Annotated[
    FrameResult | NavigationFrameResult | IdleFrameResult, Field(discriminator="mode")
]


class NavigationState(_Model):
    tour: int
    task: TaskPublic | None
    belief: BeliefPublic | None
    last_command: MotionCommand | None


# --- driving by hand (teleop) ----------------------------------------------------------------

MAX_TELEOP_TTL_S = 2.0
"""Longest a teleop command may stay in force without being sent again, seconds."""


class TeleopCommand(_Model):
    """POST /robots/{robot}/teleop: drive the robot by hand (a phone, a gamepad script, the
    dashboard's arrows). The command stays in force for ``ttl_s`` only: send it again faster
    than that while driving, and the robot stops by itself when the sender goes quiet (a dead
    man's switch). ``{"v": 0, "w": 0}`` stops at once. Speeds beyond the server's teleop
    limit are clamped to it; beyond the physical bounds they are refused (422)."""

    v: float = Field(
        ge=-MAX_LINEAR_SPEED,
        le=MAX_LINEAR_SPEED,
        allow_inf_nan=False,
        description="Linear velocity, m/s (forward positive).",
    )
    w: float = Field(
        ge=-MAX_ANGULAR_SPEED,
        le=MAX_ANGULAR_SPEED,
        allow_inf_nan=False,
        description="Angular velocity, rad/s (counter-clockwise, i.e. left, positive).",
    )
    ttl_s: float = Field(
        default=0.5,
        gt=0.0,
        le=MAX_TELEOP_TTL_S,
        allow_inf_nan=False,
        description="Seconds the command stays in force unless sent again (0 < ttl_s <= 2).",
    )


class TeleopState(_Model):
    """The teleop command now in force, as clamped to the server's limit."""

    robot: str
    v: float = Field(description="Linear velocity the robot is told, m/s.")
    w: float = Field(description="Angular velocity the robot is told, rad/s.")
    clamped: bool = Field(description="True when v or w was beyond the limit and cut to it.")
    max_v: float = Field(description="The server's teleop limit on |v|, m/s.")
    max_w: float = Field(description="The server's teleop limit on |w|, rad/s.")
    ttl_s: float = Field(description="Seconds it stays in force unless sent again.")
    mode: Literal["idle", "teaching"]


class SpinPublic(_Model):
    """The server spinning the robot once at a new place to photograph it."""

    place: str
    images: int = Field(description="Spin images kept so far.")
    turned_deg: float = Field(description="How far it has turned, by its odometry, degrees.")
    state: Literal["spinning", "done", "timeout", "stopped"] = Field(
        description="'done': one full turn; 'timeout': it did not turn a full turn in the time "
        "allowed (blocked, or no odometry); 'stopped': stopped on request or teaching ended."
    )


class RobotControlPublic(_Model):
    """What the server tells a streaming robot outside navigation (docs/robot.md)."""

    connected: bool = Field(description="A frame came within the last 2 s.")
    last_frame_age_s: float | None = Field(description="Seconds since its last frame.")
    teleop: TeleopState | None = Field(description="A person driving it, while in force.")
    spin: SpinPublic | None = Field(description="The spin under way, or the last one.")


class RobotState(_Model):
    name: str
    mode: Literal["idle", "teaching", "navigating"]
    teaching: TeachingState | None = None
    navigation: NavigationState | None = None
    control: RobotControlPublic | None = Field(
        default=None, description="Driving by hand and spins (robots that stream frames)."
    )


# --- recordings ----------------------------------------------------------------------------

RecordingName = Annotated[
    str,
    StringConstraints(
        pattern=r"^[a-z0-9][a-z0-9_-]{0,63}\.tour[0-9]{1,16}\.[0-9]{8}-[0-9]{6}(-[0-9]{1,3})?"
        r"\.(teach|task[0-9]{1,16})\.mcap$"
    ),
    Field(
        description="File name of a recording: ROBOT.tourID.YYYYMMDD-HHMMSS.(teach|taskID).mcap "
        "(GET /robots/{robot}/recordings lists them)."
    ),
]


class RecordingPublic(_Model):
    """One recorded teaching tour or navigation task (an MCAP file: docs/recording.md)."""

    name: str = Field(description="File name; GET /robots/{robot}/recordings/{name} reads it.")
    kind: Literal["teach", "navigate"]
    tour: int
    task: int | None = Field(description="The navigation task's id (none for teaching).")
    started_at: float = Field(description="Unix time, s, from the file name (whole seconds).")
    size_bytes: int
    recording: bool = Field(description="True while the task is still being written.")


# --- households, logins, audit ------------------------------------------------------------


class HouseholdCreate(_Model):
    name: HouseholdName
    password: Password | None = Field(
        default=None, description="The household's login; without one it cannot log in yet."
    )


class PasswordSet(_Model):
    password: Password


class HouseholdPublic(_Model):
    id: int
    name: str
    created_at: float
    has_login: bool = Field(description="Whether a password is set.")
    robots: int
    tours: int


class LoginRequest(_Model):
    household: HouseholdName
    password: str = Field(max_length=256)


class LoginResult(_Model):
    token: str = Field(description="Bearer token of this login. Shown once; stored hashed.")
    household: str
    expires_at: float = Field(description="Unix time, s, after which the token is refused.")


class AuditEntry(_Model):
    id: int
    at: float = Field(description="Unix time, s.")
    actor: str = Field(description="admin, robot:<name>, household:<name> or login:<name>.")
    action: str = Field(description="Method and route, e.g. 'POST /robots/{robot}/goto'.")
    target: str = Field(description="The path that was called.")
    status: int
    address: str | None
