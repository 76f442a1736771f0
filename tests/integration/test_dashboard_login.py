"""``teachrepeat serve`` and the dashboard login: refused off loopback while nobody can log in
(nothing is bound: no address printed), ``--dashboard-login off`` refused off loopback, and a
real serve with a certificate serving the gate over HTTPS."""

from __future__ import annotations

import ssl
from pathlib import Path

import httpx
import pytest
from conftest import serve_exits_2

from server import schemas
from server.cert import write_pair
from server.process import start_server


def serve_refused(db: Path, *args: str) -> str:
    """Run ``serve`` with ``args``; assert it exits 2 before binding anything; its stderr."""
    done = serve_exits_2(db, "--dashboard-port", "0", *args)
    assert "teachrepeat API" not in done.stdout and "dashboard " not in done.stdout
    return " ".join(done.stderr.split())


def test_serve_off_loopback_without_a_household_password_says_what_to_set(
    tmp_path: Path,
) -> None:
    err = serve_refused(tmp_path / "fresh.sqlite", "--host", "0.0.0.0")
    assert "the dashboard on 0.0.0.0 asks for a household login" in err
    assert "no household has a password yet" in err
    assert "`teachrepeat household password default`" in err
    assert "`teachrepeat household create NAME`" in err and "--dashboard-port -1" in err


def test_dashboard_login_off_is_refused_off_loopback(tmp_path: Path) -> None:
    err = serve_refused(tmp_path / "fresh.sqlite", "--host", "0.0.0.0", "--dashboard-login", "off")
    assert "dashboard_login is off, but host 0.0.0.0 is not a loopback address" in err
    assert not (tmp_path / "fresh.sqlite").exists()  # stopped before opening the database


def test_with_a_certificate_the_gate_is_served_over_https(tmp_path: Path) -> None:
    from server.services.households import HouseholdService, Identities
    from server.storage.repo import Repo

    pair = write_pair(tmp_path / "tls", [])
    db = tmp_path / "home.sqlite"
    repo = Repo(db)
    HouseholdService(repo, Identities(repo)).create(
        schemas.HouseholdCreate(name="home", password="home-password-1")
    )
    repo.close()
    server = start_server(
        db,
        dashboard=True,
        tls=(pair.cert, pair.key),
        extra_env={"TEACHREPEAT_DASHBOARD_LOGIN": "true"},  # on 127.0.0.1 too
    )
    try:
        url = server.dashboard_url
        assert url is not None and url.startswith("https://127.0.0.1:")
        verify = ssl.create_default_context(cafile=str(pair.cert))
        with httpx.Client(base_url=url, verify=verify) as client:
            r = client.get("/")
            assert r.status_code == 303 and r.headers["location"] == "/login"
            r = client.post("/login", data={"household": "home", "password": "home-password-1"})
            assert r.status_code == 303
            cookie = r.headers["set-cookie"]
            assert cookie.startswith("__Host-teachrepeat-login=") and "Secure" in cookie
            r = client.get("/")  # the cookie goes back over HTTPS
            assert r.status_code == 200 and "viser" in r.text.lower()
        with pytest.raises(httpx.TransportError):  # plain HTTP gets no page
            httpx.get(url.replace("https://", "http://"), timeout=5)
    finally:
        server.stop()
