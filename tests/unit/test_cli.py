"""Every command has help, and docs/commands.md (which the README links) documents every
command (sqlite-utils' rule)."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import serve_exits_2

from server.cli import COMMANDS, build_parser, main

ROOT = Path(__file__).resolve().parents[2]
COMMANDS_DOC = (ROOT / "docs" / "commands.md").read_text()
README = (ROOT / "README.md").read_text()


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
def test_the_command_reference_documents_command(path: tuple[str, ...]) -> None:
    assert "teachrepeat " + " ".join(path) in COMMANDS_DOC


def test_the_readme_links_the_command_reference_and_gives_the_two_commands() -> None:
    assert "(docs/commands.md)" in README
    assert "make demo" in README and "make test" in README


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


def test_serve_keeps_freed_memory_unless_the_environment_says(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import platform

    from server.serve import keep_freed_memory

    for name in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_"):
        monkeypatch.setenv(name, "1000000")
        assert not keep_freed_memory()
        monkeypatch.delenv(name)
    assert keep_freed_memory() == (platform.libc_ver()[0] == "glibc")


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ('{"dock_second_axes": false}', "NavigationParams has no setting 'dock_second_axes'"),
        ('{"motion.spin_w": "fast"}', "MotionParams.spin_w takes float"),
        ("not json", 'error parsing value for field "navigation"'),
    ],
)
def test_serve_refuses_navigation_settings_it_cannot_apply(
    value: str,
    message: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.setenv("TEACHREPEAT_NAVIGATION", value)
    monkeypatch.setenv("TEACHREPEAT_ADMIN_TOKEN", "a-token")
    db = tmp_path / "t.sqlite"
    assert main(["serve", "--db", str(db), "--port", "0", "--dashboard-port", "-1"]) == 2
    assert message in capsys.readouterr().err


def test_navigation_settings_reach_the_navigation_core(tmp_path: Path) -> None:
    from server.app import create_app
    from server.config import Settings

    for navigation, second_axis in (
        ({"dock_second_axis": False, "motion.unstick_s": 6}, False),
        ({}, True),
    ):
        services = create_app(
            Settings(db=tmp_path / "t.sqlite", admin_token="a-token", navigation=navigation)
        ).state.services
        try:
            params = services.navigation.params
            assert params.dock_second_axis is second_axis
            assert params.motion.unstick_s == (6.0 if navigation else 4.0)
        finally:
            services.close()


def test_an_unknown_option_prints_the_sub_command_s_usage(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["bench", "navigate", "--trials", "3", "--bogus"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: teachrepeat bench navigate")
    assert "unrecognized arguments: --bogus" in err


@pytest.mark.parametrize(
    ("host", "login", "needed"),
    [
        ("127.0.0.1", None, False),  # the loopback default: no login, every household
        ("127.3.2.1", None, False),
        ("::1", None, False),
        ("localhost", None, False),
        ("127.0.0.1", True, True),
        ("0.0.0.0", None, True),
        ("::", None, True),
        ("192.168.1.20", None, True),
        ("teachrepeat-hub.local", None, True),  # a name may resolve to anything
        ("192.168.1.20", True, True),
        ("127.0.0.1", False, False),
    ],
)
def test_the_dashboard_needs_a_login_off_loopback(
    host: str, login: bool | None, needed: bool
) -> None:
    from server.config import Settings

    settings = Settings(host=host, dashboard_login=login)
    assert settings.dashboard_needs_login() is needed


def test_a_dashboard_without_login_off_loopback_is_refused() -> None:
    from server.config import Settings

    with pytest.raises(ValueError, match=r"host 10\.0\.0\.2 is not a loopback address"):
        Settings(host="10.0.0.2", dashboard_login=False).dashboard_needs_login()


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (("--workers", "2", "--dashboard-port", "0"), "--workers runs no dashboard"),
        (("--workers", "2", "--tls-cert", "c.pem", "--tls-key", "k.pem"), "does not serve HTTPS"),
        (("--workers", "-1"), "workers"),
    ],
)
def test_serve_workers_refuses_what_it_cannot_do(
    tmp_path: Path, args: tuple[str, ...], says: str
) -> None:
    done = serve_exits_2(tmp_path / "db.sqlite", *args)
    assert says in done.stderr
