"""``create_app(settings)``: assembles storage, services and routes. Nothing runs at import."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException as StarletteHTTPException

from server import schemas
from server.api.deps import PrincipalDep
from server.api.routes import images, navigate, robots, teach, tours
from server.config import Settings
from server.errors import DomainError
from server.imaging import ImageLimits
from server.navigation import NavigationParams
from server.services.container import Services
from server.storage.repo import Repo
from server.tuning import tuned


def _error(
    status: int, detail: str, code: str, headers: dict[str, str] | None = None
) -> JSONResponse:
    body = schemas.ErrorBody(detail=detail, code=code)
    return JSONResponse(body.model_dump(), status_code=status, headers=headers)


def _validation_message(exc: RequestValidationError) -> str:
    parts = []
    for err in exc.errors():
        where = ".".join(str(p) for p in err.get("loc", ()) if p != "body") or "body"
        parts.append(f"{where}: {err.get('msg', 'invalid')}")
    return "invalid request - " + "; ".join(parts)


async def _sweep_forever(services: Services, period_s: float = 1.0) -> None:
    """Fail the tasks of robots that stopped sending frames (off the event loop)."""
    while True:
        await asyncio.sleep(period_s)
        await run_in_threadpool(services.navigation.sweep)


def create_app(settings: Settings, *, navigation: NavigationParams | None = None) -> FastAPI:
    """The FastAPI application for ``settings`` (database, admin token, limits);
    ``navigation`` tunes the navigation core (defaults documented in NavigationParams)."""
    if settings.admin_token is None:
        raise ValueError("settings.admin_token is required (serve generates one when unset)")
    if settings.navigation:
        navigation = tuned(navigation or NavigationParams(), settings.navigation)
    limits = ImageLimits(
        max_bytes=settings.max_image_bytes,
        max_pixels=settings.max_image_pixels,
        max_side=settings.max_image_side,
        min_side=settings.min_image_side,
    )
    services = Services.build(
        Repo(settings.db),
        admin_token=settings.admin_token.get_secret_value(),
        limits=limits,
        navigation=navigation,
        concurrent_steps=settings.concurrent_steps,
    )

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        watchdog = asyncio.create_task(_sweep_forever(services))
        try:
            yield
        finally:
            watchdog.cancel()
            services.close()

    app = FastAPI(
        title="teachrepeat",
        version="0.1.0",
        description="Teach a camera-only robot a home in one guided tour, then send it anywhere.",
        lifespan=lifespan,
    )
    app.state.services = services
    app.state.settings = settings

    @app.exception_handler(DomainError)
    async def domain_error(request: Request, exc: DomainError) -> JSONResponse:
        headers = {"WWW-Authenticate": "Bearer"} if exc.status == 401 else None
        return _error(exc.status, exc.message, exc.code, headers)

    @app.exception_handler(RequestValidationError)
    async def validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        return _error(422, _validation_message(exc), "invalid")

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        code = {404: "not_found", 405: "method_not_allowed"}.get(exc.status_code, "http_error")
        return _error(exc.status_code, str(exc.detail), code)

    @app.get("/health", tags=["health"])
    def health() -> dict[str, object]:
        return {"status": "ok", "schema_version": services.repo.schema_version}

    @app.get("/whoami", tags=["robots"], response_model=schemas.WhoAmI)
    def whoami(principal: PrincipalDep) -> schemas.WhoAmI:
        """Who the bearer token belongs to: the admin or a robot (and which)."""
        return schemas.WhoAmI(kind=principal.kind, robot=principal.robot)

    for module in (tours, robots, teach, navigate, images):
        app.include_router(module.router, responses={"4XX": {"model": schemas.ErrorBody}})
    return app
