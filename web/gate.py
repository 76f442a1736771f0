"""The dashboard's login gate: what serves the dashboard port off loopback (and under TLS).

A small Starlette app in front of the viser dashboards:

* ``GET /login`` a plain form (no external assets); ``POST /login`` checks the household's name
  and password with the same service as ``POST /auth/login`` and keeps the login token in a
  cookie (HttpOnly, SameSite=Strict, Secure under TLS, as long as the login lasts); a wrong
  pair is answered 401 with the form again, repeated failures 429 with ``Retry-After``.
* ``GET /logout`` asks, ``POST /logout`` ends the login (its token fails from then on) and
  clears the cookie.
* Everything else needs a live login: without one an HTTP request is sent to ``/login`` and a
  WebSocket is refused (403) before it opens. With one, the request is passed to *that
  household's own* viser dashboard (:class:`web.dashboard.Dashboard` with ``household=id``,
  on 127.0.0.1 at a free port, started at the household's first login and kept until the gate
  stops): the page's files over HTTP, and viser's WebSocket message for message both ways.
  A browser thus only ever reaches a viser server that knows nothing of other households. An
  open WebSocket is closed when its login expires or logs out (checked every ``recheck_s``).

Why a proxy rather than a check inside viser: viser serves its page and its WebSocket itself
and has no hook to refuse a connection, and its GUI is shared by every browser connected to
one server; one server per household keeps each household's view and controls apart.

With ``login=False`` the gate only carries the all-households dashboard (the loopback default)
over uvicorn, which is how TLS covers the dashboard when ``serve`` has a certificate.
The rate limits and the audit log of the API (:class:`server.api.guard.Guard`) sit in front:
a failed login counts against the address, logins and logouts are audited.
"""

from __future__ import annotations

import asyncio
import contextlib
import html
import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any
from urllib.parse import parse_qs, urlsplit

import httpx
import websockets
import websockets.asyncio.client
from pydantic import ValidationError
from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import HTTPConnection, Request
from starlette.responses import HTMLResponse, RedirectResponse, Response
from starlette.routing import Route, WebSocketRoute
from starlette.websockets import WebSocket, WebSocketDisconnect
from websockets.typing import Subprotocol

from server import schemas
from server.api.guard import Guard
from server.config import is_loopback
from server.errors import TooMany, Unauthorized
from server.ratelimit import RateLimiter, RateLimits
from server.security import hash_token
from web.dashboard import Dashboard

if TYPE_CHECKING:
    import uvicorn

    from server.services.container import Services
    from server.tls import SslOptions

log = logging.getLogger(__name__)

MAX_FORM_BYTES = 4096
"""Largest login or logout form body read, bytes (the fields are at most ~330 characters)."""

SECURITY_HEADERS = {
    # the dashboard has buttons that drive robots: never inside another site's frame
    "X-Frame-Options": "DENY",
    "Content-Security-Policy": "frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "same-origin",
}

WRONG = "wrong household or password"


@dataclass(frozen=True)
class Visitor:
    """Who may see a dashboard: a household's login (its id and name, and the hash of the
    login token) or, without the login, anyone (all None: every household's dashboard)."""

    household: int | None
    name: str | None = None
    token_hash: str | None = None


class Gate:
    """The login gate of the dashboard port. ``start()`` serves it; ``stop()`` ends it and the
    dashboards it started. ``asgi`` is the app (with rate limits and audit), for tests.

    ``login``: ask for a household login (False: carry the all-households dashboard as is).
    ``secure``: served over TLS (the cookie is then ``Secure`` and ``__Host-`` prefixed).
    """

    def __init__(
        self,
        services: Services,
        *,
        login: bool = True,
        secure: bool = False,
        refresh_hz: float = 5.0,
        recheck_s: float = 10.0,
        limits: RateLimits | None = None,
    ) -> None:
        self.services = services
        self.login = login
        self.secure = secure
        self.refresh_hz = refresh_hz
        self.recheck_s = recheck_s
        self.cookie = "__Host-teachrepeat-login" if secure else "teachrepeat-login"
        self.port: int | None = None
        self._dashboards: dict[int | None, Dashboard] = {}
        self._lock = threading.Lock()
        self._closed = False
        self._server: uvicorn.Server | None = None
        self._thread: threading.Thread | None = None
        self.app = self._build_app()
        self.asgi = Guard(
            self.app,
            limiter=RateLimiter(limits or RateLimits()),
            record=services.repo.add_audit,
        )

    # --- lifecycle ------------------------------------------------------------------------

    def start(self, host: str, port: int, *, ssl: SslOptions | None = None) -> int:
        """Serve the gate with uvicorn on ``host:port`` (0 = any free port) in a thread, over
        TLS with ``ssl`` (:func:`server.tls.ssl_options`); the port used. Raises OSError when
        the port cannot be bound."""
        import uvicorn

        from server.serve import bind_port

        sock = bind_port(host, port)
        self.port = int(sock.getsockname()[1])
        config = uvicorn.Config(
            self.asgi, log_level="warning", access_log=False, lifespan="off", **(ssl or {})
        )
        server = uvicorn.Server(config)
        self._server = server
        # not the main thread: uvicorn leaves the signals to the API server's loop
        self._thread = threading.Thread(
            target=server.run, kwargs={"sockets": [sock]}, name="dashboard-gate", daemon=True
        )
        self._thread.start()
        deadline = time.monotonic() + 30
        while not server.started:
            if time.monotonic() > deadline or not self._thread.is_alive():
                raise RuntimeError("the dashboard gate did not start")
            time.sleep(0.01)
        return self.port

    def stop(self) -> None:
        """Stop serving, then every dashboard (idempotent)."""
        if self._server is not None:
            self._server.should_exit = True
        if self._thread is not None:
            self._thread.join(timeout=10)
            self._thread = None
        with self._lock:
            self._closed = True
            dashboards = list(self._dashboards.values())
            self._dashboards.clear()
        for d in dashboards:
            d.stop()

    def dashboard(self, household: int | None) -> Dashboard:
        """The dashboard of ``household`` (every household's with None), started on first use
        on 127.0.0.1 at a free port. Blocking: call it off the event loop."""
        with self._lock:
            if self._closed:
                raise RuntimeError("the dashboard gate is stopped")
            d = self._dashboards.get(household)
            if d is None:
                d = Dashboard(
                    self.services,
                    household=household,
                    logout="/logout" if self.login else None,
                    host="127.0.0.1",
                    port=0,
                    refresh_hz=self.refresh_hz,
                )
                d.start()
                self._dashboards[household] = d
            return d

    @property
    def households(self) -> list[int | None]:
        """The households whose dashboard runs now."""
        with self._lock:
            return list(self._dashboards)

    # --- who is asking --------------------------------------------------------------------

    async def visitor(self, conn: HTTPConnection) -> Visitor | None:
        """The login behind the request's cookie, or None (no cookie, unknown, expired,
        logged out, or not a household login)."""
        if not self.login:
            # no login: only for pages asked for by a loopback name, so a web page whose name
            # was made to point at 127.0.0.1 (DNS rebinding) does not reach the dashboard
            return Visitor(None) if loopback_host(conn) else None
        token = conn.cookies.get(self.cookie)
        if not token:
            return None
        return await self._check(hash_token(token))

    async def _check(self, token_hash: str) -> Visitor | None:
        identities = self.services.identities
        principal = identities.cached(token_hash)
        if principal is None:
            principal = await run_in_threadpool(identities.lookup, token_hash)
        if principal is None or principal.kind != "household" or principal.household is None:
            return None  # a robot's token is no dashboard login
        return Visitor(principal.household, principal.household_name, token_hash)

    # --- the app --------------------------------------------------------------------------

    def _build_app(self) -> Starlette:
        routes: list[Any] = []
        if self.login:
            routes += [
                Route("/login", self._login_page, methods=["GET"]),
                Route("/login", self._login, methods=["POST"]),
                Route("/logout", self._logout_page, methods=["GET"]),
                Route("/logout", self._logout, methods=["POST"]),
            ]
        routes += [
            Route("/{path:path}", self._proxy, methods=["GET"]),
            WebSocketRoute("/{path:path}", self._proxy_websocket),
        ]
        return Starlette(routes=routes)

    async def _login_page(self, request: Request) -> Response:
        return _page(_login_form())

    async def _login(self, request: Request) -> Response:
        if not same_origin(request):
            return _page(_login_form(error="refused: the form came from another site"), 403)
        fields = await read_form(request)
        if fields is None:
            return _page(_login_form(error="the form is too large"), 413)
        name = fields.get("household", "").strip()
        request.state.actor = f"login:{name[:64]}"
        try:
            body = schemas.LoginRequest(household=name, password=fields.get("password", ""))
            result = await run_in_threadpool(self.services.households.login, body)
        except (ValidationError, Unauthorized):  # a malformed name is just as wrong
            return _page(_login_form(household=name, error=WRONG), 401)
        except TooMany as exc:
            retry = str(max(1, math.ceil(exc.retry_after_s)))
            page = _page(_login_form(household=name, error=exc.message), 429)
            page.headers["Retry-After"] = retry
            return page
        response = RedirectResponse("/", status_code=303)
        response.set_cookie(
            self.cookie,
            result.token,
            max_age=max(1, int(result.expires_at - time.time())),
            path="/",
            secure=self.secure,
            httponly=True,
            samesite="strict",
        )
        return response

    async def _logout_page(self, request: Request) -> Response:
        if await self.visitor(request) is None:
            return RedirectResponse("/login", status_code=303)
        return _page(_LOGOUT_FORM)

    async def _logout(self, request: Request) -> Response:
        if not same_origin(request):
            return _page(_login_form(error="refused: the form came from another site"), 403)
        visitor = await self.visitor(request)
        token = request.cookies.get(self.cookie)
        if visitor is not None and token:
            request.state.actor = f"household:{visitor.name}"
            await run_in_threadpool(self.services.households.logout, token)
        response = RedirectResponse("/login", status_code=303)
        response.delete_cookie(
            self.cookie, path="/", secure=self.secure, httponly=True, samesite="strict"
        )
        return response

    async def _proxy(self, request: Request) -> Response:
        """A file of the dashboard's page, from the visitor's own viser server."""
        visitor = await self.visitor(request)
        if visitor is None and not self.login:
            return _page(_NOT_LOOPBACK, 403)
        if visitor is None:
            return RedirectResponse("/login", status_code=303)
        dashboard = await run_in_threadpool(self.dashboard, visitor.household)
        url = f"http://127.0.0.1:{dashboard.port}{_target(request)}"
        headers = {"Accept-Encoding": request.headers.get("accept-encoding", "identity")}
        async with (
            httpx.AsyncClient(timeout=30.0) as client,
            client.stream("GET", url, headers=headers) as upstream,
        ):
            body = b"".join([chunk async for chunk in upstream.aiter_raw()])
        passed = {
            k: upstream.headers[k]
            for k in ("content-type", "content-encoding")
            if k in upstream.headers
        }
        return Response(body, upstream.status_code, headers={**passed, **SECURITY_HEADERS})

    async def _proxy_websocket(self, websocket: WebSocket) -> None:
        """viser's WebSocket, passed both ways to the visitor's own viser server."""
        visitor = await self.visitor(websocket)
        if visitor is None or not same_origin(websocket):
            await websocket.close(code=1008)  # before accept: the handshake is answered 403
            return
        dashboard = await run_in_threadpool(self.dashboard, visitor.household)
        offered = [Subprotocol(p) for p in websocket.scope.get("subprotocols", ())]
        try:
            upstream = await websockets.asyncio.client.connect(
                f"ws://127.0.0.1:{dashboard.port}{_target(websocket)}",
                subprotocols=offered or None,
                max_size=None,  # viser's own limit (50 MB) applies upstream
                compression=None,
                open_timeout=10,
            )
        except (OSError, TimeoutError, websockets.exceptions.WebSocketException) as exc:
            log.warning("dashboard websocket upstream refused: %s", exc)
            await websocket.close(code=1011)
            return
        async with upstream:
            await websocket.accept(subprotocol=upstream.subprotocol)
            await self._pump(websocket, upstream, visitor)

    async def _pump(
        self,
        websocket: WebSocket,
        upstream: websockets.asyncio.client.ClientConnection,
        visitor: Visitor,
    ) -> None:
        """Pass messages both ways until either side closes or the login ends."""

        async def from_browser() -> None:
            while True:
                message = await websocket.receive()
                if message["type"] == "websocket.disconnect":
                    return
                data = message.get("bytes")
                await upstream.send(data if data is not None else message.get("text", ""))

        async def to_browser() -> None:
            async for data in upstream:
                if isinstance(data, bytes):
                    await websocket.send_bytes(data)
                else:
                    await websocket.send_text(data)

        async def login_lasts() -> None:
            if visitor.token_hash is None:
                await asyncio.Event().wait()  # no login to end: forever
                return
            while True:
                await asyncio.sleep(self.recheck_s)
                if await self._check(visitor.token_hash) is None:
                    return

        tasks = [asyncio.create_task(c()) for c in (from_browser, to_browser, login_lasts)]
        try:
            await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
        with contextlib.suppress(RuntimeError, WebSocketDisconnect, OSError):
            await websocket.close(code=1008 if tasks[2].done() else 1000)


# --- helpers ---------------------------------------------------------------------------------


_NOT_LOOPBACK = (
    "<p>This dashboard has no login, so it answers only to <code>localhost</code> or "
    "<code>127.0.0.1</code>. Open it by one of those names, or give a household a password "
    "and serve it with <code>--dashboard-login on</code>.</p>"
)


def loopback_host(conn: HTTPConnection) -> bool:
    """Whether the request's ``Host`` names a loopback address (``localhost``, 127.0.0.0/8,
    ``[::1]``), whatever its port."""
    host = conn.headers.get("host", "")
    name = host[1 : host.find("]")] if host.startswith("[") else host.rsplit(":", 1)[0]
    return is_loopback(name)


def same_origin(conn: HTTPConnection) -> bool:
    """False when a browser says the request comes from a page of another origin (its
    ``Origin`` header names another host:port than the one asked); True without the header
    (not a browser, or a same-origin GET)."""
    origin = conn.headers.get("origin")
    if origin is None:
        return True
    return urlsplit(origin).netloc.lower() == conn.headers.get("host", "").lower()


async def read_form(request: Request, limit: int = MAX_FORM_BYTES) -> dict[str, str] | None:
    """The fields of a URL-encoded form body (first value of each), or None when the body is
    larger than ``limit`` bytes. (No multipart parser needed for two text fields.)"""
    chunks: list[bytes] = []
    size = 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            return None
        chunks.append(chunk)
    text = b"".join(chunks).decode("utf-8", errors="replace")
    parsed = parse_qs(text, keep_blank_values=True, max_num_fields=16)
    return {k: v[0] for k, v in parsed.items()}


def _target(conn: HTTPConnection) -> str:
    """The path and query asked for, as sent (percent-encoding kept)."""
    raw = conn.scope.get("raw_path") or conn.scope["path"].encode()
    path = raw.decode("latin-1") or "/"
    query = conn.scope.get("query_string", b"").decode("latin-1")
    return f"{path}?{query}" if query else path


def _page(body: str, status: int = 200) -> HTMLResponse:
    headers = {**SECURITY_HEADERS, "Cache-Control": "no-store"}
    return HTMLResponse(_HTML.format(body=body), status_code=status, headers=headers)


def _login_form(*, household: str = "", error: str | None = None) -> str:
    alert = "" if error is None else f'<p class="error" role="alert">{html.escape(error)}</p>'
    return _LOGIN_FORM.format(alert=alert, household=html.escape(household, quote=True))


_HTML = """<!doctype html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>teachrepeat dashboard</title>
<style>
body {{ font-family: system-ui, sans-serif; background: #f3f4f6; margin: 0; }}
main {{ max-width: 22rem; margin: 12vh auto; background: #fff; padding: 2rem;
        border-radius: 8px; box-shadow: 0 1px 4px rgba(0, 0, 0, .12); }}
h1 {{ font-size: 1.3rem; margin-top: 0; }}
label {{ display: block; margin: .8rem 0 .3rem; }}
input {{ width: 100%; box-sizing: border-box; padding: .5rem; font-size: 1rem; }}
button {{ margin-top: 1.2rem; width: 100%; padding: .6rem; font-size: 1rem; color: #fff;
          background: #2563eb; border: 0; border-radius: 4px; cursor: pointer; }}
.error {{ color: #b91c1c; }}
</style></head>
<body><main>{body}</main></body></html>
"""

_LOGIN_FORM = """<h1>teachrepeat dashboard</h1>
<p>Log in with your household's name and password.</p>
{alert}
<form method="post" action="/login">
<label for="household">Household</label>
<input id="household" name="household" value="{household}" autocomplete="username"
       autocapitalize="none" required autofocus>
<label for="password">Password</label>
<input id="password" name="password" type="password" autocomplete="current-password" required>
<button type="submit">Log in</button>
</form>"""

_LOGOUT_FORM = """<h1>teachrepeat dashboard</h1>
<form method="post" action="/logout">
<p>End this login? The dashboard then asks for the password again.</p>
<button type="submit">Log out</button>
</form>
<p><a href="/">Back to the dashboard</a></p>"""
