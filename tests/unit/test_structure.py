"""Rules about the code itself: the pure core stays pure, the wire schemas stay light."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

# The core: similarity engine, belief tracker, policy and the graph they share.
PURE = [
    "server/domain.py",
    "server/vision",
    "server/belief",
    "server/policy",
    "server/motion.py",
    "server/navigation",
]
PURE_ALLOWED = {"numpy", "cv2", "scipy", "networkx", "server"}
PURE_ALLOWED_SERVER = (
    "server.domain",
    "server.vision",
    "server.belief",
    "server.policy",
    "server.motion",
    "server.navigation",
)
FORBIDDEN_ANYWHERE_IN_CORE = {
    "fastapi",
    "sqlite_utils",
    "sqlite3",
    "viser",
    "starlette",
    "pydantic",
    "httpx",
    "uvicorn",
    "mujoco",
    "robot_client",
    "web",
}


def imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def python_files(spec: str) -> list[Path]:
    target = ROOT / spec
    return [target] if target.is_file() else sorted(target.rglob("*.py"))


def stdlib(name: str) -> bool:
    import sys

    return name.split(".")[0] in sys.stdlib_module_names or name == "__future__"


@pytest.mark.parametrize("spec", PURE)
def test_core_imports_only_numpy_opencv_scipy_networkx(spec: str) -> None:
    files = python_files(spec)
    if not files:
        pytest.skip(f"{spec} not written yet")
    for path in files:
        for name in imports(path):
            top = name.split(".")[0]
            assert top not in FORBIDDEN_ANYWHERE_IN_CORE, f"{path.relative_to(ROOT)} imports {name}"
            if stdlib(name):
                continue
            assert top in PURE_ALLOWED, f"{path.relative_to(ROOT)} imports {name}"
            if top == "server":
                assert name.startswith(PURE_ALLOWED_SERVER), f"{path} imports {name}"


def test_wire_schemas_import_pydantic_only() -> None:
    for name in imports(ROOT / "server" / "schemas.py"):
        assert stdlib(name) or name.split(".")[0] == "pydantic", name


def test_routes_hold_no_sql() -> None:
    for path in python_files("server/api"):
        text = path.read_text()
        for word in ("SELECT ", "INSERT ", "UPDATE ", "DELETE ", "sqlite"):
            assert word not in text, f"{path.relative_to(ROOT)} contains {word!r}"


DRIVERS = {"sqlite3", "sqlite_utils", "psycopg"}
SQLITE_FILE_COPIERS = {"server/recording/replay.py", "server/bench/nav_sweep.py"}
"""They copy SQLite files as files (a recording's replay, a benchmark's tour cache)."""


def test_only_storage_talks_to_the_database_driver() -> None:
    """SQLite and PostgreSQL sit behind server/storage (docs/scale.md): services see
    ``IntegrityViolation``, never a driver's exception."""
    for package in ("server", "robot_client", "web"):
        for path in python_files(package):
            where = str(path.relative_to(ROOT))
            if where.startswith("server/storage/") or where in SQLITE_FILE_COPIERS:
                continue
            used = {n.split(".")[0] for n in imports(path)} & DRIVERS
            assert not used, f"{where} imports {used}"


def test_no_machine_paths_in_code() -> None:
    for package in ("server", "robot_client", "web"):
        for path in python_files(package):
            for bad in ("'/work/", '"/work/', "'/tmp/", '"/tmp/', "'/root/", '"/root/'):
                assert bad not in path.read_text(), f"{path.relative_to(ROOT)} holds {bad}"


def test_no_place_name_is_written_into_the_code() -> None:
    """Homes are data: the places of the shipped plans (and of the corridor tour the benchmarks
    teach) are named in their data files only, never as a string in the code."""
    import json

    from server.bench.common import corridor_marks

    names = set(corridor_marks().values())
    for plan in sorted((ROOT / "robot_client" / "sim").glob("*.json")):
        names |= {p["name"] for p in json.loads(plan.read_text())["places"]}
    found = []
    for spec in ("server", "robot_client", "web"):
        for path in python_files(spec):
            for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
                if isinstance(node, ast.Constant) and node.value in names:
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno}: {node.value!r}")
    assert not found, "place names in code (put them in a plan or marks file):\n" + "\n".join(found)


NAVIGATION_MAX_COMPLEXITY = 15
"""No function of the navigation package may be more tangled than this (radon's cyclomatic
complexity): RobotSession._place_dock reached 36 before the package existed."""


def test_navigation_functions_stay_simple_and_the_session_thin() -> None:
    from radon.complexity import cc_visit

    tangled = []
    for path in python_files("server/navigation"):
        for block in cc_visit(path.read_text()):
            if block.complexity > NAVIGATION_MAX_COMPLEXITY:
                tangled.append(
                    f"{path.relative_to(ROOT)}:{block.lineno} {block.name} ({block.complexity})"
                )
    assert not tangled, "split these functions:\n" + "\n".join(tangled)
    lines = len((ROOT / "server" / "session.py").read_text().splitlines())
    assert lines < 300, (
        f"server/session.py has {lines} lines: navigation belongs in server/navigation"
    )
