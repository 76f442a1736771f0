"""Robots: registration, state, and the token lifecycle (list, rotate, revoke)."""

from __future__ import annotations

from fastapi import APIRouter, status
from starlette.concurrency import run_in_threadpool

from server import schemas
from server.api.deps import PrincipalDep, RobotDep, RobotManageDep, ServicesDep
from server.errors import Forbidden, NotFound
from server.storage.repo import DEFAULT_HOUSEHOLD

router = APIRouter(prefix="/robots", tags=["robots"])


@router.post("", status_code=status.HTTP_201_CREATED, response_model=schemas.RobotRegistered)
async def register_robot(
    body: schemas.RobotCreate, services: ServicesDep, principal: PrincipalDep
) -> schemas.RobotRegistered:
    """Register a robot: a household login registers into its own household, the admin into
    the one named in the body (default: 'default'). The answer holds its bearer token, shown
    only this once."""
    if principal.kind == "robot":
        raise Forbidden("a robot token cannot register robots; use a household login")
    if principal.kind == "household":
        if body.household not in (None, principal.household_name):
            raise Forbidden("a household login registers robots into its own household only")
        household = principal.household
    elif body.household is None:
        household = DEFAULT_HOUSEHOLD
    else:
        row = await run_in_threadpool(services.repo.household_by_name, body.household)
        if row is None:
            raise NotFound(f"no household named {body.household!r}; GET /households lists them")
        household = row.id
    assert household is not None  # a household login always has one
    return await run_in_threadpool(services.robots.register, body, household)


@router.get("", response_model=list[schemas.RobotPublic])
def list_robots(services: ServicesDep, principal: PrincipalDep) -> list[schemas.RobotPublic]:
    """The robots of the caller's household (all robots for the admin), without tokens."""
    if principal.kind == "robot":
        raise Forbidden("a robot token cannot list robots; use a household login")
    return services.robots.list(principal.household)


@router.get("/{robot}/state", response_model=schemas.RobotState)
def robot_state(robot: RobotDep, services: ServicesDep) -> schemas.RobotState:
    """Mode (idle, teaching, navigating) and what the robot is doing."""
    return services.robot_state(robot)


@router.post("/{robot}/token", response_model=schemas.RobotRegistered)
def rotate_token(robot: RobotManageDep, services: ServicesDep) -> schemas.RobotRegistered:
    """A new token for the robot (household login or admin); the old one fails at once.
    The answer holds the new token, shown only this once."""
    return services.robots.rotate(robot)


@router.delete("/{robot}/token", response_model=schemas.RobotPublic)
def revoke_token(robot: RobotManageDep, services: ServicesDep) -> schemas.RobotPublic:
    """Revoke the robot's token (household login or admin): it fails at once, including
    where it was cached. POST .../token issues a new one."""
    return services.robots.revoke(robot)
