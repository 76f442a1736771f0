"""``teachrepeat serve``: run the API (and, when installed, the dashboard).

The dashboard is served three ways (docs/security.md, Dashboard login):

* on a loopback host, by default: the gate without a login, every household's robots, only
  to pages asked for as localhost/127.0.0.1 from the same origin;
* off loopback (or with ``dashboard_login`` on): the login gate (:mod:`web.gate`) on the
  dashboard port, each household seeing only its own; ``serve`` refuses to start while no
  household has a password, saying how to set one;
* with a TLS certificate, always through the gate's uvicorn server, so HTTPS covers it too.
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import os
import socket
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from pydantic import SecretStr

from server.config import Settings
from server.errors import Unavailable
from server.security import new_token
from server.tls import SslOptions, ssl_options

if TYPE_CHECKING:
    from server.services.container import Services
    from web.gate import Gate


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--db", type=Path, help="SQLite file (default: data/teachrepeat.sqlite)")
    parser.add_argument(
        "--database-url",
        metavar="URL",
        help="postgresql://USER:PASSWORD@HOST:PORT/NAME: a PostgreSQL server shared by several "
        "processes or machines instead of the SQLite file --db (docs/scale.md). Other users "
        "can read a command line: prefer TEACHREPEAT_DATABASE_URL for the password",
    )
    parser.add_argument("--host", help="interface to bind (default 127.0.0.1)")
    parser.add_argument("--port", type=int, help="API port (default 8000; 0 = any free port)")
    parser.add_argument(
        "--dashboard-port",
        type=int,
        help="dashboard port (default 8080; 0 = any free port; -1 = no dashboard)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="run N server processes behind HAProxy on --host/--port, each robot always "
        "on the same one, a process that dies started again (docs/scale.md; needs the "
        "haproxy package). Default 0: this process serves alone",
    )
    parser.add_argument(
        "--tls-cert",
        type=Path,
        metavar="FILE",
        help="serve the API over HTTPS with this PEM certificate (`teachrepeat cert` makes one)",
    )
    parser.add_argument("--tls-key", type=Path, metavar="FILE", help="the certificate's PEM key")
    parser.add_argument(
        "--record",
        type=Path,
        metavar="DIR",
        help="record every teaching tour and navigation task to an MCAP file in DIR (one "
        "folder per household; docs/recording.md). Without it a task is recorded when it asks "
        "(record: true), into `recordings` beside the database",
    )
    parser.add_argument(
        "--dashboard-login",
        choices=("on", "off"),
        help="ask for a household login on the dashboard (default: on unless the host is "
        "loopback; off is refused off loopback)",
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
        k: getattr(args, k)
        for k in ("db", "database_url", "host", "port", "tls_cert", "tls_key", "workers")
        if getattr(args, k, None) is not None
    }
    dashboard_port = getattr(args, "dashboard_port", None)
    if dashboard_port is not None:
        overrides["dashboard_port"] = None if dashboard_port < 0 else dashboard_port
    record = getattr(args, "record", None)
    if record is not None:
        overrides.update(record=True, record_dir=record)
    dashboard_login = getattr(args, "dashboard_login", None)
    if dashboard_login is not None:
        overrides["dashboard_login"] = dashboard_login == "on"
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


M_TRIM_THRESHOLD = -1  # glibc <malloc.h>
M_MMAP_THRESHOLD = -3
M_ARENA_MAX = -8


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


def keep_freed_memory(mmap_threshold: int = 32 << 20, trim_threshold: int = 256 << 20) -> bool:
    """Let glibc's malloc keep the memory a frame's step frees for the next frame (as
    ``MALLOC_MMAP_THRESHOLD_`` and ``MALLOC_TRIM_THRESHOLD_`` would) unless the environment
    sets either: blocks up to ``mmap_threshold`` bytes come from the heap, and the heap gives
    memory back to the system only when more than ``trim_threshold`` bytes lie free at its top.

    A step allocates and frees buffers of 0.1-2 MB many times (the working image and its
    grey copy, the gradients and the Harris response of every corner extraction, the
    descriptor distances). By default each larger than 128 kB was a fresh ``mmap`` and each
    freed one went back to the system, so every frame faulted its pages in again; on this
    project's 2-core VM a page fault is dear: the Harris response of a 320x240 frame took
    1.18 ms of CPU that way and 0.27 ms with the memory kept (docs/reliability.md,
    "2026-11-28"). Returns whether the settings were applied."""
    if "MALLOC_MMAP_THRESHOLD_" in os.environ or "MALLOC_TRIM_THRESHOLD_" in os.environ:
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        return bool(
            libc.mallopt(M_MMAP_THRESHOLD, mmap_threshold)
            and libc.mallopt(M_TRIM_THRESHOLD, trim_threshold)
        )
    except (OSError, AttributeError):  # not glibc
        return False


def no_login_message(settings: Settings) -> str:
    """What ``serve`` says when the dashboard needs a login that nobody has."""
    return (
        f"teachrepeat serve: the dashboard on {settings.host} asks for a household login, and "
        "no household has a password yet. Set one first: `teachrepeat household password "
        "default` (the household that owns everything made before households existed), or "
        "`teachrepeat household create NAME` (both read the password from stdin), with the "
        "same --db; then start serve again. Or serve without the dashboard (--dashboard-port "
        "-1), or on 127.0.0.1"
    )


def start_dashboard(settings: Settings, services: Services, tls: SslOptions) -> Gate | None:
    """Start the dashboard as the settings ask and print its address; the running gate (its
    ``port``, ``stop()``), or None when the dashboard is off. Always the gate
    (:mod:`web.gate`): with a login off loopback (or when asked), else without one but
    answering only to loopback names and
    same-origin pages (viser itself checks neither: any web site the user visits could open
    its WebSocket). Raises OSError when the gate's port is taken."""
    if settings.dashboard_port is None:
        return None
    login = settings.dashboard_needs_login()
    from web.gate import Gate

    gate = Gate(services, login=login, secure=bool(tls), limits=settings.rate_limits())
    used = gate.start(settings.host, settings.dashboard_port, ssl=tls)
    print(f"dashboard        {'https' if tls else 'http'}://{settings.host}:{used}", flush=True)
    if login:
        print("dashboard login  a household's name and password", flush=True)
    return gate


def run_launcher(settings: Settings, args: argparse.Namespace) -> int:
    """``serve --workers N``: the processes behind HAProxy (:mod:`server.cluster`), or exit 2
    saying why they cannot run with these settings."""
    from server.cluster import cluster_refusal, run_cluster

    dashboard_port = getattr(args, "dashboard_port", None)
    refusal = cluster_refusal(
        settings, dashboard_asked=dashboard_port is not None and dashboard_port >= 0
    )
    if refusal is not None:
        print(f"teachrepeat serve: {refusal}", file=sys.stderr, flush=True)
        return 2
    return run_cluster(settings)


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from server.app import create_app

    limit_malloc_arenas()
    keep_freed_memory()
    try:
        settings = settings_from(args)
        if settings.workers > 0:
            return run_launcher(settings, args)
        tls = ssl_options(settings)
        login = settings.dashboard_port is not None and settings.dashboard_needs_login()
        app = create_app(settings)
    except ValueError as exc:  # a setting that does not parse or does not exist, a bad TLS file
        print(f"teachrepeat serve: {exc}", file=sys.stderr, flush=True)
        return 2
    except Unavailable as exc:  # the PostgreSQL server cannot be reached (URL masked)
        print(f"teachrepeat serve: {exc.message}", file=sys.stderr, flush=True)
        return 2
    services: Services = app.state.services
    if login and not services.repo.any_login():
        services.close()
        print(no_login_message(settings), file=sys.stderr, flush=True)
        return 2
    sock = bind_port(settings.host, settings.port)
    port = sock.getsockname()[1]
    base = f"{'https' if tls else 'http'}://{settings.host}:{port}"
    print(f"teachrepeat API  {base}", flush=True)
    print(f"API docs         {base}/docs", flush=True)
    print(f"database         {settings.database_shown()}", flush=True)
    if settings.record:
        print(f"recording to     {settings.recordings_dir()}", flush=True)
    if token_file(settings).exists():
        print(f"admin token in   {token_file(settings)}", flush=True)
    try:
        dashboard = start_dashboard(settings, services, tls)
        if dashboard is not None:  # GET / tells where it is: the port it really got
            app.state.settings = settings.model_copy(update={"dashboard_port": dashboard.port})
    except OSError as exc:  # the gate's port (viser moves to the next free one by itself)
        sock.close()
        services.close()
        print(
            f"teachrepeat serve: cannot listen on dashboard port {settings.dashboard_port} "
            f"({exc.strerror}); choose another with --dashboard-port (0 = any free port)",
            file=sys.stderr,
            flush=True,
        )
        return 2
    config = uvicorn.Config(app, log_level="warning", access_log=False, **tls)
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
