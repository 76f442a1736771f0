"""Where a robot command reads its bearer token (a file, the environment, or, discouraged, the
command line) and which server certificate it trusts (``--ca-cert``, ``--fingerprint``:
:mod:`robot_client.pinning`).

A command line is visible to every user of the machine (``ps``), so the token is best given
as ``--token-file FILE`` (one line; a file others can read is warned about) or in the
environment variable ``TEACHREPEAT_ROBOT_TOKEN``. ``--token T`` still works, with a warning.
The token is never printed.
"""

from __future__ import annotations

import argparse
import os
import stat
import sys
from pathlib import Path

TOKEN_ENV = "TEACHREPEAT_ROBOT_TOKEN"
"""The environment variable a robot's token may come from."""


def add_token_arguments(parser: argparse.ArgumentParser) -> None:
    """``--token T`` and ``--token-file FILE`` (the environment variable is the default)."""
    given = parser.add_mutually_exclusive_group()
    given.add_argument(
        "--token",
        help=f"the robot's bearer token; visible to other users in `ps`: prefer --token-file "
        f"or the environment variable {TOKEN_ENV}",
    )
    given.add_argument(
        "--token-file",
        type=Path,
        metavar="FILE",
        help=f"read the robot's bearer token from FILE (one line; keep it mode 0600); "
        f"default: the environment variable {TOKEN_ENV}",
    )


def read_token(args: argparse.Namespace) -> str:
    """The token from ``--token-file``, ``--token`` or the environment, in that order.

    Raises:
        ValueError: none given, the file cannot be read or is empty (the message says what to
            do; it never holds the token).
    """
    path: Path | None = getattr(args, "token_file", None)
    if path is not None:
        try:
            text = path.read_text().strip()
            mode = path.stat().st_mode
        except OSError as exc:
            raise ValueError(f"--token-file {path}: cannot read it ({exc.strerror})") from None
        if not text:
            raise ValueError(f"--token-file {path} is empty; put the robot's token in it")
        if mode & (stat.S_IRWXG | stat.S_IRWXO):
            print(
                f"warning: {path} can be read by other users; `chmod 600 {path}`",
                file=sys.stderr,
            )
        return text.splitlines()[0].strip()
    token: str | None = getattr(args, "token", None)
    if token:
        print(
            f"warning: --token is visible to other users of this machine (ps); prefer "
            f"--token-file FILE or the environment variable {TOKEN_ENV}",
            file=sys.stderr,
        )
        return token
    token = os.environ.get(TOKEN_ENV, "").strip()
    if token:
        return token
    raise ValueError(
        f"no robot token: give --token-file FILE or set {TOKEN_ENV} (POST /robots answers the "
        "token when the robot is registered)"
    )


def add_pinning_arguments(parser: argparse.ArgumentParser) -> None:
    """``--ca-cert FILE`` and ``--fingerprint SHA256``: pin an https:// server's certificate."""
    parser.add_argument(
        "--ca-cert",
        type=Path,
        metavar="FILE",
        help="trust only this certificate (a copy of the server's cert.pem; https:// only)",
    )
    parser.add_argument(
        "--fingerprint",
        metavar="SHA256",
        help="the server certificate's SHA-256 fingerprint, as `teachrepeat cert` prints it",
    )
