"""``teachrepeat cert``: a self-signed certificate and key for a home server.

A home has no public name a certificate authority would sign, so the server gets its own
certificate and every robot pins it (``--ca-cert cert.pem`` or ``--fingerprint``). The
certificate names the hosts and addresses the robots reach the server by, plus ``localhost``,
``127.0.0.1`` and ``::1``; the key is an ECDSA P-256 key written with mode 0600.
"""

from __future__ import annotations

import argparse
import datetime as dt
import ipaddress
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from robot_client.pinning import fingerprint_of

LOOPBACK = ("localhost", "127.0.0.1", "::1")
DEFAULT_DAYS = 3650
"""Ten years: every new certificate must be pinned on every robot again, and a home has nobody
whose job that is. The key never leaves the server."""
CERT_FILE = "cert.pem"
KEY_FILE = "key.pem"


@dataclass(frozen=True)
class CertPair:
    """What :func:`write_pair` wrote."""

    cert: Path
    key: Path
    names: tuple[str, ...]
    """Host names and addresses in the subjectAltName, in order."""
    not_after: dt.datetime
    fingerprint: str
    """SHA-256 of the certificate, ``AB:01:...`` (:func:`robot_client.pinning.fingerprint_of`)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out", required=True, type=Path, help=f"folder for {CERT_FILE} and {KEY_FILE}"
    )
    parser.add_argument(
        "--host",
        action="append",
        default=[],
        metavar="NAME_OR_IP",
        help="a host name or IP address the robots use to reach the server (repeat for more); "
        "localhost, 127.0.0.1 and ::1 are always included",
    )
    parser.add_argument(
        "--days", type=int, default=DEFAULT_DAYS, help=f"validity (default {DEFAULT_DAYS})"
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help="replace an existing pair (robots pinned to the old one will refuse the new one)",
    )


def subject_names(hosts: Sequence[str]) -> tuple[str, ...]:
    """``hosts`` then the loopback names, each once, IP addresses in their canonical form."""
    names: list[str] = []
    for host in [*hosts, *LOOPBACK]:
        host = host.strip()
        try:
            host = str(ipaddress.ip_address(host.strip("[]")))
        except ValueError:
            host = host.lower().rstrip(".")
            if not host or any(c in host for c in "/:@ "):
                raise ValueError(
                    f"--host {host!r} is neither a host name nor an IP address "
                    "(give the name or address alone, no scheme or port)"
                ) from None
        if host not in names:
            names.append(host)
    return tuple(names)


def make_self_signed(
    hosts: Sequence[str] = (), *, days: int = DEFAULT_DAYS, now: dt.datetime | None = None
) -> tuple[bytes, bytes]:
    """A self-signed certificate for ``hosts`` (plus the loopback names) and its key, both
    PEM: ``(cert, key)``. Valid from a day before ``now`` (a robot's clock a little behind)
    for ``days`` days."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    if days < 1:
        raise ValueError(f"--days {days}: a certificate must be valid for at least one day")
    names = subject_names(hosts)
    alt: list[x509.GeneralName] = []
    for name in names:
        try:
            alt.append(x509.IPAddress(ipaddress.ip_address(name)))
        except ValueError:
            alt.append(x509.DNSName(name))
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name(
        [
            x509.NameAttribute(NameOID.COMMON_NAME, names[0]),
            x509.NameAttribute(NameOID.ORGANIZATION_NAME, "teachrepeat home server"),
        ]
    )
    start = (now or dt.datetime.now(dt.UTC)) - dt.timedelta(days=1)
    public = key.public_key()
    cert = (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(subject)
        .public_key(public)
        .serial_number(x509.random_serial_number())
        .not_valid_before(start)
        .not_valid_after(start + dt.timedelta(days=days + 1))
        .add_extension(x509.SubjectAlternativeName(alt), critical=False)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=False,
                crl_sign=False,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(public), critical=False)
        .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(public), critical=False)
        .sign(key, hashes.SHA256())
    )
    key_pem = key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )
    return cert.public_bytes(serialization.Encoding.PEM), key_pem


def write_pair(
    out: Path, hosts: Sequence[str] = (), *, days: int = DEFAULT_DAYS, force: bool = False
) -> CertPair:
    """Write ``out/cert.pem`` and ``out/key.pem`` (mode 0600), creating ``out``. Refuses to
    replace an existing pair unless ``force``: robots pinned to it would be refused."""
    from cryptography import x509
    from cryptography.hazmat.primitives.serialization import Encoding

    cert_path, key_path = out / CERT_FILE, out / KEY_FILE
    existing = [p for p in (cert_path, key_path) if p.exists()]
    if existing and not force:
        raise FileExistsError(
            f"{existing[0]} exists; robots pinned to it would refuse a new one. "
            "Give --force to replace the pair, or another --out"
        )
    cert_pem, key_pem = make_self_signed(hosts, days=days)
    out.mkdir(parents=True, exist_ok=True)
    fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    os.fchmod(fd, 0o600)  # an existing file keeps its mode through O_CREAT
    with os.fdopen(fd, "wb") as fh:
        fh.write(key_pem)
    cert_path.write_bytes(cert_pem)
    cert = x509.load_pem_x509_certificate(cert_pem)
    return CertPair(
        cert=cert_path,
        key=key_path,
        names=subject_names(hosts),
        not_after=cert.not_valid_after_utc,
        fingerprint=fingerprint_of(cert.public_bytes(Encoding.DER)),
    )


def run(args: argparse.Namespace) -> int:
    try:
        pair = write_pair(args.out, args.host, days=args.days, force=args.force)
    except (ValueError, OSError) as exc:
        print(f"teachrepeat cert: {exc}", file=sys.stderr)
        return 2
    print(f"certificate  {pair.cert}  (for the server, and a copy for every robot)")
    print(f"key          {pair.key}  (mode 0600; stays on the server)")
    print(f"names        {', '.join(pair.names)}")
    print(f"valid until  {pair.not_after:%Y-%m-%d}")
    print(f"SHA-256      {pair.fingerprint}")
    print(f"serve with   teachrepeat serve --tls-cert {pair.cert} --tls-key {pair.key} --host ...")
    return 0
