"""Bearer tokens: issued random, stored as SHA-256 hashes, compared in constant time."""

from __future__ import annotations

import hashlib
import hmac
import secrets

#: What every issued token starts with: never a "-" (a token that began with one was read as an
#: option by ``robot teach --token``), and easy to find for secret scanners.
TOKEN_PREFIX = "tr_"


def new_token() -> str:
    """A fresh bearer token: ``tr_`` and 256 random bits as URL-safe text."""
    return TOKEN_PREFIX + secrets.token_urlsafe(32)


def hash_token(token: str) -> str:
    """The hex SHA-256 of ``token``; what the database stores. Tokens are random, so an
    unsalted fast hash is enough: nothing is gained by guessing them offline."""
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


def same_token(given: str, expected: str) -> bool:
    """Constant-time comparison of two tokens."""
    return hmac.compare_digest(given.encode("utf-8"), expected.encode("utf-8"))


def hash_password(password: str) -> str:
    """An argon2id hash of a household's password (salted, memory-hard; argon2-cffi's
    defaults, RFC 9106's low-memory profile: about 0.1 s and 64 MiB per hash)."""
    from argon2 import PasswordHasher

    return PasswordHasher().hash(password)


_DUMMY_HASH: list[str] = []


def verify_password(password: str, password_hash: str | None) -> bool:
    """Whether ``password`` matches ``password_hash``. With ``None`` (no such household, or no
    password set) a dummy hash is checked anyway, so the answer takes as long either way and
    its timing does not tell which household names exist."""
    from argon2 import PasswordHasher
    from argon2.exceptions import InvalidHashError, VerificationError

    known = password_hash is not None
    if password_hash is None:
        if not _DUMMY_HASH:
            _DUMMY_HASH.append(hash_password(new_token()))
        password_hash = _DUMMY_HASH[0]
    try:
        PasswordHasher().verify(password_hash, password)
    except (VerificationError, InvalidHashError):
        return False
    return known
