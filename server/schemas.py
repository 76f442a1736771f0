"""Wire schemas: the pydantic models of every request and response body.

The single source of truth for what crosses HTTP, shared by the server and the robot client.
Importing this module pulls in pydantic and the standard library only.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, StringConstraints, field_validator

RobotName = Annotated[
    str,
    StringConstraints(pattern=r"^[a-z0-9][a-z0-9_-]{0,63}$"),
    Field(description="Lower-case letters, digits, '-' and '_', 1 to 64 characters."),
]
TourName = Annotated[
    str,
    StringConstraints(strip_whitespace=True, min_length=1, max_length=100),
    Field(description="Unique name of the tour, 1 to 100 characters."),
]
LocationName = Annotated[
    str,
    StringConstraints(strip_whitespace=True, min_length=1, max_length=64),
    Field(description="Name of the place, unique within its tour, 1 to 64 characters."),
]


DbId = Annotated[int, Field(ge=1, le=2**63 - 1, description="A database id.")]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class ErrorBody(_Model):
    """Every 4xx/5xx answer."""

    detail: str = Field(description="What was wrong and what to do about it.")
    code: str = Field(description="Machine-readable error kind, e.g. 'not_found'.")


# --- tours -------------------------------------------------------------------------------


class TourCreate(_Model):
    name: TourName


class TourSummary(_Model):
    id: int
    name: str
    locations: int
    edges: int
    images: int


class LocationPublic(_Model):
    id: int
    name: str
    image_count: int
    image_ids: list[int] = Field(description="Spin images, in the order they were taken.")


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


class TourGraphPublic(_Model):
    id: int
    name: str
    locations: list[LocationPublic]
    edges: list[EdgePublic]


# --- robots ------------------------------------------------------------------------------


class RobotCreate(_Model):
    name: RobotName


class RobotRegistered(_Model):
    name: str
    token: str = Field(description="Bearer token of the robot. Shown once; stored hashed.")


class WhoAmI(_Model):
    kind: Literal["admin", "robot"]
    robot: str | None = Field(default=None, description="The robot's name for a robot token.")


class RobotPublic(_Model):
    name: str
    created_at: float


# --- teaching ----------------------------------------------------------------------------


class TeachStart(_Model):
    tour: DbId = Field(description="Id of the tour to teach (create it with POST /tours).")


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


class FrameMeta(_Model):
    """Query parameters that come with every frame (the body is the JPEG)."""

    timestamp: float = Field(description="Capture time, seconds, non-decreasing per robot.")
    v: float = Field(default=0.0, description="Linear velocity being executed, m/s.")
    w: float = Field(default=0.0, description="Angular velocity being executed, rad/s.")
    depth: list[float] | None = Field(
        default=None,
        max_length=256,
        description="Optional depth profile: ranges in metres, leftmost ray first "
        "(repeat the parameter: depth=1.2&depth=0.9...). Use a large number for 'nothing'.",
    )

    @field_validator("timestamp", "v", "w")
    @classmethod
    def _finite(cls, value: float) -> float:
        if not math.isfinite(value):
            raise ValueError("must be a finite number")
        return value

    @field_validator("depth")
    @classmethod
    def _ranges(cls, value: list[float] | None) -> list[float] | None:
        if value is not None and any(not (r >= 0) or math.isnan(r) for r in value):
            raise ValueError("ranges must be non-negative numbers")
        return value


class FrameResult(_Model):
    """A frame taken while teaching: stored on the open path."""

    mode: Literal["teaching"]
    image: ImageStored
    open_path_images: int


# --- navigation ----------------------------------------------------------------------------

ActionName = Literal["rotate_and_find_edge", "navigate", "explore", "do_nothing"]
TaskStateName = Literal["underway", "arrived", "failed", "cancelled"]


class GotoRequest(_Model):
    location: LocationName
    tour: DbId | None = Field(
        default=None,
        description="Tour to navigate in; defaults to the tour the robot last used.",
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
        "unstick, backoff, escape, settle, dock or place-dock (server.navigation.BEHAVIOURS).",
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


AnyFrameResult = Annotated[FrameResult | NavigationFrameResult, Field(discriminator="mode")]


class NavigationState(_Model):
    tour: int
    task: TaskPublic | None
    belief: BeliefPublic | None
    last_command: MotionCommand | None


class RobotState(_Model):
    name: str
    mode: Literal["idle", "teaching", "navigating"]
    teaching: TeachingState | None = None
    navigation: NavigationState | None = None
