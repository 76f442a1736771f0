"""Typed dependencies: the services, the caller's identity, bounded request bodies."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

from fastapi import Depends, Path, Request, Security
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.concurrency import run_in_threadpool

from server.errors import Forbidden, NotFound, TooLarge, Unauthorized, UnsupportedMedia
from server.schemas import RobotName
from server.security import hash_token, same_token
from server.services.container import Services


async def get_services(request: Request) -> Services:
    services: Services = request.app.state.services
    return services


ServicesDep = Annotated[Services, Depends(get_services)]

_bearer = HTTPBearer(auto_error=False, description="Robot token or the admin token.")


@dataclass(frozen=True)
class Principal:
    """Who is calling: the admin, or one registered robot."""

    kind: Literal["admin", "robot"]
    robot: str | None = None


async def get_principal(
    services: ServicesDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Security(_bearer)],
) -> Principal:
    """Async, so a frame does not hop through the thread pool to be authenticated: a known
    token is answered from memory, an unknown one is looked up in a worker thread."""
    if credentials is None or credentials.scheme.lower() != "bearer":
        raise Unauthorized("missing bearer token: send 'Authorization: Bearer <token>'")
    token = credentials.credentials
    if same_token(token, services.admin_token):
        return Principal("admin")
    token_hash = hash_token(token)
    robot = services.robots.cached_robot(token_hash)
    if robot is None:
        robot = await run_in_threadpool(services.robots.robot_for_token, token_hash)
    if robot is None:
        raise Unauthorized("the bearer token is not valid; use the token given at registration")
    return Principal("robot", robot)


PrincipalDep = Annotated[Principal, Depends(get_principal)]


async def require_admin(principal: PrincipalDep) -> Principal:
    if principal.kind != "admin":
        raise Forbidden("this needs the admin token; a robot token cannot do it")
    return principal


AdminDep = Annotated[Principal, Depends(require_admin)]


async def robot_access(
    services: ServicesDep,
    principal: PrincipalDep,
    robot: Annotated[RobotName, Path(description="Name of the robot.")],
) -> str:
    """The robot named in the path, when the caller may act for it (itself, or the admin)."""
    if principal.kind == "robot" and principal.robot != robot:
        raise Forbidden(
            f"this token belongs to robot {principal.robot!r}; it cannot read or drive {robot!r}"
        )
    if principal.kind == "admin" and not await run_in_threadpool(services.repo.robot_exists, robot):
        raise NotFound(f"no robot named {robot!r}; register it with POST /robots")
    return robot


RobotDep = Annotated[str, Depends(robot_access)]

JPEG_TYPES = {"image/jpeg", "image/jpg", "application/octet-stream"}


async def read_image_body(request: Request, services: ServicesDep) -> bytes:
    """The request body, refused with 413 as soon as it passes the byte limit (never buffered
    beyond it) and with 415 when its declared type is not JPEG."""
    content_type = request.headers.get("content-type", "image/jpeg").split(";")[0].strip().lower()
    if content_type not in JPEG_TYPES:
        raise UnsupportedMedia(
            f"Content-Type {content_type!r} is not accepted; send the frame as image/jpeg"
        )
    limit = services.limits.max_bytes
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > limit:
        raise TooLarge(f"the body is {declared} bytes; the limit is {limit} bytes")
    chunks: list[bytes] = []
    size = 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            raise TooLarge(f"the body is over the limit of {limit} bytes")
        chunks.append(chunk)
    return b"".join(chunks)


ImageBodyDep = Annotated[bytes, Depends(read_image_body)]

IMAGE_BODY_OPENAPI = {
    "requestBody": {
        "required": True,
        "content": {"image/jpeg": {"schema": {"type": "string", "format": "binary"}}},
    }
}
