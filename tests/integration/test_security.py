"""Hostile input and isolation: bad image bodies, one robot against another, secrets in logs,
and the interfaces the server listens on."""

from __future__ import annotations

import logging
import os
import re
import stat
import struct
import subprocess
import sys
import time
import tracemalloc
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from conftest import Api, make_jpeg
from pydantic import SecretStr

JPEG = {"Content-Type": "image/jpeg"}
PROJECT_ROOT = Path(__file__).resolve().parents[2]
SERVE = [sys.executable, "-m", "server.cli", "serve"]


# --- the routes, read from the OpenAPI schema --------------------------------------------------


def openapi() -> dict[str, Any]:
    """The app's OpenAPI document (an app on an in-memory database; nothing is started)."""
    from server.app import create_app
    from server.config import Settings

    settings = Settings(db=Path(":memory:"), admin_token=SecretStr("x"), dashboard_port=None)
    app = create_app(settings)
    try:
        return app.openapi()
    finally:
        app.state.services.close()


SCHEMA = openapi()
OPERATIONS = [
    (method.upper(), path, op)
    for path, item in SCHEMA["paths"].items()
    for method, op in item.items()
    if method in {"get", "post", "put", "patch", "delete"}
]
ROBOT_OPERATIONS = [o for o in OPERATIONS if o[1].startswith("/robots/{robot}/")]
PUBLIC = {("GET", "/health")}


def _resolve(schema: dict[str, Any]) -> dict[str, Any]:
    while "$ref" in schema:
        schema = SCHEMA["components"]["schemas"][schema["$ref"].rsplit("/", 1)[-1]]
    return schema


def example(schema: dict[str, Any]) -> Any:
    """A minimal valid value for a JSON schema: required fields only, simple values."""
    schema = _resolve(schema)
    if "anyOf" in schema:
        return example(next(s for s in schema["anyOf"] if s.get("type") != "null"))
    kind = schema.get("type")
    if kind == "object":
        props = schema.get("properties", {})
        return {k: example(props[k]) for k in schema.get("required", [])}
    if kind == "array":
        return []
    return {"integer": 1, "number": 0.5, "boolean": False}.get(str(kind), "place")


def request_for(method: str, path: str, op: dict[str, Any], robot: str) -> dict[str, Any]:
    """``httpx`` request arguments that are valid for ``op`` (except, maybe, its authority)."""
    url = path.replace("{robot}", robot)
    url = re.sub(r"\{[^}]+\}", "1", url)
    params = {
        p["name"]: example(p["schema"])
        for p in op.get("parameters", [])
        if p["in"] == "query" and p.get("required")
    }
    kwargs: dict[str, Any] = {"method": method, "url": url, "params": params, "headers": {}}
    content = op.get("requestBody", {}).get("content", {})
    if "image/jpeg" in content:
        kwargs["content"] = make_jpeg(1)
        kwargs["headers"] = dict(JPEG)
    elif "application/json" in content:
        kwargs["json"] = example(content["application/json"]["schema"])
    return kwargs


def op_id(o: tuple[str, str, dict[str, Any]]) -> str:
    return f"{o[0]} {o[1]}"


# --- one robot cannot read or drive another ---------------------------------------------------


@pytest.fixture()
def two_robots(api: Api) -> tuple[Api, dict[str, str], dict[str, str]]:
    """Robots ``alice`` and ``bob``; ``bob`` is navigating in a tour with one place."""
    alice = api.register("alice")
    bob = api.register("bob")
    tour = api.client.post("/tours", json={"name": "home"}, headers=bob).json()["id"]
    api.client.post("/robots/bob/teach/start", json={"tour": tour}, headers=bob)
    api.client.post("/robots/bob/teach/locations", json={"name": "place"}, headers=bob)
    api.client.post(
        "/robots/bob/teach/spin",
        params={"timestamp": 0},
        content=make_jpeg(2),
        headers={
            **bob,
            **JPEG,
        },
    )
    api.client.post("/robots/bob/teach/finish", headers=bob)
    r = api.client.post("/robots/bob/goto", json={"location": "place"}, headers=bob)
    assert r.status_code == 200, r.text
    return api, alice, bob


def test_every_robot_route_is_covered() -> None:
    assert len(ROBOT_OPERATIONS) >= 9
    assert all("{robot}" in path for _, path, _ in ROBOT_OPERATIONS)


@pytest.mark.parametrize("operation", ROBOT_OPERATIONS, ids=op_id)
def test_a_robot_token_cannot_use_another_robots_routes(
    two_robots: tuple[Api, dict[str, str], dict[str, str]],
    operation: tuple[str, str, dict[str, Any]],
) -> None:
    api, alice, bob = two_robots
    method, path, op = operation
    before = api.dump()
    state_before = api.client.get("/robots/bob/state", headers=bob).json()
    kwargs = request_for(method, path, op, "bob")
    kwargs["headers"].update(alice)
    r = api.client.request(**kwargs)
    assert r.status_code == 403, r.text
    body = r.json()
    assert body["code"] == "forbidden" and "alice" in body["detail"]
    assert "place" not in r.text and "navigat" not in r.text  # nothing about bob leaks
    assert api.dump() == before
    assert api.client.get("/robots/bob/state", headers=bob).json() == state_before
    # the same request for itself is not refused for lack of rights
    own = request_for(method, path, op, "alice")
    own["headers"].update(alice)
    assert api.client.request(**own).status_code not in (401, 403)


@pytest.mark.parametrize("operation", [o for o in OPERATIONS if o[:2] not in PUBLIC], ids=op_id)
def test_every_route_but_health_needs_a_valid_token(
    api: Api, operation: tuple[str, str, dict[str, Any]]
) -> None:
    api.register("alice")
    method, path, op = operation
    for headers in ({}, {"Authorization": "Bearer not-a-token"}, {"Authorization": "Basic eDp5"}):
        kwargs = request_for(method, path, op, "alice")
        kwargs["headers"].update(headers)
        r = api.client.request(**kwargs)
        assert r.status_code == 401, (headers, r.text)
        assert r.headers.get("www-authenticate") == "Bearer"
        assert "token" in r.json()["detail"]


@pytest.mark.parametrize(("method", "path"), [("POST", "/robots"), ("GET", "/robots")])
def test_admin_routes_refuse_a_robot_token(api: Api, method: str, path: str) -> None:
    robot = api.register("alice")
    before = api.dump()
    r = api.client.request(method, path, json={"name": "mallory"}, headers=robot)
    assert r.status_code == 403 and "admin" in r.json()["detail"]
    assert api.dump() == before


# --- hostile image bodies ---------------------------------------------------------------------


def _png(width: int, height: int) -> bytes:
    """A PNG of ``width x height`` black grey pixels: a few hundred kB that inflate to
    ``width * height`` bytes (a decompression bomb)."""
    z = zlib.compressobj(9)
    row = b"\x00" * (width + 1)
    idat = b"".join(z.compress(row) for _ in range(height)) + z.flush()

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
        )

    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")
    )


def _claims(width: int, height: int) -> bytes:
    """A small real JPEG whose frame header claims ``width x height``."""
    data = bytearray(make_jpeg(3, 64, 48))
    pos = 2
    while data[pos + 1] not in (0xC0, 0xC2):
        pos += 2 + int.from_bytes(data[pos + 2 : pos + 4], "big")
    data[pos + 5 : pos + 9] = struct.pack(">HH", height, width)
    return bytes(data)


@pytest.fixture(scope="module")
def png_bomb() -> bytes:
    return _png(20000, 20000)


HOSTILE: dict[str, Callable[[], bytes]] = {
    "zero-bytes": lambda: b"",
    "truncated-jpeg": lambda: make_jpeg(4, 320, 240)[:600],
    "jpeg-header-only": lambda: make_jpeg(4, 320, 240)[:2],
    "claims-20000x20000": lambda: _claims(20000, 20000),
    "claims-0x0": lambda: _claims(0, 0),
    "text": lambda: b"hello, I am not an image" * 10,
    "gif": lambda: b"GIF89a\x01\x00\x01\x00\x00\x00\x00;",
    "random-after-soi": lambda: b"\xff\xd8" + os.urandom(5000),
}


def teaching_robot(api: Api) -> dict[str, str]:
    robot = api.register("rover")
    tour = api.client.post("/tours", json={"name": "t"}, headers=robot).json()["id"]
    api.client.post("/robots/rover/teach/start", json={"tour": tour}, headers=robot)
    api.client.post("/robots/rover/teach/locations", json={"name": "a"}, headers=robot)
    return robot


def post_measured(
    api: Api, url: str, body: bytes, headers: dict[str, str]
) -> tuple[httpx.Response, float, int]:
    """The answer, the seconds it took and the peak bytes Python allocated meanwhile."""
    tracemalloc.start()
    tracemalloc.reset_peak()
    started = time.perf_counter()
    try:
        r = api.client.post(url, params={"timestamp": 1.0}, content=body, headers=headers)
    finally:
        elapsed = time.perf_counter() - started
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    return r, elapsed, peak


@pytest.mark.parametrize("url", ["/robots/rover/frames", "/robots/rover/teach/spin"])
@pytest.mark.parametrize("name", [*HOSTILE, "png-bomb"])
def test_hostile_images_are_refused_quickly_and_cheaply(
    api: Api, url: str, name: str, png_bomb: bytes
) -> None:
    robot = teaching_robot(api)
    body = png_bomb if name == "png-bomb" else HOSTILE[name]()
    before = api.dump()
    r, elapsed, peak = post_measured(api, url, body, {**robot, **JPEG})
    assert 400 <= r.status_code < 500, r.text
    assert r.status_code in (413, 415, 422), r.text
    assert r.json()["detail"]  # says what to do
    assert elapsed < 1.0, f"{elapsed:.2f} s"
    assert peak < 3 * len(body) + 8 * 2**20, f"peak {peak / 2**20:.1f} MiB"
    assert api.dump() == before


def test_a_png_with_its_own_content_type_is_refused_as_media_type(
    api: Api, png_bomb: bytes
) -> None:
    robot = teaching_robot(api)
    r, elapsed, peak = post_measured(
        api, "/robots/rover/frames", png_bomb, {**robot, "Content-Type": "image/png"}
    )
    assert r.status_code == 415 and "image/jpeg" in r.json()["detail"]
    assert elapsed < 1.0 and peak < 3 * len(png_bomb) + 8 * 2**20


def test_a_body_over_the_limit_is_refused_without_reading_it_all(api: Api) -> None:
    """Straight through ASGI (the test client would buffer the body itself): the server stops
    reading the stream as soon as it passes the limit."""
    import asyncio

    robot = teaching_robot(api)
    limit = api.client.app.state.services.limits.max_bytes
    chunk = b"\xff\xd8" + b"\x00" * (2**20 - 2)
    total = limit // len(chunk) + 64  # 64 MiB beyond the limit
    received = 0
    answer: dict[str, Any] = {}

    async def receive() -> dict[str, Any]:
        nonlocal received
        received += 1
        return {"type": "http.request", "body": chunk, "more_body": received < total}

    async def send(message: dict[str, Any]) -> None:
        if message["type"] == "http.response.start":
            answer["status"] = message["status"]
        elif message["type"] == "http.response.body":
            answer["body"] = answer.get("body", b"") + message.get("body", b"")

    headers = [
        (b"authorization", robot["Authorization"].encode()),
        (b"content-type", b"image/jpeg"),
    ]
    scope = {
        "type": "http",
        "asgi": {"version": "3.0"},
        "http_version": "1.1",
        "method": "POST",
        "scheme": "http",
        "path": "/robots/rover/frames",
        "raw_path": b"/robots/rover/frames",
        "query_string": b"timestamp=1.0",
        "headers": headers,
        "client": ("127.0.0.1", 1),
        "server": ("testserver", 80),
        "root_path": "",
    }
    before = api.dump()
    asyncio.run(api.client.app(scope, receive, send))
    assert answer["status"] == 413 and str(limit).encode() in answer["body"]
    assert received <= limit // len(chunk) + 2, f"read {received} MiB of {total}"
    assert api.dump() == before


@pytest.mark.parametrize("url", ["/robots/rover/frames", "/robots/rover/teach/spin"])
def test_a_1x1_image_is_refused(api: Api, url: str) -> None:
    robot = teaching_robot(api)
    before = api.dump()
    r, _, _ = post_measured(api, url, make_jpeg(5, 1, 1), {**robot, **JPEG})
    assert r.status_code == 422, r.text
    assert api.dump() == before


# --- secrets never reach the logs; the server listens on loopback only ----------------------


def test_tokens_never_reach_python_logging(api: Api, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG)
    robot = api.register("rover")
    token = robot["Authorization"].split()[1]
    api.client.get("/robots/rover/state", headers=robot)
    api.client.get("/robots/other/state", headers=robot)  # 403
    api.client.get("/robots", headers={"Authorization": "Bearer wrong-" + token})  # 401
    api.client.post("/robots", json={"name": token}, headers=api.admin)  # 422, name echoed?
    text = caplog.text + "".join(str(r.args) for r in caplog.records)
    for secret in (token, api.admin["Authorization"].split()[1]):
        assert secret not in text


def _listening(port: int) -> list[str]:
    """Local addresses (hex, as in /proc/net/tcp*) listening on ``port``."""
    found = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            address, hex_port = fields[1].split(":")
            if int(hex_port, 16) == port and fields[3] == "0A":  # 0A = LISTEN
                found.append(address)
    return found


@pytest.fixture()
def logged_server(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[bytes], Path, Path]]:
    """``teachrepeat serve`` with no admin token configured (it generates one) and the
    dashboard on, its stdout and stderr captured in a file."""
    log = tmp_path / "server.log"
    env = {k: v for k, v in os.environ.items() if not k.startswith("TEACHREPEAT_")}
    db = tmp_path / "data" / "t.sqlite"
    with log.open("wb") as out:
        proc = subprocess.Popen(
            [*SERVE, "--db", str(db), "--port", "0", "--dashboard-port", "0"],
            stdout=out,
            stderr=subprocess.STDOUT,
            env=env,
            cwd=PROJECT_ROOT,
        )
    try:
        yield proc, log, db
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


def _wait_for(log: Path, pattern: str, timeout: float = 60.0) -> re.Match[str]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = re.search(pattern, log.read_text(errors="replace"))
        if found:
            return found
        time.sleep(0.1)
    raise AssertionError(f"{pattern!r} never appeared:\n{log.read_text(errors='replace')}")


@pytest.mark.slow
def test_real_server_logs_no_tokens_and_listens_on_loopback_only(
    logged_server: tuple[subprocess.Popen[bytes], Path, Path],
) -> None:
    proc, log, db = logged_server
    url = _wait_for(log, r"teachrepeat API\s+(http://\S+)").group(1)
    dashboard = _wait_for(log, r"dashboard\s+(http://\S+)").group(1)
    token_file = db.parent / "admin_token"
    assert stat.S_IMODE(token_file.stat().st_mode) == 0o600
    admin = token_file.read_text().strip()
    for address in (url, dashboard):
        host, port = address.removeprefix("http://").rsplit(":", 1)
        assert host == "127.0.0.1"
        listening = _listening(int(port))
        assert listening and all(a == "0100007F" for a in listening), listening

    deadline = time.monotonic() + 30
    while True:
        try:
            httpx.get(f"{url}/health", timeout=1)
            break
        except httpx.TransportError:
            assert time.monotonic() < deadline
            time.sleep(0.1)
    with httpx.Client(base_url=url, timeout=30) as http:
        a = {"Authorization": f"Bearer {admin}"}
        token = http.post("/robots", json={"name": "rover"}, headers=a).json()["token"]
        r = {"Authorization": f"Bearer {token}"}
        tour = http.post("/tours", json={"name": "t"}, headers=r).json()["id"]
        http.post("/robots/rover/teach/start", json={"tour": tour}, headers=r)
        http.post("/robots/rover/teach/locations", json={"name": "a"}, headers=r)
        for k in range(3):
            http.post(
                "/robots/rover/frames",
                params={"timestamp": k},
                content=make_jpeg(k),
                headers={**r, **JPEG},
            )
        http.post("/robots/rover/frames", params={"timestamp": 9}, content=b"x", headers=r)
        http.get("/robots/nobody/state", headers=r)  # 403
        http.get("/robots", headers={"Authorization": f"Bearer {token}x"})  # 401
        http.get("/robots", headers={"Authorization": f"Bearer {admin}x"})  # 401
        http.get(f"{url}/health")
    proc.terminate()
    proc.wait(timeout=10)
    output = log.read_text(errors="replace")
    assert "teachrepeat API" in output  # the capture worked
    for secret in (admin, token):
        assert secret not in output
        assert secret[:12] not in output
    assert "authorization" not in output.lower()
    assert "POST /robots" not in output and "GET /health" not in output  # no access log


# --- remembered tokens ------------------------------------------------------------------------


def test_a_found_token_is_remembered_for_a_minute_and_an_unknown_one_is_not(
    tmp_path: Path,
) -> None:
    from server.security import hash_token
    from server.services.tours import TOKEN_CACHE_S, RobotService
    from server.storage.repo import Repo

    now = [1000.0]
    repo = Repo(tmp_path / "tokens.sqlite")
    robots = RobotService(repo, clock=lambda: now[0])
    try:
        from server import schemas

        token = robots.register(schemas.RobotCreate(name="rover")).token
        found = hash_token(token)
        unknown = hash_token("not-a-token")
        assert robots.cached_robot(found) is None  # nothing remembered before a lookup
        assert robots.robot_for_token(found) == "rover"
        assert robots.cached_robot(found) == "rover"
        assert robots.robot_for_token(unknown) is None
        assert robots.cached_robot(unknown) is None
        # a robot row removed by hand stops authenticating once the memory expires
        with repo.transaction():
            repo.db.conn.execute("DELETE FROM robots WHERE name = 'rover'")
        now[0] += TOKEN_CACHE_S - 1
        assert robots.cached_robot(found) == "rover"
        now[0] += 2
        assert robots.cached_robot(found) is None
        assert robots.robot_for_token(found) is None
    finally:
        repo.close()


def test_a_token_that_authenticated_once_cannot_drive_another_robot(api: Api) -> None:
    rover = api.register("rover")
    api.register("other")
    assert api.client.get("/robots/rover/state", headers=rover).status_code == 200  # remembered
    r = api.client.get("/robots/other/state", headers=rover)
    assert r.status_code == 403 and "belongs to robot 'rover'" in r.json()["detail"]
    r = api.client.post("/robots/other/goto", json={"location": "kitchen"}, headers=rover)
    assert r.status_code == 403
