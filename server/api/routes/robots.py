"""Robots: registration (admin) and state."""

from __future__ import annotations

from fastapi import APIRouter, status

from server import schemas
from server.api.deps import AdminDep, RobotDep, ServicesDep

router = APIRouter(prefix="/robots", tags=["robots"])


@router.post("", status_code=status.HTTP_201_CREATED, response_model=schemas.RobotRegistered)
def register_robot(
    body: schemas.RobotCreate, services: ServicesDep, _: AdminDep
) -> schemas.RobotRegistered:
    """Register a robot (admin). The answer holds its bearer token, shown only this once."""
    return services.robots.register(body)


@router.get("", response_model=list[schemas.RobotPublic])
def list_robots(services: ServicesDep, _: AdminDep) -> list[schemas.RobotPublic]:
    return services.robots.list()


@router.get("/{robot}/state", response_model=schemas.RobotState)
def robot_state(robot: RobotDep, services: ServicesDep) -> schemas.RobotState:
    """Mode (idle, teaching, navigating) and what the robot is doing."""
    return services.robot_state(robot)
