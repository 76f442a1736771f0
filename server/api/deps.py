"""Typed dependencies: the services, the caller's identity, bounded request bodies."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Path, Request, Security
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.concurrency import run_in_threadpool

from server.errors import Forbidden, NotFound, TooLarge, Unauthorized, UnsupportedMedia
from server.schemas import RobotName
from server.security import hash_token, same_token
from server.services.container import Services
from server.services.households import ADMIN, Principal


async def get_services(request: Request) -> Services:
    services: Services = request.app.state.services
    return services


ServicesDep = Annotated[Services, Depends(get_services)]

_bearer = HTTPBearer(
    auto_error=False,
    description="A robot's token, a household login (POST /auth/login) or the admin token.",
)


async def get_principal(
    request: Request,
    services: ServicesDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Security(_bearer)],
) -> Principal:
    """Async, so a frame does not hop through the thread pool to be authenticated: a known
    token is answered from memory, an unknown one is looked up in a worker thread. The caller
    is kept on ``request.state.principal`` for the audit log."""
    if credentials is None or credentials.scheme.lower() != "bearer":
        raise Unauthorized("missing bearer token: send 'Authorization: Bearer <token>'")
    token = credentials.credentials
    if same_token(token, services.admin_token):
        principal: Principal | None = ADMIN
    else:
        token_hash = hash_token(token)
        principal = services.identities.cached(token_hash)
        if principal is None:
            principal = await run_in_threadpool(services.identities.lookup, token_hash)
    if principal is None:
        raise Unauthorized(
            "the bearer token is not valid (unknown, revoked or expired); use a robot's current "
            "token or log in again with POST /auth/login"
        )
    request.state.principal = principal
    return principal


PrincipalDep = Annotated[Principal, Depends(get_principal)]


async def require_admin(principal: PrincipalDep) -> Principal:
    if principal.kind != "admin":
        raise Forbidden("this needs the admin token; a robot token or household login cannot")
    return principal


AdminDep = Annotated[Principal, Depends(require_admin)]


async def require_household(principal: PrincipalDep) -> int:
    """The caller's household (a robot's or a login's). The admin token is for administration
    (households, robots, audit) only: it reads no tour, image or robot's camera."""
    if principal.household is None:
        raise Forbidden(
            "the admin token is for administration only; use a robot token or a household "
            "login (POST /auth/login) to reach a household's tours, images and robots"
        )
    return principal.household


HouseholdDep = Annotated[int, Depends(require_household)]


async def require_login(principal: PrincipalDep) -> Principal:
    if principal.kind != "household":
        raise Forbidden("this needs a household login (POST /auth/login)")
    return principal


LoginDep = Annotated[Principal, Depends(require_login)]


async def robot_access(
    services: ServicesDep,
    principal: PrincipalDep,
    robot: Annotated[RobotName, Path(description="Name of the robot.")],
) -> str:
    """The robot named in the path, when the caller may act for it: the robot itself, or a
    login of its household. A robot of another household is answered as one that does not
    exist (404); another robot of the same household is refused (403)."""
    if principal.kind == "robot" and principal.robot == robot:
        return robot
    if principal.kind == "admin":
        raise Forbidden(
            "the admin token is for administration only; the robot's own token or a login of "
            "its household drives it"
        )
    owner = await run_in_threadpool(services.repo.robot_household, robot)
    if owner is None or owner != principal.household:
        raise NotFound(f"no robot named {robot!r}; GET /robots lists your household's robots")
    if principal.kind == "robot":
        raise Forbidden(
            f"this token belongs to robot {principal.robot!r}; it cannot read or drive {robot!r}"
        )
    return robot


RobotDep = Annotated[str, Depends(robot_access)]


async def robot_manage(
    services: ServicesDep,
    principal: PrincipalDep,
    robot: Annotated[RobotName, Path(description="Name of the robot.")],
) -> str:
    """The robot named in the path, when the caller may manage its token: the admin, or a
    login of its household (a robot cannot rotate or revoke tokens)."""
    if principal.kind == "robot":
        raise Forbidden("a robot token cannot manage tokens; use a household login")
    owner = await run_in_threadpool(services.repo.robot_household, robot)
    if owner is None or (principal.kind == "household" and owner != principal.household):
        raise NotFound(f"no robot named {robot!r}; GET /robots lists the robots")
    return robot


RobotManageDep = Annotated[str, Depends(robot_manage)]

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
