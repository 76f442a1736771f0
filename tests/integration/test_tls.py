"""A real ``teachrepeat serve --tls-cert --tls-key`` and the robot client that pins it: the right
certificate is talked to, another one is refused before the token leaves, plain HTTP gets
nothing, and a wrong pair of files stops ``serve`` with a message."""

from __future__ import annotations

import socket
import ssl
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import pytest
from conftest import make_jpeg, serve_exits_2

from robot_client.client import TeachRepeatClient, UntrustedServerError
from server.cert import CertPair, write_pair
from server.cli import main
from server.process import ADMIN, ServerProcess, start_server


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory) -> CertPair:
    return write_pair(tmp_path_factory.mktemp("home"), ["teachrepeat-hub.local"])


@pytest.fixture(scope="module")
def other(tmp_path_factory: pytest.TempPathFactory) -> CertPair:
    """Another home's pair: same names, another key."""
    return write_pair(tmp_path_factory.mktemp("elsewhere"), ["teachrepeat-hub.local"])


@pytest.fixture(scope="module")
def server(pair: CertPair, tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    proc = start_server(tmp_path_factory.mktemp("db") / "tls.sqlite", tls=(pair.cert, pair.key))
    yield proc
    proc.stop()


def test_serve_prints_an_https_address(server: ServerProcess) -> None:
    assert server.url.startswith("https://127.0.0.1:")


def test_the_client_pinned_to_the_servers_certificate_talks_to_it(
    server: ServerProcess, pair: CertPair
) -> None:
    with TeachRepeatClient(server.url, ADMIN, ca_cert=pair.cert) as client:
        assert client.health()["status"] == "ok"
        assert client.whoami().kind == "admin"
    # the certificate names localhost too: the host name is checked, and holds
    with TeachRepeatClient(
        server.url.replace("127.0.0.1", "localhost"), ADMIN, ca_cert=pair.cert
    ) as client:
        assert client.whoami().kind == "admin"


@pytest.mark.parametrize("form", ["as printed", "bare lower-case hex"])
def test_the_client_pinned_to_the_fingerprint_talks_to_it(
    server: ServerProcess, pair: CertPair, form: str
) -> None:
    pin = pair.fingerprint if form == "as printed" else pair.fingerprint.replace(":", "").lower()
    with TeachRepeatClient(server.url, ADMIN, fingerprint=pin) as client:
        assert client.health()["status"] == "ok"
        assert client.whoami().kind == "admin"
    with TeachRepeatClient(server.url, ADMIN, ca_cert=pair.cert, fingerprint=pin) as client:
        assert client.whoami().kind == "admin"


@pytest.mark.parametrize("pin", ["ca_cert", "fingerprint", "both"])
def test_the_client_pinned_to_another_certificate_is_refused(
    server: ServerProcess, pair: CertPair, other: CertPair, pin: str
) -> None:
    kwargs = {
        "ca_cert": {"ca_cert": other.cert},
        "fingerprint": {"fingerprint": other.fingerprint},
        "both": {"ca_cert": pair.cert, "fingerprint": other.fingerprint},
    }[pin]
    with (
        TeachRepeatClient(server.url, ADMIN, retries=5, **kwargs) as client,
        pytest.raises(UntrustedServerError, match="not the pinned one") as exc,
    ):
        client.whoami()
    assert "Nothing was sent" in str(exc.value)
    if pin != "ca_cert":
        assert pair.fingerprint in str(exc.value)  # what the server presented


def test_an_unpinned_client_says_how_to_pin(server: ServerProcess) -> None:
    with (
        TeachRepeatClient(server.url, ADMIN) as client,
        pytest.raises(UntrustedServerError, match=r"--ca-cert.*--fingerprint"),
    ):
        client.health()


def test_plain_http_to_the_tls_port_gets_no_answer(server: ServerProcess) -> None:
    plain = server.url.replace("https://", "http://")
    with pytest.raises(httpx.TransportError):
        httpx.get(f"{plain}/health", headers={"Authorization": f"Bearer {ADMIN}"}, timeout=5)


def test_robot_teach_takes_the_pins(
    server: ServerProcess,
    pair: CertPair,
    other: CertPair,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(4):
        (frames / f"{k:03d}.jpg").write_bytes(make_jpeg(k, 160, 120))
    marks = tmp_path / "marks.csv"
    marks.write_text("0,door\n3,desk\n")
    token = server.register_robot("tls-rover")
    base = ["robot", "teach", "--server", server.url, "--token", token, "--tour", "tls"]
    base += ["--frames", str(frames), "--marks", str(marks), "--quiet"]

    assert main([*base, "--ca-cert", str(other.cert)]) == 1
    assert "the server's certificate is not the pinned one" in capsys.readouterr().err
    assert main([*base, "--fingerprint", other.fingerprint]) == 1
    assert "the server's certificate is not the pinned one" in capsys.readouterr().err

    assert main([*base, "--fingerprint", pair.fingerprint]) == 0
    assert "taught 'tls': 2 places, 1 edges" in capsys.readouterr().out


# --- against a bare TLS listener: what reaches it, and names ---------------------------------

ANSWER = b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nContent-Length: 15\r\n"
ANSWER += b'Connection: close\r\n\r\n{"status":"ok"}'


@contextmanager
def tls_listener(pair: CertPair, host: str = "127.0.0.1") -> Iterator[tuple[str, list[bytes]]]:
    """A TLS listener on ``host`` with ``pair``'s certificate that records every byte a
    client sends after the handshake and answers each request ``{"status": "ok"}``:
    ``(https URL, received chunks)``."""
    context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    context.load_cert_chain(pair.cert, pair.key)
    listener = socket.create_server((host, 0))
    listener.settimeout(0.1)
    received: list[bytes] = []
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            try:
                conn, _ = listener.accept()
            except TimeoutError:
                continue
            conn.settimeout(5)
            try:
                with context.wrap_socket(conn, server_side=True) as tls:
                    data = b""
                    while b"\r\n\r\n" not in data and (chunk := tls.recv(65536)):
                        received.append(chunk)
                        data += chunk
                    if data:
                        tls.sendall(ANSWER)
            except OSError:  # the client broke off the handshake
                conn.close()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield f"https://{host}:{listener.getsockname()[1]}", received
    finally:
        stop.set()
        thread.join(timeout=10)
        listener.close()


@pytest.mark.parametrize("pin", ["ca_cert", "fingerprint"])
def test_no_byte_of_the_request_reaches_a_server_with_another_certificate(
    pair: CertPair, other: CertPair, pin: str
) -> None:
    kwargs = {"ca_cert": pair.cert} if pin == "ca_cert" else {"fingerprint": pair.fingerprint}
    with (
        tls_listener(other) as (url, received),
        TeachRepeatClient(url, ADMIN, **kwargs) as client,
        pytest.raises(UntrustedServerError),
    ):
        client.register_robot("mallory")
    assert received == []


def test_the_impostor_does_receive_an_unpinned_request(other: CertPair) -> None:
    """The check above can fail: a client that trusts the impostor's certificate sends it
    the request, token and all."""
    with (
        tls_listener(other) as (url, received),
        TeachRepeatClient(url, ADMIN, ca_cert=other.cert) as client,
    ):
        assert client.health() == {"status": "ok"}
    assert ADMIN.encode() in b"".join(received)


def test_a_name_the_certificate_does_not_hold_is_refused_with_the_fix(pair: CertPair) -> None:
    """The certificate names teachrepeat-hub.local and the loopback names; reached at another
    address (127.0.0.2, this machine too), ``--ca-cert`` refuses and says how to make a pair
    for it; the fingerprint, which checks no names, accepts."""
    with tls_listener(pair, "127.0.0.2") as (url, received):
        with (
            TeachRepeatClient(url, ADMIN, ca_cert=pair.cert) as client,
            pytest.raises(UntrustedServerError, match=r"does not name the host.*--host"),
        ):
            client.health()
        assert received == []
        with TeachRepeatClient(url, ADMIN, fingerprint=pair.fingerprint) as client:
            assert client.health() == {"status": "ok"}


# --- serve refuses a wrong pair of files --------------------------------------------------------


def serve_fails(tmp_path: Path, *args: str, env: dict[str, str] | None = None) -> str:
    """Run ``serve`` (no dashboard) with ``args``; assert it exits 2 at once; its stderr."""
    return serve_exits_2(tmp_path / "t.sqlite", "--dashboard-port", "-1", *args, env=env).stderr


def test_serve_refuses_a_key_that_is_not_the_certificates(
    tmp_path: Path, pair: CertPair, other: CertPair
) -> None:
    err = serve_fails(tmp_path, "--tls-cert", str(pair.cert), "--tls-key", str(other.key))
    assert f"TLS key {other.key} is not the key of the certificate {pair.cert}" in err


@pytest.mark.parametrize("given", ["cert", "key"])
def test_serve_refuses_one_tls_option_without_the_other(
    tmp_path: Path, pair: CertPair, given: str
) -> None:
    path = pair.cert if given == "cert" else pair.key
    missing = "key" if given == "cert" else "cert"
    err = serve_fails(tmp_path, f"--tls-{given}", str(path))
    assert f"tls_{given} is set but not tls_{missing}; set --tls-{missing}" in err
    # the same from the environment
    err = serve_fails(tmp_path, env={f"TEACHREPEAT_TLS_{given.upper()}": str(path)})
    assert f"set --tls-{missing} (or TEACHREPEAT_TLS_{missing.upper()})" in err


def test_serve_names_a_missing_file(tmp_path: Path, pair: CertPair) -> None:
    err = serve_fails(
        tmp_path, "--tls-cert", str(tmp_path / "cert.pem"), "--tls-key", str(pair.key)
    )
    assert f"TLS certificate {tmp_path / 'cert.pem'}: no such file" in err
    assert not (tmp_path / "t.sqlite").exists()  # stopped before opening the database
