"""A rule about the code itself: server/vision imports NumPy, OpenCV and the stdlib only."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

VISION = Path(__file__).resolve().parents[3] / "server" / "vision"
ALLOWED = {"numpy", "cv2", "server"}


def test_vision_imports_only_numpy_opencv_and_stdlib() -> None:
    files = sorted(VISION.glob("*.py"))
    assert files
    for path in files:
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            names: list[str] = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            for name in names:
                top = name.split(".")[0]
                ok = top in ALLOWED or top in sys.stdlib_module_names or name == "__future__"
                assert ok, f"{path.name} imports {name}; server/vision must stay pure"
                if top == "server":
                    assert name.startswith("server.vision"), f"{path.name} imports {name}"
