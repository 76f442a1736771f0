"""The ``teachrepeat`` command: ``serve``, ``cert``, ``robot ...``, ``demo`` and ``bench ...``.

Each sub-command lives in its own module with ``add_arguments(parser)`` and ``run(args) -> int``;
this file only wires them together. Command modules keep heavy imports (OpenCV, MuJoCo, the
server) inside ``run`` so that building the parser stays cheap.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import signal
import sys
import threading
from collections.abc import Sequence

from server.threads import pin_environment

# one thread for BLAS and OpenCV, before NumPy or OpenCV are imported (server/threads.py)
pin_environment()

# (command path, module, help). The module provides add_arguments(parser) and run(args) -> int.
COMMANDS: tuple[tuple[tuple[str, ...], str, str], ...] = (
    (("serve",), "server.serve", "run the API server (and the dashboard)"),
    (
        ("household",),
        "server.households_cli",
        "create households, set their login passwords, list them",
    ),
    (("cert",), "server.cert", "make a self-signed TLS certificate and key for a home server"),
    (
        ("replay",),
        "server.recording.cli",
        "a recorded navigation task through the server's step again: what differs now",
    ),
    (
        ("robot", "run"),
        "robot_client.agent",
        "the robot agent: stream frames, obey the server's commands (idle, teaching, navigating)",
    ),
    (("robot", "teach"), "robot_client.teach", "replay a folder of images as a teaching tour"),
    (("demo",), "robot_client.demo", "the simulated home, taught and navigated end to end"),
    (
        ("sim", "check-plan"),
        "robot_client.sim.check_plan",
        "check a floor plan of a simulated home, print its teaching route, draw it",
    ),
    (
        ("sim", "generate"),
        "robot_client.sim.generate",
        "a random home from a seed: a floor plan that passes check-plan",
    ),
    (
        ("sim", "ros2-robot"),
        "robot_client.sim.ros2_robot",
        "the simulated robot as a ROS 2 robot on DDS: camera, odometry, scan, cmd_vel",
    ),
    (("bench", "retrieval"), "server.bench.retrieval", "image retrieval on real images vs OpenCV"),
    (("bench", "localize"), "server.bench.localize", "sequence localisation on real routes"),
    (
        ("bench", "features"),
        "server.bench.features",
        "local feature options compared: extraction time, retrieval, localisation, simulator",
    ),
    (
        ("bench", "navigate"),
        "server.bench.navigate",
        "closed-loop navigation in the simulated home",
    ),
    (
        ("bench", "sim-retrieval"),
        "server.bench.sim_retrieval",
        "image matching in the simulated home under changed light and furniture",
    ),
    (
        ("bench", "dock-views"),
        "server.bench.dock_views",
        "docking's scale fit on single views off the taught spot in the simulated homes",
    ),
    (
        ("bench", "carried"),
        "server.bench.carried",
        "a robot carried off a place of a three-place tour, sent to another (the fault test's)",
    ),
    (("bench", "load"), "server.bench.load", "many robots at once against one server"),
    (("bench", "upload"), "server.bench.upload", "teaching upload rate of the robot client"),
    (
        ("bench", "teleop"),
        "server.bench.teleop",
        "driving by hand: command-to-wheel latency, and the stop when the server disappears",
    ),
    (
        ("bench", "questions"),
        "server.bench.questions",
        "questions while teaching in the simulated homes: asked where, revisits closed",
    ),
    (("bench", "dashboard"), "web.bench", "robot step latency with and without a browser"),
)


EXTRA_OF = {"mujoco": "sim", "skimage": "sim", "PIL": "sim", "cyclonedds": "ros2", "gpiozero": "pi"}
"""Top-level module -> the extra of ``pyproject.toml`` that installs it (others: ``server``)."""


def _available(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError as exc:  # its package is there, a dependency of the package not
        return _missing_dependency(exc) is not None


def _missing_dependency(exc: ModuleNotFoundError) -> str | None:
    """The third-party module a command's import lacked, or ``None`` when the project's own
    code is missing (a real bug: let it raise)."""
    top = (exc.name or "").split(".")[0]
    return None if top in ("", "server", "robot_client", "web") else top


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser; commands whose module is not installed are left out."""
    parser = argparse.ArgumentParser(
        prog="teachrepeat",
        description="Teach a camera-only robot a home in one guided tour, then send it anywhere.",
    )
    top = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    groups: dict[str, argparse._SubParsersAction[argparse.ArgumentParser]] = {}
    for path, module, help_text in COMMANDS:
        if not _available(module):
            continue
        parent = top
        if len(path) == 2:
            group = path[0]
            if group not in groups:
                gp = top.add_parser(group, help=f"{group} commands")
                groups[group] = gp.add_subparsers(dest="subcommand", required=True, metavar="SUB")
            parent = groups[group]
        sub = parent.add_parser(path[-1], help=help_text, description=help_text)
        try:
            importlib.import_module(module).add_arguments(sub)
        except ModuleNotFoundError as exc:  # a slim install (the robot's) lacks its extra
            missing = _missing_dependency(exc)
            if missing is None:
                raise
            sub.add_argument("rest", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
            sub.set_defaults(_module=module, _parser=sub, _missing=missing)
            continue
        sub.set_defaults(_module=module, _parser=sub)
    return parser


def _refuse_missing(args: argparse.Namespace) -> int:
    """Say which extra a command needs on an install without it; exit status 2."""
    extra = EXTRA_OF.get(args._missing, "server")
    print(
        f"{args._parser.prog}: this install lacks {args._missing}, which the command needs: "
        f"pip install 'teachrepeat[{extra}]' (or [server,sim] for demo and the benchmarks; "
        "docs/robot.md, 'Install on the robot')",
        file=sys.stderr,
    )
    return 2


def _exit_on_sigterm(signum: int, frame: object) -> None:
    """SIGTERM ends a command like Ctrl-C does: as an exception, so that its ``with`` blocks
    (a benchmark's scratch server, a simulator) clean up instead of leaving children behind."""
    raise SystemExit(128 + signum)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``teachrepeat`` console script."""
    from server.threads import pin_threads

    args, unknown = build_parser().parse_known_args(argv)
    if getattr(args, "_missing", None):
        return _refuse_missing(args)
    if unknown:  # the sub-command's usage, not the top level's, says what it takes
        args._parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    # ``serve`` leaves SIGTERM to uvicorn, which shuts down gracefully and re-raises it
    in_main = threading.current_thread() is threading.main_thread()
    handle = in_main and args._module != "server.serve"
    previous = signal.signal(signal.SIGTERM, _exit_on_sigterm) if handle else None
    try:
        module = importlib.import_module(args._module)
        pin_threads()  # the libraries the command loaded too
        return int(module.run(args) or 0)
    finally:
        if handle:
            signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)


if __name__ == "__main__":
    sys.exit(main())
