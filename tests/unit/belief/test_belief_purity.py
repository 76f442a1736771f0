"""Structural test: the belief tracker and the policy are pure (001 core, STYLE principle 1)."""

from __future__ import annotations

import subprocess
import sys

FORBIDDEN = ("fastapi", "sqlite_utils", "viser", "pydantic", "uvicorn", "httpx", "cv2", "mujoco")


def test_belief_and_policy_import_only_the_pure_core() -> None:
    code = (
        "import sys\n"
        "import server.belief, server.belief.model, server.belief.tracker, server.belief.smoother\n"
        "import server.belief.questions\n"
        "import server.policy, server.policy.costs, server.policy.voting\n"
        f"bad = sorted(m for m in sys.modules if m.split('.')[0] in {FORBIDDEN!r})\n"
        "assert not bad, bad\n"
        "ours = sorted(m for m in sys.modules if m.startswith('server.'))\n"
        "allowed = ('server.belief', 'server.policy', 'server.domain')\n"
        "assert all(m.startswith(allowed) for m in ours), ours\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
