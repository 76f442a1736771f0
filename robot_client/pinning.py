"""Which server certificate a robot trusts: exactly one (``ca_cert``), one digest
(``fingerprint``), or the system's certificate authorities.

A home server has no certificate from a public authority; ``teachrepeat cert`` makes it a
self-signed one. The robot pins it, either by holding a copy of ``cert.pem`` (verified as the
only trusted authority, with the host name checked) or by its SHA-256 fingerprint (compared
during the TLS handshake, before a request, and so before any token, is sent).
"""

from __future__ import annotations

import hashlib
import ssl
from pathlib import Path
from typing import Any

_HEX = set("0123456789abcdef")


class UntrustedServerError(ConnectionError):
    """The server's TLS certificate is not the one this client was told to trust."""


class FingerprintMismatch(ssl.SSLCertVerificationError):
    """Raised inside the TLS handshake when the server's certificate has another digest.

    An ``ssl.SSLCertVerificationError``, so that the socket is closed and the HTTP stack
    reports it as a failed connection; :func:`explain` turns it into an
    :class:`UntrustedServerError`."""

    def __init__(self, expected: str, presented: str) -> None:
        super().__init__(f"certificate fingerprint {presented}, pinned {expected}")
        self.expected = expected
        self.presented = presented


def fingerprint_of(der: bytes) -> str:
    """SHA-256 of a DER certificate as ``teachrepeat cert`` prints it: 32 upper-case hex
    pairs joined by colons (``AB:01:...``), the form ``openssl x509 -fingerprint`` uses."""
    return ":".join(f"{b:02X}" for b in hashlib.sha256(der).digest())


def parse_fingerprint(text: str) -> str:
    """A SHA-256 fingerprint in the canonical form of :func:`fingerprint_of`. Takes hex with or
    without colons (or spaces), any case, optionally after ``sha256:`` or ``SHA256
    Fingerprint=``."""
    cleaned = text.strip().lower()
    for prefix in ("sha256 fingerprint=", "sha256:", "sha256="):
        cleaned = cleaned.removeprefix(prefix)
    digits = "".join(c for c in cleaned if c not in ": ")
    if len(digits) != 64 or not set(digits) <= _HEX:
        raise ValueError(
            f"{text!r} is not a SHA-256 fingerprint: that is 64 hex digits (colons allowed), "
            "as `teachrepeat cert` prints it"
        )
    return ":".join(digits[i : i + 2] for i in range(0, 64, 2)).upper()


def _checks_fingerprint(base: type[Any], expected: str) -> type[Any]:
    """A subclass of ``ssl.SSLSocket`` or ``ssl.SSLObject`` that compares the peer
    certificate's digest with ``expected`` as soon as the handshake completes."""

    def do_handshake(self: Any, *args: Any) -> None:
        base.do_handshake(self, *args)
        der = self.getpeercert(binary_form=True)
        presented = fingerprint_of(der) if der else "none"
        if presented != expected:
            raise FingerprintMismatch(expected, presented)

    return type(f"Pinned{base.__name__}", (base,), {"do_handshake": do_handshake})


def ssl_context(
    *, ca_cert: Path | None = None, fingerprint: str | None = None
) -> ssl.SSLContext | None:
    """The TLS context for a pinned server, or ``None`` when neither is given (the system's
    authorities then decide).

    ``ca_cert``: trust exactly this certificate (a copy of the server's ``cert.pem``); the
    host name in the URL must be one it names. ``fingerprint``: the server's certificate must
    have this SHA-256 digest; given alone, nothing else is checked (not the name, not the
    dates), which suits a robot that reaches the server by an address the certificate does
    not name or whose clock is not set yet. Given both, both must hold."""
    if ca_cert is None and fingerprint is None:
        return None
    if ca_cert is not None:
        if not ca_cert.is_file():
            raise ValueError(
                f"--ca-cert {ca_cert}: no such file; copy the server's cert.pem to the robot"
            )
        try:
            context = ssl.create_default_context(cafile=str(ca_cert))
        except ssl.SSLError as exc:
            raise ValueError(
                f"--ca-cert {ca_cert}: not a PEM certificate ({exc.reason}); copy the "
                "server's cert.pem, not its key"
            ) from None
    else:
        context = ssl.create_default_context()
        context.check_hostname = False
        context.verify_mode = ssl.CERT_NONE
    if fingerprint is not None:
        expected = parse_fingerprint(fingerprint)
        context.sslsocket_class = _checks_fingerprint(ssl.SSLSocket, expected)
        context.sslobject_class = _checks_fingerprint(ssl.SSLObject, expected)
    return context


def explain(exc: BaseException, *, ca_cert: Path | None = None) -> str | None:
    """What to tell the user when ``exc`` (an HTTP transport error) comes from a certificate
    that does not verify; ``None`` when it does not."""
    cause: BaseException | None = exc
    while cause is not None and not isinstance(cause, ssl.SSLCertVerificationError):
        cause = cause.__cause__ or cause.__context__
    if cause is None:
        return None
    if isinstance(cause, FingerprintMismatch):
        return (
            f"the server's certificate is not the pinned one: its SHA-256 fingerprint is "
            f"{cause.presented}, the pinned one {cause.expected}. Nothing was sent. If the "
            "server has a new certificate, pin its fingerprint (printed by `teachrepeat cert`)"
        )
    reason = cause.verify_message or str(cause)
    code = cause.verify_code
    if code in (62, 64):  # X509_V_ERR_HOSTNAME_MISMATCH, X509_V_ERR_IP_ADDRESS_MISMATCH
        return (
            f"the server's certificate does not name the host in the URL ({reason}); make "
            "the pair again with `teachrepeat cert --host NAME_OR_IP` for the address the "
            "robot uses, or pin it with --fingerprint, which does not check names"
        )
    if code in (9, 10):  # X509_V_ERR_CERT_NOT_YET_VALID, X509_V_ERR_CERT_HAS_EXPIRED
        return (
            f"the server's certificate is out of its dates ({reason}); check the robot's "
            "clock, or make a new pair with `teachrepeat cert` and pin that"
        )
    if ca_cert is not None:
        return (
            f"the server's certificate is not the pinned one, {ca_cert} (OpenSSL: {reason}). "
            "Nothing was sent. If the server has a new certificate, copy its cert.pem to the "
            "robot"
        )
    return (
        f"the server's certificate is not trusted ({reason}); for a home server's "
        "self-signed certificate give a copy of its cert.pem with --ca-cert, or its "
        "fingerprint with --fingerprint"
    )
