"""The robot's install is the client only: the robot side imports nothing of the server's, the
simulator's or a driver's hardware, and ``pyproject.toml`` declares exactly that.

The robot side is every module of ``robot_client/`` but the simulation and benchmark ones
(:data:`SIM_SIDE`), plus the server modules the client shares (:data:`SHARED`). New modules
are robot side unless listed: the robot agent (``robot_client/agent.py``, written on another
branch) is covered by the walk as soon as it lands, and so is its ``robot run`` command.
"""

from __future__ import annotations

import ast
import importlib.metadata
import json
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())

SIM_SIDE = (
    "robot_client.sim",
    "robot_client.demo",
    "robot_client.guide",
    "robot_client.trial",
    "robot_client.judge_localisation",
    "robot_client.tour_recording",
)
"""robot_client modules that simulate a robot or judge one: the ``sim`` and ``server`` extras."""

SHARED = ("server.cli", "server.threads", "server.schemas", "server.imaging", "server.errors")
"""Server modules the robot side imports: the command line, the wire schemas, JPEG checks."""

PLAN_DATA = ("robot_client.sim.floorplan",)
"""Simulator modules a robot may import all the same: a floor plan's data (the standard library
only), which the ``sim`` driver's options name (its conditions); ``robot_client.sim`` imports
its heavy parts on first use."""

HARDWARE = {"robot_client.drivers.ros2_dds": "ros2"}
"""Robot-side modules that import a driver's hardware library at import time; only a
driver's ``open_robot`` imports them (extra they need)."""

SERVER_ONLY = ("fastapi", "uvicorn", "viser", "scipy", "sqlite_utils", "psycopg", "mujoco")
SERVER_ONLY += ("skimage", "starlette", "networkx", "pydantic_settings", "argon2", "mcap")
"""Import names a robot must never load (the brief's list and what the server brings)."""


def dist(requirement: str) -> str:
    """``"psycopg[binary]>=3.1"`` -> ``"psycopg"`` (normalised)."""
    name = re.split(r"[\s\[<>=;!~]", requirement.strip(), maxsplit=1)[0]
    return re.sub(r"[-_.]+", "-", name).lower()


CORE = {dist(r) for r in PYPROJECT["project"]["dependencies"]}
EXTRAS = {
    extra: {dist(r) for r in reqs}
    for extra, reqs in PYPROJECT["project"]["optional-dependencies"].items()
}


def robot_side() -> list[str]:
    modules = []
    for path in sorted((ROOT / "robot_client").rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        if not name.startswith(SIM_SIDE) and name not in HARDWARE:
            modules.append(name)
    return [*modules, *SHARED]


def module_path(name: str) -> Path:
    base = ROOT.joinpath(*name.split("."))
    return base / "__init__.py" if base.is_dir() else base.with_suffix(".py")


def third_party_imports(path: Path) -> tuple[set[str], set[str]]:
    """Top-level names a module imports: ``(at import time, inside functions)``."""
    tree = ast.parse(path.read_text())
    eager: set[str] = set()
    lazy: set[str] = set()

    def visit(node: ast.AST, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            inner = in_function or isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef)
            names: list[str] = []
            if isinstance(child, ast.Import):
                names = [a.name for a in child.names]
            elif isinstance(child, ast.ImportFrom) and child.module and child.level == 0:
                names = [child.module]
            for name in names:
                top = name.split(".")[0]
                if top in sys.stdlib_module_names or top in ("server", "robot_client", "web"):
                    continue
                (lazy if inner else eager).add(top)
            if isinstance(child, ast.If) and _is_type_checking(child.test):
                continue
            visit(child, inner)

    visit(tree, False)
    return eager, lazy


def _is_type_checking(test: ast.expr) -> bool:
    return isinstance(test, ast.Name) and test.id == "TYPE_CHECKING"


def distributions(top: str) -> set[str]:
    return {dist(d) for d in importlib.metadata.packages_distributions().get(top, [])}


def test_the_core_dependencies_hold_nothing_the_server_or_the_simulator_needs() -> None:
    assert not CORE & (EXTRAS["server"] | EXTRAS["sim"]), CORE & (EXTRAS["server"] | EXTRAS["sim"])
    assert {"numpy", "opencv-contrib-python-headless", "pydantic", "httpx", "tqdm"} == CORE
    for name in ("fastapi", "uvicorn", "viser", "scipy", "sqlite-utils", "psycopg", "mujoco"):
        assert name not in CORE
    assert "scikit-image" not in CORE and {"cyclonedds", "gpiozero"}.isdisjoint(CORE)
    assert EXTRAS["ros2"] == {"cyclonedds"} and EXTRAS["pi"] == {"gpiozero"}
    assert "teachrepeat" in EXTRAS["dev"]  # dev: every extra (self-reference) + test tools


@pytest.mark.parametrize("module", [*robot_side(), *HARDWARE])
def test_every_import_of_the_robot_side_is_declared_where_it_belongs(module: str) -> None:
    eager, lazy = third_party_imports(module_path(module))
    allowed_eager = CORE | EXTRAS[HARDWARE[module]] if module in HARDWARE else CORE
    for top in eager:
        assert distributions(top) & allowed_eager, (
            f"{module} imports {top} at import time, which {sorted(allowed_eager)} do not "
            "install: add it to [project.dependencies] or import it where it is used"
        )
    optional = set().union(*(EXTRAS[e] for e in ("ros2", "pi")))
    for top in lazy:
        assert distributions(top) & (CORE | optional), f"{module} imports {top}, undeclared"


SCRIPT = """
import importlib, importlib.abc, io, json, sys, contextlib
blocked = set(json.loads(sys.argv[1]))
class Slim(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in blocked:
            raise ModuleNotFoundError(f"No module named {name!r} (not on a robot)", name=name)
        return None
sys.meta_path.insert(0, Slim())
for module in json.loads(sys.argv[2]):
    importlib.import_module(module)
from robot_client.drivers import DRIVERS
import argparse
parser = argparse.ArgumentParser()
for name, module in DRIVERS.items():
    importlib.import_module(module).add_arguments(parser)
from server.cli import main
codes = {}
for argv in json.loads(sys.argv[3]):
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        try:
            codes[" ".join(argv)] = [main(argv), err.getvalue()]
        except SystemExit as exc:
            codes[" ".join(argv)] = [exc.code, err.getvalue()]
print(json.dumps({"modules": sorted(sys.modules), "codes": codes}))
"""


def run_robot_side(blocked: set[str], commands: list[list[str]]) -> dict[str, object]:
    result = subprocess.run(
        [
            sys.executable,
            "-c",
            SCRIPT,
            json.dumps(sorted(blocked)),
            json.dumps([*robot_side(), *PLAN_DATA]),
            json.dumps(commands),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    out: dict[str, object] = json.loads(result.stdout.splitlines()[-1])
    return out


def import_names(extras: tuple[str, ...]) -> set[str]:
    """Top-level import names of every distribution the ``extras`` install."""
    wanted = set().union(*(EXTRAS[e] for e in extras))
    return {
        top
        for top, dists in importlib.metadata.packages_distributions().items()
        if {dist(d) for d in dists} & wanted
    }


def robot_commands() -> list[list[str]]:
    from server.cli import COMMANDS

    return [[*path, "--help"] for path, module, _ in COMMANDS if module in robot_side()]


def test_the_robot_side_loads_no_server_module_where_everything_is_installed() -> None:
    """Everything installed (as here): importing the robot side still loads none of it."""
    out = run_robot_side(set(), [])
    loaded = {m.split(".")[0] for m in out["modules"]}  # type: ignore[attr-defined]
    assert not loaded & set(SERVER_ONLY), loaded & set(SERVER_ONLY)
    assert not loaded & {"cyclonedds", "gpiozero"}  # the drivers' libraries wait for open_robot


def test_on_a_slim_install_the_robot_side_imports_and_server_commands_say_what_to_install() -> None:
    """The server's, the simulator's and the drivers' libraries made unimportable, as on a
    robot that installed ``teachrepeat`` alone: the robot side imports, every driver lists its
    options, the robot's commands give their help, ``serve`` says which extra it needs."""
    blocked = import_names(("server", "sim", "ros2", "pi")) | set(SERVER_ONLY)
    assert not blocked & {"numpy", "cv2", "pydantic", "httpx", "tqdm"}
    commands = robot_commands()
    assert ["robot", "teach", "--help"] in commands
    out = run_robot_side(blocked, [*commands, ["serve"], ["sim", "ros2-robot"]])
    codes: dict[str, list[object]] = out["codes"]  # type: ignore[assignment]
    for command in commands:
        assert codes[" ".join(command)][0] == 0, codes[" ".join(command)]
    code, err = codes["serve"]
    assert code == 2 and "this install lacks" in str(err)
    assert "pip install 'teachrepeat[server]'" in str(err)
    code, err = codes["sim ros2-robot"]
    assert code == 2 and "pip install 'teachrepeat[" in str(err)
