"""Navigation: "go to the kitchen", and stop."""

from __future__ import annotations

from fastapi import APIRouter
from starlette.concurrency import run_in_threadpool

from server import schemas
from server.api.deps import RobotDep, ServicesDep

router = APIRouter(prefix="/robots/{robot}", tags=["navigation"])


@router.post("/goto", response_model=schemas.TaskPublic)
async def goto(
    body: schemas.GotoRequest, robot: RobotDep, services: ServicesDep
) -> schemas.TaskPublic:
    """Start a navigation task to a named place. The robot's frames are then answered with
    motion commands until it arrives, fails, or is stopped. A new goto replaces the goal."""
    return await run_in_threadpool(services.navigation.goto, robot, body)


@router.post("/stop", response_model=schemas.TaskPublic)
def stop(robot: RobotDep, services: ServicesDep) -> schemas.TaskPublic:
    """Cancel the navigation underway (409 when there is none)."""
    return services.navigation.stop(robot)
