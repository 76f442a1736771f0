"""Issued bearer tokens (server/security.py)."""

from __future__ import annotations

from server.security import TOKEN_PREFIX, hash_token, new_token, same_token


def test_tokens_never_start_with_a_dash_and_do_not_repeat() -> None:
    """A token beginning with "-" was read as an option after ``robot teach --token`` (one in
    64 of the old tokens)."""
    tokens = [new_token() for _ in range(2000)]
    assert all(t.startswith(TOKEN_PREFIX) and not t.startswith("-") for t in tokens)
    assert len(set(tokens)) == len(tokens)
    assert all(len(t) == len(TOKEN_PREFIX) + 43 for t in tokens)  # 256 bits, URL-safe text


def test_a_token_matches_only_itself_by_its_hash() -> None:
    a, b = new_token(), new_token()
    assert same_token(hash_token(a), hash_token(a))
    assert not same_token(hash_token(a), hash_token(b))
