"""``teachrepeat cert``, the checks ``serve`` runs on a certificate and key, the TLS settings,
and how the robot client reads a pinned fingerprint."""

from __future__ import annotations

import datetime as dt
import ipaddress
import re
import stat
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from pydantic import ValidationError

from robot_client.client import TeachRepeatClient
from robot_client.pinning import parse_fingerprint
from server.cert import CertPair, make_self_signed, subject_names, write_pair
from server.cli import main
from server.config import Settings
from server.tls import TlsError, check_pair, ssl_options

FINGERPRINT = re.compile(r"^(?:[0-9A-F]{2}:){31}[0-9A-F]{2}$")


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory) -> CertPair:
    return write_pair(tmp_path_factory.mktemp("tls"), ["192.168.1.20", "Robot-Hub.local."])


def load(path: Path) -> x509.Certificate:
    return x509.load_pem_x509_certificate(path.read_bytes())


# --- teachrepeat cert ---------------------------------------------------------------------------


def test_the_certificate_names_the_given_hosts_and_loopback(pair: CertPair) -> None:
    cert = load(pair.cert)
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert san.get_values_for_type(x509.DNSName) == ["robot-hub.local", "localhost"]
    assert san.get_values_for_type(x509.IPAddress) == [
        ipaddress.ip_address("192.168.1.20"),
        ipaddress.ip_address("127.0.0.1"),
        ipaddress.ip_address("::1"),
    ]
    assert pair.names == ("192.168.1.20", "robot-hub.local", "localhost", "127.0.0.1", "::1")
    assert cert.issuer == cert.subject  # self-signed
    constraints = cert.extensions.get_extension_for_class(x509.BasicConstraints).value
    assert constraints.ca is False
    days = (cert.not_valid_after_utc - dt.datetime.now(dt.UTC)).days
    assert 3649 <= days <= 3650


def test_the_key_is_private_and_belongs_to_the_certificate(pair: CertPair) -> None:
    assert stat.S_IMODE(pair.key.stat().st_mode) == 0o600
    key = serialization.load_pem_private_key(pair.key.read_bytes(), password=None)
    spki = serialization.PublicFormat.SubjectPublicKeyInfo
    assert key.public_key().public_bytes(serialization.Encoding.DER, spki) == (
        load(pair.cert).public_key().public_bytes(serialization.Encoding.DER, spki)
    )
    check_pair(pair.cert, pair.key)  # what serve checks passes


def test_the_fingerprint_is_the_certificates_sha256_in_openssl_form(pair: CertPair) -> None:
    assert FINGERPRINT.match(pair.fingerprint), pair.fingerprint
    digest = load(pair.cert).fingerprint(hashes.SHA256())
    assert pair.fingerprint == ":".join(f"{b:02X}" for b in digest)
    assert parse_fingerprint(pair.fingerprint) == pair.fingerprint


def test_the_command_prints_the_fingerprint_and_refuses_to_replace_a_pair(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "tls"
    assert main(["cert", "--out", str(out), "--host", "10.0.0.7", "--days", "30"]) == 0
    printed = capsys.readouterr().out
    found = re.search(r"SHA-256\s+(\S+)", printed)
    assert found and FINGERPRINT.match(found.group(1))
    first = (out / "cert.pem").read_bytes()
    assert "10.0.0.7, localhost, 127.0.0.1, ::1" in printed

    assert main(["cert", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "cert.pem exists" in err and "--force" in err
    assert (out / "cert.pem").read_bytes() == first

    (out / "key.pem").chmod(0o644)
    assert main(["cert", "--out", str(out), "--force"]) == 0
    assert (out / "cert.pem").read_bytes() != first
    assert stat.S_IMODE((out / "key.pem").stat().st_mode) == 0o600


@pytest.mark.parametrize("host", ["https://hub.local", "hub.local:8000", "", "a b"])
def test_a_host_that_is_not_a_name_or_address_is_refused(host: str) -> None:
    with pytest.raises(ValueError, match="neither a host name nor an IP address"):
        subject_names([host])


def test_names_are_canonical_and_given_once() -> None:
    assert subject_names(["[::1]", "LOCALHOST", "0:0::1"]) == ("::1", "localhost", "127.0.0.1")


# --- what serve checks --------------------------------------------------------------------------


def test_a_key_of_another_certificate_is_refused(pair: CertPair, tmp_path: Path) -> None:
    other = write_pair(tmp_path)
    with pytest.raises(TlsError, match="is not the key of the certificate"):
        check_pair(pair.cert, other.key)


def test_swapped_files_say_so(pair: CertPair) -> None:
    with pytest.raises(TlsError, match=r"not a PEM certificate \(that is a private key"):
        check_pair(pair.key, pair.cert)


def test_missing_files_and_folders_are_named(pair: CertPair, tmp_path: Path) -> None:
    with pytest.raises(TlsError, match=rf"TLS certificate {tmp_path}/no.pem: no such file"):
        check_pair(tmp_path / "no.pem", pair.key)
    with pytest.raises(TlsError, match=rf"TLS key {tmp_path}/no.pem: no such file"):
        check_pair(pair.cert, tmp_path / "no.pem")
    with pytest.raises(TlsError, match="is a folder"):
        check_pair(tmp_path, pair.key)


def test_a_key_with_a_passphrase_is_refused(pair: CertPair, tmp_path: Path) -> None:
    key = serialization.load_pem_private_key(pair.key.read_bytes(), password=None)
    locked = tmp_path / "locked.pem"
    locked.write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.BestAvailableEncryption(b"secret"),
        )
    )
    with pytest.raises(TlsError, match="protected by a passphrase"):
        check_pair(pair.cert, locked)


def test_an_expired_certificate_is_refused(tmp_path: Path) -> None:
    cert_pem, key_pem = make_self_signed(days=1, now=dt.datetime(2020, 1, 1, tzinfo=dt.UTC))
    (tmp_path / "c.pem").write_bytes(cert_pem)
    (tmp_path / "k.pem").write_bytes(key_pem)
    with pytest.raises(TlsError, match="expired on 2020-01-02"):
        check_pair(tmp_path / "c.pem", tmp_path / "k.pem")


def test_ssl_options_are_uvicorns_keywords(pair: CertPair) -> None:
    settings = Settings(tls_cert=pair.cert, tls_key=pair.key)
    assert ssl_options(settings) == {"ssl_certfile": str(pair.cert), "ssl_keyfile": str(pair.key)}
    assert ssl_options(Settings()) == {}


@pytest.mark.parametrize(("given", "missing"), [("cert", "key"), ("key", "cert")])
def test_settings_take_both_tls_files_or_neither(
    given: str, missing: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("TEACHREPEAT_ADMIN_TOKEN", "do-not-print-me")
    monkeypatch.setenv(f"TEACHREPEAT_TLS_{given.upper()}", "/srv/tls/x.pem")
    with pytest.raises(ValidationError) as exc:
        Settings()
    text = str(exc.value)
    assert f"tls_{given} is set but not tls_{missing}" in text
    assert f"--tls-{missing}" in text and f"TEACHREPEAT_TLS_{missing.upper()}" in text
    assert "do-not-print-me" not in text  # the error does not echo the other settings


# --- the robot client's pins --------------------------------------------------------------------


@pytest.mark.parametrize(
    "text",
    [
        "ab" * 32,
        ":".join(["AB"] * 32),
        " ".join(["ab"] * 32),
        "sha256 Fingerprint=" + ":".join(["AB"] * 32),
        "SHA256:" + "Ab" * 32,
    ],
)
def test_a_fingerprint_is_read_with_or_without_colons(text: str) -> None:
    assert parse_fingerprint(text) == ":".join(["AB"] * 32)


@pytest.mark.parametrize("text", ["", "ab" * 31, "ab" * 33, "zz" * 32, "ab" * 20])
def test_a_fingerprint_of_the_wrong_shape_is_refused(text: str) -> None:
    with pytest.raises(ValueError, match="64 hex digits"):
        parse_fingerprint(text)


def test_a_pinned_client_refuses_plain_http(pair: CertPair) -> None:
    with pytest.raises(ValueError, match="needs an https:// server URL"):
        TeachRepeatClient("http://192.168.1.20:8000", "t", ca_cert=pair.cert)
    with pytest.raises(ValueError, match="needs an https:// server URL"):
        TeachRepeatClient("http://192.168.1.20:8000", "t", fingerprint=pair.fingerprint)


def test_a_pinned_client_says_which_file_is_wrong(pair: CertPair, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="no such file"):
        TeachRepeatClient("https://hub:8000", "t", ca_cert=tmp_path / "none.pem")
    with pytest.raises(ValueError, match="not a PEM certificate"):
        TeachRepeatClient("https://hub:8000", "t", ca_cert=pair.key)
