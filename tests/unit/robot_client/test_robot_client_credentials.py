"""Where a robot command reads its token: a file, the environment, the command line."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from robot_client.credentials import TOKEN_ENV, add_token_arguments, read_token


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_token_arguments(parser)
    return parser.parse_args(argv)


def test_from_a_file_first_line_stripped(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    token = tmp_path / "token"
    token.write_text("  s3cret-token  \n# a comment\n")
    token.chmod(0o600)
    assert read_token(parse("--token-file", str(token))) == "s3cret-token"
    assert capsys.readouterr().err == ""


def test_a_file_others_can_read_is_warned_about(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    token = tmp_path / "token"
    token.write_text("s3cret-token\n")
    token.chmod(0o644)
    assert read_token(parse("--token-file", str(token))) == "s3cret-token"
    err = capsys.readouterr().err
    assert "can be read by other users" in err and "s3cret" not in err


def test_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(TOKEN_ENV, "env-token")
    assert read_token(parse()) == "env-token"


def test_on_the_command_line_with_a_warning(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv(TOKEN_ENV, "env-token")
    assert read_token(parse("--token", "flag-token")) == "flag-token"
    err = capsys.readouterr().err
    assert "visible to other users" in err and "flag-token" not in err


def test_none_or_a_bad_file_says_what_to_do(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv(TOKEN_ENV, raising=False)
    with pytest.raises(ValueError, match="no robot token: give --token-file FILE or set"):
        read_token(parse())
    with pytest.raises(ValueError, match="cannot read it"):
        read_token(parse("--token-file", str(tmp_path / "missing")))
    empty = tmp_path / "empty"
    empty.write_text("\n")
    with pytest.raises(ValueError, match="is empty"):
        read_token(parse("--token-file", str(empty)))
    with pytest.raises(SystemExit):  # not both
        parse("--token", "a", "--token-file", str(empty))
