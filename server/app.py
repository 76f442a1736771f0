"""``create_app(settings)``: assembles storage, services and routes. Nothing runs at import."""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from importlib import resources

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse, JSONResponse
from fastapi.staticfiles import StaticFiles
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match, Mount

from server import schemas
from server.api.deps import PrincipalDep
from server.api.guard import Guard
from server.api.routes import (
    drive,
    households,
    images,
    navigate,
    questions,
    recordings,
    robots,
    teach,
    tours,
)
from server.api.worker import WorkerHeader
from server.config import Settings
from server.errors import DomainError, TooMany
from server.imaging import ImageLimits
from server.navigation import NavigationParams
from server.ratelimit import RateLimiter
from server.recording.store import Retention
from server.services.container import Services
from server.services.control import ControlParams
from server.services.households import LoginParams
from server.storage.repo import Repo
from server.tuning import tuned

DOCS_ASSETS = "/docs-assets"
"""Where Swagger UI's script, style sheet and icon are served from (for /docs)."""


def _swagger_ui_dir() -> str:
    """Swagger UI 5 as installed by the ``fastapi-offline`` package (its bundled files only):
    /docs must work on a home network without internet, so nothing is fetched from a CDN."""
    return str(resources.files("fastapi_offline") / "static")


log = logging.getLogger(__name__)


def _error(
    status: int, detail: str, code: str, headers: dict[str, str] | None = None
) -> JSONResponse:
    body = schemas.ErrorBody(detail=detail, code=code)
    return JSONResponse(body.model_dump(), status_code=status, headers=headers)


def _validation_message(exc: RequestValidationError) -> str:
    parts = []
    for err in exc.errors():
        if err.get("type") == "json_invalid":
            parts.append(f"body: {_json_error(err, exc.body)}")
            continue
        where = ".".join(str(p) for p in err.get("loc", ()) if p != "body") or "body"
        parts.append(f"{where}: {err.get('msg', 'invalid')}")
    return "invalid request - " + "; ".join(parts)


def _json_error(err: dict[str, object], document: object) -> str:
    """Where and why a body is not JSON: "JSON decode error at line 1, column 12: Expecting ','
    delimiter". FastAPI puts the character offset in ``loc``, the reason in ``ctx`` and the
    text in the exception's ``body``."""
    loc = err.get("loc")
    offset = loc[1] if isinstance(loc, tuple) and len(loc) > 1 else None
    ctx = err.get("ctx")
    reason = ctx.get("error") if isinstance(ctx, dict) else None
    where = ""
    if isinstance(offset, int) and isinstance(document, str):
        line = document.count("\n", 0, offset) + 1
        column = offset - document.rfind("\n", 0, offset)
        where = f" at line {line}, column {column}"
    elif isinstance(offset, int):
        where = f" at character {offset}"
    return f"{err.get('msg', 'JSON decode error')}{where}" + (f": {reason}" if reason else "")


def _allowed_methods(request: Request) -> str:
    """The ``Allow`` header of a 405: every method some route answers at this path (Starlette
    names only the first route's, e.g. POST alone for /tours), found by asking each route."""
    allowed = [
        method
        for method in ("GET", "POST", "PUT", "PATCH", "DELETE")
        if any(
            route.matches({**request.scope, "method": method})[0] == Match.FULL
            for route in request.app.router.routes
            if not isinstance(route, Mount)  # static files: a mount matches any method
        )
    ]
    return ", ".join(allowed)


async def _sweep_forever(services: Services, period_s: float = 1.0) -> None:
    """Fail the tasks of robots that stopped sending frames (off the event loop)."""
    while True:
        await asyncio.sleep(period_s)
        await run_in_threadpool(services.navigation.sweep)


async def _forget_forever(repo: Repo, keep_s: float, period_s: float = 3600.0) -> None:
    """Every ``period_s``: delete audit entries older than ``keep_s`` and expired logins."""
    while True:
        try:
            await run_in_threadpool(repo.forget_before, time.time() - keep_s, time.time())
        except DomainError as exc:  # a read-only or full disk: try again next time
            log.warning("old audit entries not deleted: %s", exc.message)
        await asyncio.sleep(period_s)


def create_app(
    settings: Settings,
    *,
    navigation: NavigationParams | None = None,
    clock: Callable[[], float] = time.monotonic,
    wall_clock: Callable[[], float] = time.time,
) -> FastAPI:
    """The FastAPI application for ``settings`` (database, admin token, limits);
    ``navigation`` tunes the navigation core (defaults documented in NavigationParams);
    ``clock`` is what the rate limits read the time from (seconds, monotonic);
    ``wall_clock`` (unix seconds) is when the robot's questions are asked and expire (stored,
    so it must be a wall clock; tests pass their own)."""
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
        Repo(settings.database()),
        admin_token=settings.admin_token.get_secret_value(),
        limits=limits,
        navigation=navigation,
        concurrent_steps=settings.concurrent_steps,
        logins=LoginParams(lifetime_s=settings.login_hours * 3600.0),
        recordings=settings.recordings_dir(),
        record_all=settings.record,
        retention=Retention(
            keep_files=settings.record_keep_files,
            keep_bytes=round(settings.record_keep_mb * 1e6),
            file_bytes=round(settings.record_file_mb * 1e6),
        ),
        shared_store=settings.worker_name is not None,  # one of several processes on the file
        wall_clock=wall_clock,
        control=ControlParams(
            max_v=settings.teleop_max_v, max_w=settings.teleop_max_w, spin_w=settings.spin_w
        ),
    )

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        watchdog = asyncio.create_task(_sweep_forever(services))
        forgetting = asyncio.create_task(
            _forget_forever(services.repo, settings.audit_days * 86400.0)
        )
        try:
            yield
        finally:
            watchdog.cancel()
            forgetting.cancel()
            services.close()

    app = FastAPI(
        title="teachrepeat",
        version="0.1.0",
        description="Teach a camera-only robot a home in one guided tour, then send it anywhere.",
        lifespan=lifespan,
        docs_url=None,  # served below from local files: a home network may have no internet
        redoc_url=None,
    )
    app.state.services = services
    app.state.settings = settings

    @app.exception_handler(DomainError)
    async def domain_error(request: Request, exc: DomainError) -> JSONResponse:
        headers = {"WWW-Authenticate": "Bearer"} if exc.status == 401 else None
        if isinstance(exc, TooMany):
            headers = {"Retry-After": str(max(1, math.ceil(exc.retry_after_s)))}
        return _error(exc.status, exc.message, exc.code, headers)

    @app.exception_handler(RequestValidationError)
    async def validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        return _error(422, _validation_message(exc), "invalid")

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        code = {404: "not_found", 405: "method_not_allowed"}.get(exc.status_code, "http_error")
        headers = dict(exc.headers or {})
        if exc.status_code == 405 and "Allow" in headers:  # raised by the router
            headers["Allow"] = _allowed_methods(request) or headers["Allow"]
        return _error(exc.status_code, str(exc.detail), code, headers or None)

    @app.get("/", tags=["health"], response_model=schemas.ServiceIndex)
    def index(request: Request) -> schemas.ServiceIndex:
        """Where the API documentation and the dashboard are."""
        port = request.app.state.settings.dashboard_port
        host = request.url.hostname or settings.host
        return schemas.ServiceIndex(
            version=app.version,
            docs="/docs",
            openapi=app.openapi_url or "/openapi.json",
            dashboard=None if not port else f"http://{host}:{port}",
        )

    app.mount(DOCS_ASSETS, StaticFiles(directory=_swagger_ui_dir()), name="docs-assets")

    @app.get("/docs", include_in_schema=False)
    def docs() -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url=app.openapi_url or "/openapi.json",
            title=f"{app.title} - API",
            swagger_js_url=f"{DOCS_ASSETS}/swagger-ui-bundle.js",
            swagger_css_url=f"{DOCS_ASSETS}/swagger-ui.css",
            swagger_favicon_url=f"{DOCS_ASSETS}/favicon.png",
            oauth2_redirect_url=None,
        )

    @app.get("/health", tags=["health"])
    def health() -> dict[str, object]:
        found: dict[str, object] = {"status": "ok", "schema_version": services.repo.schema_version}
        if settings.worker_name is not None:
            found["worker"] = settings.worker_name
        return found

    @app.get(
        "/whoami",
        tags=["robots"],
        response_model=schemas.WhoAmI,
        responses={
            401: {"model": schemas.ErrorBody, "description": "Missing or unknown bearer token."},
            "4XX": {"model": schemas.ErrorBody},
        },
    )
    def whoami(principal: PrincipalDep) -> schemas.WhoAmI:
        """Who the bearer token belongs to: the admin, a robot or a household login."""
        return schemas.WhoAmI(
            kind=principal.kind, robot=principal.robot, household=principal.household_name
        )

    for module in (
        tours,
        robots,
        teach,
        navigate,
        drive,
        questions,
        recordings,
        images,
        households,
    ):
        app.include_router(module.router, responses={"4XX": {"model": schemas.ErrorBody}})
    app.add_middleware(
        Guard,
        limiter=RateLimiter(settings.rate_limits()),
        record=services.repo.add_audit,
        clock=clock,
    )
    if settings.worker_name is not None:  # one of several behind HAProxy (docs/scale.md)
        app.add_middleware(WorkerHeader, name=settings.worker_name)
    return app
