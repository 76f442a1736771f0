"""Teaching a tour, and the frames a robot streams."""

from __future__ import annotations

from fastapi import APIRouter, Request
from starlette.concurrency import run_in_threadpool

from server import schemas
from server.api.deps import RobotDep, RobotPath, ServicesDep, read_upload, upload_openapi

router = APIRouter(prefix="/robots/{robot}", tags=["teaching"])
UPLOAD_OPENAPI = upload_openapi(schemas.FrameMeta)


@router.post("/teach/start", response_model=schemas.TeachingState)
def start(
    body: schemas.TeachStart, robot: RobotDep, services: ServicesDep
) -> schemas.TeachingState:
    """Begin teaching a tour. Then name the starting place with POST .../teach/locations."""
    return services.teaching.start(robot, body)


@router.post("/teach/locations", response_model=schemas.MarkResult)
def mark_location(
    body: schemas.LocationMark, robot: RobotDep, services: ServicesDep
) -> schemas.MarkResult:
    """ "This is the kitchen": creates the place, or closes the open path into the existing
    place of that name. The frames since the previous place become one edge."""
    return services.teaching.mark(robot, body)


@router.post("/teach/spin", response_model=schemas.ImageStored, openapi_extra=UPLOAD_OPENAPI)
async def spin_image(request: Request, robot: RobotPath) -> schemas.ImageStored:
    """One image taken while spinning at the current place (JPEG body)."""
    up = await read_upload(request, robot, schemas.FrameMeta)
    return await run_in_threadpool(up.services.teaching.spin_image, up.robot, up.body, up.meta)


@router.post("/teach/finish", response_model=schemas.TeachingEnded)
def finish(robot: RobotDep, services: ServicesDep) -> schemas.TeachingEnded:
    """End teaching. Refused while the open path has frames: mark its place or abort."""
    return services.teaching.finish(robot)


@router.post("/teach/abort", response_model=schemas.TeachingEnded)
def abort(robot: RobotDep, services: ServicesDep) -> schemas.TeachingEnded:
    """End teaching, discarding only the open path; marked places and edges stay."""
    return services.teaching.abort(robot)


@router.post("/frames", response_model=schemas.AnyFrameResult, openapi_extra=UPLOAD_OPENAPI)
async def frame(request: Request, robot: RobotPath) -> schemas.AnyFrameResult:
    """A camera frame (JPEG body) with its timestamp, odometry and optional depth profile.
    While teaching it is appended to the open path; while navigating it is answered with the
    next motion command."""
    up = await read_upload(request, robot, schemas.FrameMeta)
    return await run_in_threadpool(up.services.frame, up.robot, up.body, up.meta)
