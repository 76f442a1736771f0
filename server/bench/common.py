"""What every benchmark shares: percentiles, the data folder, printing and saving JSON."""

from __future__ import annotations

import json
import os
import platform
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np


def default_data_dir() -> Path:
    """``TEACHREPEAT_DATA`` or ``../shared/data`` relative to the working directory."""
    return Path(os.environ.get("TEACHREPEAT_DATA", Path("..") / "shared" / "data"))


def stats(values: Sequence[float]) -> dict[str, float]:
    """``{"p50", "p95", "p99", "mean", "n"}`` of ``values`` (empty -> NaNs)."""
    a = np.asarray(values, dtype=np.float64)
    if a.size == 0:
        return {
            "p50": float("nan"),
            "p95": float("nan"),
            "p99": float("nan"),
            "mean": float("nan"),
            "n": 0,
        }
    p50, p95, p99 = np.percentile(a, [50, 95, 99])
    return {
        "p50": float(p50),
        "p95": float(p95),
        "p99": float(p99),
        "mean": float(a.mean()),
        "n": int(a.size),
    }


def machine() -> dict[str, Any]:
    return {
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "date": time.strftime("%Y-%m-%d %H:%M:%S"),
    }


def write_json(path: Path | None, result: dict[str, Any]) -> None:
    """Save ``result`` (with the machine it ran on) to ``path``, creating its folder."""
    if path is None:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({**result, "machine": machine()}, indent=2, sort_keys=True) + "\n")
    print(f"saved {path}")
