"""Typed dependencies: the services, the caller's identity, bounded request bodies, and the
robot's image uploads read in one call (:func:`read_upload`)."""

from __future__ import annotations

import functools
import types
from dataclasses import dataclass
from typing import Annotated, Any, Generic, TypeVar, Union, get_args, get_origin

from fastapi import Depends, Path, Request, Security
from fastapi.exceptions import RequestValidationError
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from pydantic import BaseModel, ValidationError
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


async def authenticate(
    request: Request, services: Services, credentials: HTTPAuthorizationCredentials | None
) -> Principal:
    """The caller of ``request``, from its bearer ``credentials`` (401 without a valid one).

    Async, so a frame does not hop through the thread pool to be authenticated: a known
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


async def get_principal(
    request: Request,
    services: ServicesDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Security(_bearer)],
) -> Principal:
    return await authenticate(request, services, credentials)


PrincipalDep = Annotated[Principal, Depends(get_principal)]
RobotPath = Annotated[RobotName, Path(description="Name of the robot.")]


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


async def may_act_for(services: Services, principal: Principal, robot: str) -> str:
    """``robot``, when ``principal`` may act for it: the robot itself, or a login of its
    household. A robot of another household is answered as one that does not exist (404);
    another robot of the same household is refused (403)."""
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


async def robot_access(services: ServicesDep, principal: PrincipalDep, robot: RobotPath) -> str:
    """The robot named in the path, when the caller may act for it (:func:`may_act_for`)."""
    return await may_act_for(services, principal, robot)


RobotDep = Annotated[str, Depends(robot_access)]


async def robot_manage(services: ServicesDep, principal: PrincipalDep, robot: RobotPath) -> str:
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


async def read_image_body(request: Request, services: Services) -> bytes:
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


IMAGE_BODY_OPENAPI = {
    "requestBody": {
        "required": True,
        "content": {"image/jpeg": {"schema": {"type": "string", "format": "binary"}}},
    }
}


Meta = TypeVar("Meta", bound=BaseModel)


def _is_list(annotation: Any) -> bool:
    """``list[...]``, or a union holding one (``list[float] | None``)."""
    if get_origin(annotation) is list:
        return True
    if get_origin(annotation) in (Union, types.UnionType):
        return any(_is_list(a) for a in get_args(annotation))
    return False


def read_query(model: type[Meta], request: Request) -> Meta:
    """``request``'s query string as ``model``: a list field takes every value of its name
    (``depth=1.2&depth=0.9``), any other the last one; a name the model does not have is
    passed on for the model to refuse. A refusal is FastAPI's 422 (each error's ``loc``
    starts with ``"query"``), as for a ``Query()`` model parameter."""
    params = request.query_params
    values = {
        name: params.getlist(name) if name in _list_fields(model) else params[name]
        for name in params
    }
    try:
        return model.model_validate(values)
    except ValidationError as exc:
        errors = [{**e, "loc": ("query", *e["loc"])} for e in exc.errors(include_url=False)]
        raise RequestValidationError(errors) from None


@functools.cache
def _list_fields(model: type[BaseModel]) -> frozenset[str]:
    return frozenset(
        name for name, field in model.model_fields.items() if _is_list(field.annotation)
    )


def query_openapi(model: type[BaseModel]) -> list[dict[str, Any]]:
    """The OpenAPI ``parameters`` of ``model`` read with :func:`read_query` (one query
    parameter per field, as FastAPI lists a ``Query()`` model's)."""
    schema = model.model_json_schema()
    if "$defs" in schema:
        raise TypeError(f"{model.__name__}: a query model cannot nest models")
    required = set(schema.get("required", ()))
    return [
        {
            "name": name,
            "in": "query",
            "required": name in required,
            "schema": prop,
            **({"description": prop["description"]} if "description" in prop else {}),
        }
        for name, prop in schema["properties"].items()
    ]


@dataclass(frozen=True)
class Upload(Generic[Meta]):
    """An image a robot sent (teaching or navigating): who, its query metadata, its JPEG."""

    services: Services
    robot: str
    meta: Meta
    body: bytes


async def read_upload(request: Request, robot: str, model: type[Meta]) -> Upload[Meta]:
    """What an image upload's route needs, read in one call and refused in the order the
    dependencies would refuse it: the caller (401), its right to act for ``robot`` (403,
    404), the body (415, 413), then the query string as ``model`` (422).

    The frames route runs ten times a second per robot. Declared as dependencies, these
    inputs are nine dependants that FastAPI walks, classifies and caches on every request:
    in-process the route took 0.42-0.47 ms of CPU with them, 0.31-0.35 ms without
    (docs/reliability.md, 2026-11-29). Routes that
    take it declare :func:`upload_openapi`, so their documentation is unchanged."""
    services: Services = request.app.state.services
    principal = await authenticate(request, services, await _bearer(request))
    await may_act_for(services, principal, robot)
    body = await read_image_body(request, services)
    return Upload(services=services, robot=robot, meta=read_query(model, request), body=body)


def upload_openapi(model: type[BaseModel]) -> dict[str, Any]:
    """``openapi_extra`` of a route that takes :func:`read_upload`: the JPEG body, ``model``'s
    query parameters and the bearer token."""
    return {
        **IMAGE_BODY_OPENAPI,
        "parameters": query_openapi(model),
        "security": [{_bearer.scheme_name: []}],
    }
