"""Households (admin), household logins, and the audit log (admin)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Query, Request, Response, status
from starlette.concurrency import run_in_threadpool

from server import schemas
from server.api.deps import AdminDep, LoginDep, ServicesDep
from server.api.guard import bearer_token
from server.schemas import MAX_ID

router = APIRouter(tags=["households"])
HouseholdId = Annotated[int, Path(ge=1, le=MAX_ID, description="Household id.")]


@router.post(
    "/households", status_code=status.HTTP_201_CREATED, response_model=schemas.HouseholdPublic
)
async def create_household(
    body: schemas.HouseholdCreate, services: ServicesDep, _: AdminDep
) -> schemas.HouseholdPublic:
    """Create a household (admin), optionally with its login password."""
    return await run_in_threadpool(services.households.create, body)


@router.get("/households", response_model=list[schemas.HouseholdPublic])
def list_households(services: ServicesDep, _: AdminDep) -> list[schemas.HouseholdPublic]:
    return services.households.list()


@router.put("/households/{household_id}/password", status_code=status.HTTP_204_NO_CONTENT)
async def set_password(
    household_id: HouseholdId, body: schemas.PasswordSet, services: ServicesDep, _: AdminDep
) -> Response:
    """Set or change a household's login password (admin). Existing logins stay valid
    until they expire or log out."""
    await run_in_threadpool(services.households.set_password, household_id, body)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.post("/auth/login", response_model=schemas.LoginResult)
async def login(
    body: schemas.LoginRequest, request: Request, services: ServicesDep
) -> schemas.LoginResult:
    """Log in as a household: the answer's token is a bearer token for that household's
    tours, images and robots until it expires or logs out. Repeated failures make the next
    try wait (429 with Retry-After)."""
    request.state.actor = f"login:{body.household}"
    return await run_in_threadpool(services.households.login, body)


@router.post("/auth/logout", status_code=status.HTTP_204_NO_CONTENT)
async def logout(request: Request, services: ServicesDep, _: LoginDep) -> Response:
    """End this household login: its token fails from now on."""
    token = bearer_token(request.scope)
    if token is not None:  # always: the login dependency authenticated it
        await run_in_threadpool(services.households.logout, token)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.get("/audit", response_model=list[schemas.AuditEntry])
def audit(
    services: ServicesDep,
    _: AdminDep,
    limit: Annotated[int, Query(ge=1, le=1000, description="Entries to return.")] = 100,
    before: Annotated[
        int | None, Query(ge=1, le=MAX_ID, description="Only entries older than this id.")
    ] = None,
) -> list[schemas.AuditEntry]:
    """State-changing calls, newest first (admin): who, what, when, the answer's status."""
    return [
        schemas.AuditEntry(**vars(row))
        for row in services.repo.audit(limit=limit, before_id=before)
    ]
