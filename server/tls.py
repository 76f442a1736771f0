"""Serving over HTTPS: the certificate and key from the settings, checked, as uvicorn options.

:func:`ssl_options` is what ``serve`` passes to ``uvicorn.Config``; anything else served with
uvicorn from the same settings can pass the same. The checks run before the server starts, so
a wrong file stops it with a message naming the file and what is wrong with it, not with an
OpenSSL traceback ("PEM lib") from inside uvicorn.
"""

from __future__ import annotations

import datetime as dt
import ssl
from pathlib import Path
from typing import TypedDict

from server.config import Settings


class TlsError(ValueError):
    """The certificate or key the settings name cannot be served with."""


class SslOptions(TypedDict, total=False):
    """The ``uvicorn.Config`` keyword arguments for TLS; empty for plain HTTP."""

    ssl_certfile: str
    ssl_keyfile: str


def ssl_options(settings: Settings) -> SslOptions:
    """``uvicorn.Config`` keyword arguments for TLS: ``ssl_certfile`` and ``ssl_keyfile``
    after :func:`check_pair`, or ``{}`` when the settings name no certificate (plain HTTP).
    Raises :class:`TlsError`."""
    if settings.tls_cert is None or settings.tls_key is None:
        return {}
    check_pair(settings.tls_cert, settings.tls_key)
    return {"ssl_certfile": str(settings.tls_cert), "ssl_keyfile": str(settings.tls_key)}


def _read(path: Path, what: str) -> bytes:
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise TlsError(
            f"{what} {path}: no such file (make a pair with `teachrepeat cert --out DIR`)"
        ) from None
    except IsADirectoryError:
        raise TlsError(f"{what} {path}: is a folder; give the .pem file in it") from None
    except OSError as exc:
        raise TlsError(
            f"{what} {path}: cannot read it ({exc.strerror}); the user running serve needs "
            "read access"
        ) from None


def check_pair(cert: Path, key: Path, *, now: dt.datetime | None = None) -> None:
    """Raise :class:`TlsError` unless ``cert`` is a readable PEM certificate, valid at
    ``now``, and ``key`` a readable, unencrypted PEM private key that belongs to it."""
    from cryptography import x509
    from cryptography.exceptions import UnsupportedAlgorithm
    from cryptography.hazmat.primitives import serialization

    cert_pem = _read(cert, "TLS certificate")
    key_pem = _read(key, "TLS key")
    try:
        certificate = x509.load_pem_x509_certificate(cert_pem)
    except ValueError:
        hint = " (that is a private key: swap the two?)" if b"PRIVATE KEY" in cert_pem else ""
        raise TlsError(
            f"TLS certificate {cert}: not a PEM certificate{hint}; it should begin with "
            "-----BEGIN CERTIFICATE-----"
        ) from None
    try:
        private = serialization.load_pem_private_key(key_pem, password=None)
    except TypeError:
        raise TlsError(
            f"TLS key {key}: the key is protected by a passphrase, which serve cannot ask "
            "for; keep it unencrypted with mode 0600 (as `teachrepeat cert` writes it)"
        ) from None
    except (ValueError, UnsupportedAlgorithm) as exc:
        hint = " (that is a certificate: swap the two?)" if b"CERTIFICATE" in key_pem else ""
        raise TlsError(f"TLS key {key}: not a PEM private key{hint} ({exc})") from None
    same = private.public_key().public_bytes(
        serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo
    ) == certificate.public_key().public_bytes(
        serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo
    )
    if not same:
        raise TlsError(
            f"TLS key {key} is not the key of the certificate {cert}: give the key.pem made "
            "together with that cert.pem"
        )
    moment = now or dt.datetime.now(dt.UTC)
    if moment > certificate.not_valid_after_utc:
        raise TlsError(
            f"TLS certificate {cert}: expired on {certificate.not_valid_after_utc:%Y-%m-%d}; "
            "make a new pair with `teachrepeat cert` and pin the new one on the robots"
        )
    if moment < certificate.not_valid_before_utc:
        raise TlsError(
            f"TLS certificate {cert}: valid only from "
            f"{certificate.not_valid_before_utc:%Y-%m-%d %H:%M} UTC; check this machine's clock"
        )
    try:  # what uvicorn will do; the checks above should have caught every reason it fails
        ssl.create_default_context(ssl.Purpose.CLIENT_AUTH).load_cert_chain(cert, key)
    except ssl.SSLError as exc:
        raise TlsError(
            f"TLS certificate {cert} and key {key}: OpenSSL refuses them ({exc})"
        ) from None
