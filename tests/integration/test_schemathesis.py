"""Property-based fuzzing of every operation in the OpenAPI schema: no input is a server error.

Schemathesis generates valid (positive) and invalid (negative) requests for each operation from
``/openapi.json`` and sends them to the in-process ASGI app, as the admin and as a robot that is
navigating a small taught tour. Every answer must be below 500 and must not raise.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from conftest import make_jpeg
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis.errors import Unsatisfiable
from pydantic import SecretStr

ADMIN_TOKEN = "schemathesis-admin-token"
KNOWN: dict[str, str] = {}
"""Server errors found by this fuzzer and not fixed yet (message fragment -> why). The two it
found (ids above 2**63 - 1, a 1x1 frame while navigating) are fixed and have tests below."""
EXAMPLES = 20
"""Generated cases per operation, generation mode and caller; a few operations run out of
distinct inputs sooner, the total stays above 1000."""


@pytest.fixture()
def fuzzed(tmp_path: Path) -> Iterator[tuple[Any, dict[str, str]]]:
    """The loaded schema and a robot's auth header; robot ``rover`` navigates tour ``home``.

    Function-scoped: schemathesis' pytest plugin ends every ASGI lifespan after each test."""
    schemathesis = pytest.importorskip("schemathesis")
    from schemathesis.python import asgi

    from server.app import create_app
    from server.config import Settings

    db = tmp_path / "fuzz.sqlite"
    settings = Settings(db=db, admin_token=SecretStr(ADMIN_TOKEN), dashboard_port=None)
    app = create_app(settings)
    admin = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
    with asgi.get_client(app) as http:  # type: ignore[arg-type]  # starts the app's lifespan
        token = http.post("/robots", json={"name": "rover"}, headers=admin).json()["token"]
        robot = {"Authorization": f"Bearer {token}"}
        jpeg = {**robot, "Content-Type": "image/jpeg"}
        tour = http.post("/tours", json={"name": "home"}, headers=robot).json()["id"]
        http.post("/robots/rover/teach/start", json={"tour": tour}, headers=robot)
        for k, place in enumerate(("hall", "kitchen")):
            http.post("/robots/rover/teach/locations", json={"name": place}, headers=robot)
            http.post(
                "/robots/rover/teach/spin",
                params={"timestamp": 10 * k},
                data=make_jpeg(k, 160, 120),
                headers=jpeg,
            )
            for j in range(3 if k == 0 else 0):
                http.post(
                    "/robots/rover/frames",
                    params={"timestamp": 10 * k + j + 1, "v": 0.3},
                    data=make_jpeg(10 + j, 160, 120),
                    headers=jpeg,
                )
        assert http.post("/robots/rover/teach/finish", headers=robot).status_code == 200
        r = http.post("/robots/rover/goto", json={"location": "kitchen"}, headers=robot)
        assert r.status_code == 200, r.text
        schema = schemathesis.openapi.from_asgi("/openapi.json", app)
        yield schema, robot
    asgi.shutdown_lifespans()


def run_cases(strategy: Any, headers: dict[str, str], label: str, failures: list[str]) -> int:
    """Send ``EXAMPLES`` cases drawn from ``strategy``; server errors go to ``failures``."""
    sent = 0

    @settings(
        max_examples=EXAMPLES,
        deadline=None,
        database=None,
        derandomize=True,
        phases=[Phase.generate],
        suppress_health_check=list(HealthCheck),
    )
    @given(case=strategy)
    def check(case: Any) -> None:
        nonlocal sent
        sent += 1
        try:
            response = case.call(headers=headers)
        except Exception as exc:  # an unhandled error in the app
            failures.append(f"{case.operation.label} [{label}] raised {exc!r}")
            return
        if response.status_code >= 500:
            failures.append(
                f"{case.operation.label} [{label}] -> {response.status_code}: {response.text[:200]}"
            )

    with contextlib.suppress(Unsatisfiable):  # nothing to make invalid (GET /health, negative)
        check()
    return sent


def test_no_generated_request_is_a_server_error(fuzzed: tuple[Any, dict[str, str]]) -> None:
    from schemathesis import GenerationMode

    schema, robot = fuzzed
    admin = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
    callers = {"admin": (admin, None), "robot": (robot, "rover")}
    sent = 0
    failures: list[str] = []
    operations = [result.ok() for result in schema.get_all_operations()]
    assert len(operations) >= 15
    for operation in operations:
        for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE):
            for who, (headers, name) in callers.items():
                fixed = {"robot": name} if name and "{robot}" in operation.path else None
                strategy = operation.as_strategy(generation_mode=mode, path_parameters=fixed)
                sent += run_cases(strategy, headers, f"{who}, {mode.value}", failures)
    unknown = [f for f in failures if not any(k in f for k in KNOWN)]
    assert not unknown, "\n".join(unknown[:20])
    assert sent >= 1000, sent


def test_huge_ids_are_refused_with_4xx(fuzzed: tuple[Any, dict[str, str]]) -> None:
    schema, robot = fuzzed
    from schemathesis.python import asgi

    with asgi.get_client(schema.app) as http:
        for method, url, body in (
            ("GET", "/tours/1180591620717411303424", None),
            ("GET", "/images/1180591620717411303424", None),
            ("POST", "/robots/rover/goto", {"location": "kitchen", "tour": 2**70}),
        ):
            r = http.request(method, url, json=body, headers=robot)
            assert 400 <= r.status_code < 500, (url, r.status_code, r.text)


def test_a_tiny_frame_while_navigating_is_refused_with_4xx(
    fuzzed: tuple[Any, dict[str, str]],
) -> None:
    schema, robot = fuzzed
    from schemathesis.python import asgi

    with asgi.get_client(schema.app) as http:
        r = http.post(
            "/robots/rover/frames",
            params={"timestamp": 1e6},
            data=make_jpeg(0, 1, 1),
            headers={**robot, "Content-Type": "image/jpeg"},
        )
    assert r.status_code == 422, r.text


def test_the_schema_documents_every_route(fuzzed: tuple[Any, dict[str, str]]) -> None:
    """Every route the app serves is in the schema, so the fuzzer reaches it."""
    schema, _ = fuzzed
    documented = {
        (op.method.upper(), op.path) for op in (r.ok() for r in schema.get_all_operations())
    }
    from server.app import create_app
    from server.config import Settings

    settings = Settings(db=Path(":memory:"), admin_token=SecretStr("x"), dashboard_port=None)
    app = create_app(settings)
    try:
        served = {
            (method, getattr(route, "path", ""))
            for route in app.routes
            for method in getattr(route, "methods", set()) or set()
            if getattr(route, "include_in_schema", False) and method != "HEAD"
        }
    finally:
        app.state.services.close()
    assert served <= documented, served - documented
