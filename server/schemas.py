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
    tour: int = Field(description="Id of the tour to teach (create it with POST /tours).")


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

    @field_validator("timestamp", "v", "w")
    @classmethod
    def _finite(cls, value: float) -> float:
        if not math.isfinite(value):
            raise ValueError("must be a finite number")
        return value


class FrameResult(_Model):
    mode: Literal["teaching"]
    image: ImageStored
    open_path_images: int


class RobotState(_Model):
    name: str
    mode: Literal["idle", "teaching", "navigating"]
    teaching: TeachingState | None = None
