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

CORRIDOR_MARKS_FILE = Path(__file__).with_name("corridor_marks.csv")
#: The ``--descriptor`` options of the benchmarks: ``server.vision.features.DESCRIPTOR_KINDS``,
#: written out so that building the CLI parser does not import OpenCV (a test keeps them equal).
DESCRIPTOR_CHOICES: tuple[str, ...] = (
    "grad36",
    "orb",
    "orb_fast",
    "sift",
    "akaze",
    "akaze_upright",
    "brisk",
    "teblid",
)


def corridor_marks() -> dict[int, str]:
    """The places of the real corridor tour the benchmarks teach: frame index -> name, from
    ``corridor_marks.csv`` (names are data, not code)."""
    from robot_client.teach import read_marks

    return read_marks(CORRIDOR_MARKS_FILE)


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


def wilson_interval(successes: int, trials: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval of a success rate (95 % for the default ``z``); ``(nan, nan)``
    for no trials. Unlike the normal approximation it stays inside [0, 1] and is not empty at
    0 or N successes: 50 of 50 gives [0.929, 1]."""
    if trials <= 0:
        return float("nan"), float("nan")
    p = successes / trials
    z2 = z * z
    denom = 1.0 + z2 / trials
    centre = (p + z2 / (2 * trials)) / denom
    half = z * float(np.sqrt(p * (1 - p) / trials + z2 / (4 * trials * trials))) / denom
    lo = 0.0 if successes == 0 else max(0.0, centre - half)
    hi = 1.0 if successes == trials else min(1.0, centre + half)
    return lo, hi
