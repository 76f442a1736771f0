"""Driving a robot by hand (teleop), and halting whatever it does."""

from __future__ import annotations

from fastapi import APIRouter, Request
from starlette.concurrency import run_in_threadpool

from server import schemas
from server.api.deps import PrincipalDep, RobotDep, ServicesDep

router = APIRouter(prefix="/robots/{robot}", tags=["driving"])


@router.post("/teleop", response_model=schemas.TeleopState)
async def teleop(
    body: schemas.TeleopCommand,
    robot: RobotDep,
    services: ServicesDep,
    principal: PrincipalDep,
    request: Request,
) -> schemas.TeleopState:
    """Drive the robot by hand (a phone, a gamepad script): the robot's next answers carry
    this command until ``ttl_s`` runs out, so send it again while driving; ``{"v": 0, "w": 0}``
    stops at once. Speeds are clamped to the server's teleop limit. 409 while the robot
    navigates or spins at a new place, or when its agent sends no frames (not connected)."""
    address = request.client.host if request.client else None
    return await run_in_threadpool(
        services.control.teleop, robot, body, actor=principal.actor, address=address
    )


@router.post("/halt", response_model=schemas.RobotState)
def halt(robot: RobotDep, services: ServicesDep) -> schemas.RobotState:
    """Stop whatever the robot does (driving by hand, a spin at a new place, a navigation
    task); always 200, with the robot's state afterwards."""
    services.control.halt(robot)
    return services.robot_state(robot)
