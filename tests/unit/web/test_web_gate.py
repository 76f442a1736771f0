"""The dashboard's login gate (web/gate.py) driven in-process with Starlette's TestClient, and
the household-scoped dashboard behind it, against real services on a temporary SQLite file."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from pydantic import SecretStr
from starlette.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from server import schemas
from server.services.container import Services
from web.gate import Gate

PASSWORD = "correct horse battery"
VISER = ["viser-v" + __import__("viser").__version__]


@pytest.fixture()
def services(tmp_path: Path) -> Iterator[Services]:
    from server.app import create_app
    from server.config import Settings

    settings = Settings(
        db=tmp_path / "gate.sqlite", admin_token=SecretStr("gate-admin"), dashboard_port=None
    )
    services: Services = create_app(settings).state.services
    for name in ("alpha", "beta"):
        household = services.households.create(
            schemas.HouseholdCreate(name=name, password=PASSWORD + name)
        )
        services.robots.register(schemas.RobotCreate(name=f"{name}-rover"), household.id)
        services.tours.create(schemas.TourCreate(name=f"{name}-home"), household.id)
    yield services
    services.close()


@pytest.fixture()
def gate(services: Services) -> Iterator[Gate]:
    g = Gate(services, recheck_s=0.2)
    yield g
    g.stop()


@pytest.fixture()
def client(gate: Gate) -> Iterator[TestClient]:
    with TestClient(gate.asgi, follow_redirects=False) as c:
        yield c


def log_in(client: TestClient, household: str = "alpha", password: str | None = None) -> str:
    r = client.post(
        "/login", data={"household": household, "password": password or PASSWORD + household}
    )
    assert r.status_code == 303 and r.headers["location"] == "/", r.text
    return r.headers["set-cookie"]


def test_without_a_login_every_page_goes_to_the_login_form(client: TestClient) -> None:
    for path in ("/", "/index.html", "/anything?x=1"):
        r = client.get(path)
        assert r.status_code == 303 and r.headers["location"] == "/login", path
    r = client.get("/login")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    assert '<form method="post" action="/login">' in r.text
    assert 'name="household"' in r.text and 'type="password"' in r.text
    assert "<script" not in r.text and "http" not in r.text.split("<body>")[1]  # no assets
    assert r.headers["x-frame-options"] == "DENY" and r.headers["cache-control"] == "no-store"


def test_a_wrong_password_is_refused_with_the_form_again(client: TestClient) -> None:
    r = client.post("/login", data={"household": "alpha", "password": "not the password"})
    assert r.status_code == 401
    assert "wrong household or password" in r.text and 'value="alpha"' in r.text
    assert "set-cookie" not in r.headers
    for name in ("nobody", "Not A Name <b>"):  # unknown and malformed: the same answer
        r = client.post("/login", data={"household": name, "password": PASSWORD})
        assert r.status_code == 401 and "wrong household or password" in r.text
        assert "<b>" not in r.text  # what was typed is escaped
    assert client.get("/").status_code == 303


def test_repeated_failures_wait_with_retry_after(client: TestClient) -> None:
    codes = [
        client.post("/login", data={"household": "beta", "password": "wrong-" * 3}).status_code
        for _ in range(4)
    ]
    assert codes[:3] == [401, 401, 401] and codes[3] == 429
    r = client.post("/login", data={"household": "beta", "password": PASSWORD + "beta"})
    assert r.status_code == 429 and int(r.headers["retry-after"]) >= 1
    assert "too many failed logins for &#x27;beta&#x27;" in r.text


def test_the_cookie_holds_the_login_with_strict_flags(
    client: TestClient, services: Services
) -> None:
    cookie = log_in(client)
    name, _, rest = cookie.partition("=")
    token = rest.split(";")[0]
    flags = [f.strip().lower() for f in cookie.split(";")[1:]]
    assert name == "teachrepeat-login" and len(token) >= 40
    assert "httponly" in flags and "samesite=strict" in flags and "path=/" in flags
    assert "secure" not in flags  # plain HTTP here
    max_age = int(next(f for f in flags if f.startswith("max-age=")).split("=")[1])
    assert 12 * 3600 - 60 <= max_age <= 12 * 3600  # as long as the login (login_hours)
    from server.security import hash_token

    principal = services.identities.lookup(hash_token(token))
    assert principal is not None and principal.household_name == "alpha"


def test_under_tls_the_cookie_is_secure_and_host_prefixed(services: Services) -> None:
    gate = Gate(services, secure=True)
    with TestClient(gate.asgi, base_url="https://dash.test", follow_redirects=False) as client:
        cookie = log_in(client)
    assert cookie.startswith("__Host-teachrepeat-login=")
    assert "secure" in [f.strip().lower() for f in cookie.split(";")]


def test_a_login_shows_only_its_households_dashboard(client: TestClient, gate: Gate) -> None:
    log_in(client, "alpha")
    r = client.get("/")
    assert r.status_code == 200 and "viser" in r.text.lower()  # the client page, proxied
    assert r.headers["x-frame-options"] == "DENY"
    assert gate.households == [gate.services.repo.household_by_name("alpha").id]  # type: ignore[union-attr]
    dashboard = gate.dashboard(gate.households[0])
    snap = dashboard.refresh()
    assert snap is not None
    assert snap.robots == ("alpha-rover",) and [t[1] for t in snap.tours] == ["alpha-home"]
    assert dashboard.controls is not None
    assert dashboard.controls.robot.options == ("alpha-rover",)


def test_the_websocket_needs_the_login_and_is_passed_through(client: TestClient) -> None:
    with pytest.raises(WebSocketDisconnect) as refused, client.websocket_connect("/", VISER):
        pass
    assert refused.value.code == 1008
    log_in(client)
    with client.websocket_connect("/", VISER) as ws:
        assert ws.accepted_subprotocol == VISER[0]
        first = ws.receive_bytes()  # viser's first messages (msgpack) came from the upstream
        assert len(first) > 10
    # a page of another site may not open it, even with the cookie
    with (
        pytest.raises(WebSocketDisconnect),
        client.websocket_connect("/", VISER, headers={"Origin": "http://evil.test"}),
    ):
        pass


def test_logout_ends_the_login_and_its_open_websocket(client: TestClient) -> None:
    cookie = log_in(client)
    token = cookie.split(";")[0].split("=", 1)[1]
    assert client.get("/").status_code == 200
    with client.websocket_connect("/", VISER) as ws:
        ws.receive_bytes()
        page = client.get("/logout")
        assert page.status_code == 200 and 'action="/logout"' in page.text  # asks first
        r = client.post("/logout")
        assert r.status_code == 303 and r.headers["location"] == "/login"
        assert 'teachrepeat-login=""' in r.headers["set-cookie"]
        deadline = time.monotonic() + 5  # the open socket closes at the next check (0.2 s)
        with pytest.raises(WebSocketDisconnect):
            while time.monotonic() < deadline:
                ws.receive_bytes()
    assert client.get("/").status_code == 303
    client.cookies.set("teachrepeat-login", token)  # the old token no longer opens it
    assert client.get("/").headers["location"] == "/login"


def test_an_expired_login_goes_back_to_the_form(
    client: TestClient, services: Services, monkeypatch: pytest.MonkeyPatch
) -> None:
    log_in(client)
    assert client.get("/").status_code == 200
    later = time.time() + 13 * 3600  # past login_hours (12)
    monkeypatch.setattr(services.identities, "wall", lambda: later)
    r = client.get("/")
    assert r.status_code == 303 and r.headers["location"] == "/login"


def test_a_robot_token_is_no_dashboard_login(client: TestClient, services: Services) -> None:
    robot = services.robots.register(schemas.RobotCreate(name="sneaky"), 1)
    client.cookies.set("teachrepeat-login", robot.token)
    assert client.get("/").status_code == 303


def test_a_form_from_another_site_is_refused(client: TestClient) -> None:
    r = client.post(
        "/login",
        data={"household": "alpha", "password": PASSWORD + "alpha"},
        headers={"Origin": "http://evil.test"},
    )
    assert r.status_code == 403 and "set-cookie" not in r.headers


def test_logins_and_logouts_are_audited(client: TestClient, services: Services) -> None:
    client.post("/login", data={"household": "alpha", "password": "not the password"})
    log_in(client)
    client.post("/logout")
    rows = [(a.actor, a.action, a.status) for a in services.repo.audit(limit=3)][::-1]
    assert rows == [
        ("login:alpha", "POST /login", 401),
        ("login:alpha", "POST /login", 303),
        ("household:alpha", "POST /logout", 303),
    ]


def test_without_the_login_it_carries_every_households_dashboard(services: Services) -> None:
    gate = Gate(services, login=False)
    try:
        with TestClient(
            gate.asgi, base_url="http://127.0.0.1:8080", follow_redirects=False
        ) as client:
            assert client.get("/").status_code == 200
            assert client.get("/login").status_code == 404  # viser's answer: no such page
            assert client.get("/", headers={"Host": "localhost:8080"}).status_code == 200
            assert client.get("/", headers={"Host": "[::1]:8080"}).status_code == 200
            # a name that points at 127.0.0.1 from a web page (DNS rebinding) gets nothing
            r = client.get("/", headers={"Host": "evil.example:8080"})
            assert r.status_code == 403 and "localhost" in r.text
        with (
            TestClient(gate.asgi, base_url="http://127.0.0.1:8080") as client,
            pytest.raises(WebSocketDisconnect),
            client.websocket_connect("/", headers={"Origin": "http://evil.example"}),
        ):
            pass  # another site's page cannot open the dashboard's socket
        assert gate.households == [None]
    finally:
        gate.stop()
