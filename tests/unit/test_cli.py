"""Every command has help, and the README documents every command (sqlite-utils' rule)."""

from __future__ import annotations

from pathlib import Path

import pytest

from server.cli import COMMANDS, build_parser, main

README = (Path(__file__).resolve().parents[2] / "README.md").read_text()


def installed() -> list[tuple[str, ...]]:
    import importlib.util

    return [path for path, module, _ in COMMANDS if importlib.util.find_spec(module)]


@pytest.mark.parametrize("path", installed())
def test_command_has_help(path: tuple[str, ...], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main([*path, "--help"])
    assert exc.value.code == 0
    assert "usage: teachrepeat " + " ".join(path) in capsys.readouterr().out


@pytest.mark.parametrize("path", installed())
def test_readme_documents_command(path: tuple[str, ...]) -> None:
    assert "teachrepeat " + " ".join(path) in README


def test_parser_builds() -> None:
    assert build_parser().prog == "teachrepeat"


def test_serve_caps_malloc_arenas_unless_the_environment_says(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import platform

    from server.serve import limit_malloc_arenas

    monkeypatch.setenv("MALLOC_ARENA_MAX", "4")
    assert not limit_malloc_arenas()
    monkeypatch.delenv("MALLOC_ARENA_MAX")
    assert limit_malloc_arenas() == (platform.libc_ver()[0] == "glibc")
