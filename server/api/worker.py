"""The ``X-Teachrepeat-Worker`` response header: which of several server processes answered.

Behind a load balancer (``teachrepeat serve --workers N``, docs/scale.md) each process has a
name (``w0``, ``w1``, ...); every response says it, so that a test, a benchmark or a person
reading a robot's log can tell that a robot's requests all reach one process. The name is not
a secret and says nothing about the request.
"""

from __future__ import annotations

from starlette.types import ASGIApp, Message, Receive, Scope, Send

WORKER_HEADER = "X-Teachrepeat-Worker"


class WorkerHeader:
    """ASGI middleware adding ``X-Teachrepeat-Worker: <name>`` to every HTTP response."""

    def __init__(self, app: ASGIApp, *, name: str) -> None:
        self.app = app
        self.header = (WORKER_HEADER.lower().encode(), name.encode())

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def send_named(message: Message) -> None:
            if message["type"] == "http.response.start":
                message["headers"] = [*message.get("headers", []), self.header]
            await send(message)

        await self.app(scope, receive, send_named)
