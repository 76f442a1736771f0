"""The ASGI layer in front of every route: rate limits (429 with ``Retry-After``) and the
audit log of state-changing calls. Pure ASGI (no request objects) to keep a frame's cost low.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any

from starlette.concurrency import run_in_threadpool

from server.errors import DomainError
from server.ratelimit import RateLimiter

log = logging.getLogger(__name__)

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

AUDITED_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})
NOT_AUDITED_SUFFIXES = ("/frames", "/teach/spin", "/teleop")
"""Camera frames and spin images: the data stream itself, 10 per second per robot, not a
decision anyone makes; the calls around them (teach start, marks, goto, stop) are audited.
Teleop commands are repeated ~10 times a second while a key is held: the start of each drive
is audited by the service (``teleop start``), not every repeat."""


def bearer_token(scope: Scope) -> str | None:
    for name, value in scope.get("headers", ()):
        if name == b"authorization":
            scheme, _, token = value.decode("latin-1").partition(" ")
            return token.strip() if scheme.lower() == "bearer" and token.strip() else None
    return None


class Guard:
    """Rate limits first (a refused request costs no authentication and no database), then
    the app; afterwards a 401 counts against the address, and a state-changing call is
    written to the audit log with who made it (``scope['state']['principal']``, set by the
    authentication dependency), what, when and the status answered."""

    def __init__(
        self,
        app: ASGIApp,
        limiter: RateLimiter,
        record: Callable[..., None],
        *,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.app = app
        self.limiter = limiter
        self.record = record
        self.clock = clock

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        client = scope.get("client")
        address = client[0] if client else "unknown"
        wait, why = self.limiter.admit(address, bearer_token(scope), self.clock())
        if wait > 0:
            await _too_many(send, wait, why)
            return
        status = 0

        async def send_status(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = int(message["status"])
            await send(message)

        await self.app(scope, receive, send_status)
        if status == 401:
            self.limiter.failed(address, self.clock())
        method = scope["method"]
        path: str = scope["path"]
        if method in AUDITED_METHODS and not path.endswith(NOT_AUDITED_SUFFIXES):
            state = scope.get("state", {})
            principal = state.get("principal")
            actor = principal.actor if principal is not None else state.get("actor", "anonymous")
            route = getattr(scope.get("route"), "path", path)
            try:
                await run_in_threadpool(
                    self.record,
                    actor=actor,
                    action=f"{method} {route}",
                    target=path,
                    status=status,
                    address=address,
                )
            except DomainError as exc:  # a read-only or full disk: the answer stands
                log.warning("audit entry for %s %s not written: %s", method, route, exc.message)


async def _too_many(send: Send, wait_s: float, why: str) -> None:
    retry = max(1, math.ceil(wait_s))
    body = json.dumps(
        {"detail": f"{why}; retry after {retry} s", "code": "too_many_requests"}
    ).encode()
    await send(
        {
            "type": "http.response.start",
            "status": 429,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
                (b"retry-after", str(retry).encode()),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})
