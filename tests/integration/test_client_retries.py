"""The robot client sends a request again when a load balancer answers 502 / 504 for a server
process that died with it (``serve --workers``), and never for the server's own errors."""

from __future__ import annotations

import http.server
import threading
from collections.abc import Iterator
from typing import ClassVar

import pytest

from robot_client.client import ApiError, TeachRepeatClient


class Flaky(http.server.BaseHTTPRequestHandler):
    """Answers ``statuses`` in turn (then 200 with ``{"status": "ok"}``), counting requests."""

    statuses: ClassVar[list[int]] = []
    seen: ClassVar[int] = 0

    def do_GET(self) -> None:
        cls = type(self)
        cls.seen += 1
        status = cls.statuses.pop(0) if cls.statuses else 200
        body = b'{"status": "ok"}' if status == 200 else b'{"detail": "no", "code": "x"}'
        self.send_response(status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args: object) -> None:
        pass


@pytest.fixture
def flaky() -> Iterator[tuple[str, type[Flaky]]]:
    handler = type("Handler", (Flaky,), {"statuses": [], "seen": 0})
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}", handler
    finally:
        server.shutdown()
        server.server_close()


def test_a_gateway_error_is_sent_again(flaky: tuple[str, type[Flaky]]) -> None:
    url, handler = flaky
    handler.statuses = [502, 504]
    with TeachRepeatClient(url, "t", retries=2, backoff_s=0.01) as client:
        assert client.health() == {"status": "ok"}
    assert handler.seen == 3


def test_without_retries_or_past_them_the_gateway_error_is_raised(
    flaky: tuple[str, type[Flaky]],
) -> None:
    url, handler = flaky
    handler.statuses = [502, 502, 502]
    with (
        TeachRepeatClient(url, "t", retries=1, backoff_s=0.01) as client,
        pytest.raises(ApiError) as err,
    ):
        client.health()
    assert err.value.status == 502 and handler.seen == 2


def test_the_servers_own_errors_are_not_sent_again(flaky: tuple[str, type[Flaky]]) -> None:
    url, handler = flaky
    handler.statuses = [503]
    with (
        TeachRepeatClient(url, "t", retries=3, backoff_s=0.01) as client,
        pytest.raises(ApiError) as err,
    ):
        client.health()
    assert err.value.status == 503 and handler.seen == 1
