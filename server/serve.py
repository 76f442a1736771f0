"""``teachrepeat serve``: run the API (and, when installed, the dashboard)."""

from __future__ import annotations

import argparse
import ctypes
import gc
import os
import socket
import sys
from pathlib import Path

from pydantic import SecretStr

from server.config import Settings
from server.security import new_token


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--db", type=Path, help="SQLite file (default: data/teachrepeat.sqlite)")
    parser.add_argument("--host", help="interface to bind (default 127.0.0.1)")
    parser.add_argument("--port", type=int, help="API port (default 8000; 0 = any free port)")
    parser.add_argument(
        "--dashboard-port",
        type=int,
        help="dashboard port (default 8080; 0 = any free port; -1 = no dashboard)",
    )


def admin_token_for(settings: Settings) -> SecretStr:
    """The configured admin token, or one kept in ``admin_token`` beside the database
    (created with mode 0600 on first use). The token itself is never printed."""
    if settings.admin_token is not None:
        return settings.admin_token
    path = token_file(settings)
    if path.exists():
        return SecretStr(path.read_text().strip())
    path.parent.mkdir(parents=True, exist_ok=True)
    token = new_token()
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.write(token + "\n")
    return SecretStr(token)


def token_file(settings: Settings) -> Path:
    return settings.db.parent / "admin_token"


def settings_from(args: argparse.Namespace) -> Settings:
    overrides = {
        k: getattr(args, k) for k in ("db", "host", "port") if getattr(args, k, None) is not None
    }
    dashboard_port = getattr(args, "dashboard_port", None)
    if dashboard_port is not None:
        overrides["dashboard_port"] = None if dashboard_port < 0 else dashboard_port
    settings = Settings(**overrides)
    return settings.model_copy(update={"admin_token": admin_token_for(settings)})


def bind_port(host: str, port: int) -> socket.socket:
    """A listening socket on ``host:port`` (``port`` 0 = any free port). It listens
    before the address is printed, so a client that reads the address can connect at
    once (connections wait in the backlog until the server accepts them)."""
    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    # Accepted connections inherit this: without it, a response written in two parts waits
    # for the client's delayed ACK (40 ms per request on Linux).
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    sock.bind((host, port))
    sock.listen(2048)
    return sock


M_ARENA_MAX = -8  # glibc <malloc.h>


def limit_malloc_arenas(arenas: int = 2) -> bool:
    """Cap glibc's malloc arenas (as ``MALLOC_ARENA_MAX`` would) unless the environment sets
    it. By default every thread of the request pool gets its own arena, and the server's RSS
    crept up by 20 % over 5 minutes at 10 robots before levelling off; with 2 arenas it grew
    by 4.5 % and stayed flat after the first minute (docs/reliability.md). Returns whether
    the cap was applied."""
    if "MALLOC_ARENA_MAX" in os.environ:
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        return bool(libc.mallopt(M_ARENA_MAX, arenas))
    except (OSError, AttributeError):  # not glibc
        return False


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from server.app import create_app

    limit_malloc_arenas()
    try:
        settings = settings_from(args)
        app = create_app(settings)
    except ValueError as exc:  # a setting that does not parse or does not exist
        print(f"teachrepeat serve: {exc}", file=sys.stderr, flush=True)
        return 2
    sock = bind_port(settings.host, settings.port)
    port = sock.getsockname()[1]
    base = f"http://{settings.host}:{port}"
    print(f"teachrepeat API  {base}", flush=True)
    print(f"API docs         {base}/docs", flush=True)
    print(f"database         {settings.db}", flush=True)
    if token_file(settings).exists():
        print(f"admin token in   {token_file(settings)}", flush=True)
    dashboard = None
    if settings.dashboard_port is not None:
        from web.dashboard import Dashboard

        dashboard = Dashboard(app.state.services, host=settings.host, port=settings.dashboard_port)
        used = dashboard.start()
        print(f"dashboard        http://{settings.host}:{used}", flush=True)
    config = uvicorn.Config(app, log_level="warning", access_log=False)
    # what exists now (modules, the app, ~90 000 objects) lives as long as the process: keep
    # it out of the collector, whose full passes over it stalled a step by ~35 ms now and then
    gc.collect()
    gc.freeze()
    try:
        uvicorn.Server(config).run(sockets=[sock])
    finally:
        if dashboard is not None:
            dashboard.stop()
    return 0
