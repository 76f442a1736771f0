"""``teachrepeat bench dock-views``: what docking's scale fit reads off the taught spot.

For each simulated home, each place and ``--headings`` headings around it, the view taught at
the place is compared with views rendered ``--offsets`` metres along the heading (negative:
behind the spot, the taught view looks larger: docking should read "short"; positive: past
it, "past"; 0: on it, "there"). Two ways of reading the scale, on the same frames:

* ``frame``: :func:`server.vision.homing.homing_scale_zoomed` over the frame's four zooms (what
  docking's creeping and verdicts read, and with ``NavigationParams.dock_taught_zooms``
  ``"off"`` its looking for a view too);
* ``taught``: :func:`server.vision.homing.homing_scale_taught_zoomed` over the taught image's
  four zooms (what ``dock_taught_zooms`` ``"look"``, the default, reads while looking for a
  view; it acts on the inliers, not on the verdict).

Per offset: views, mean inliers, the share with at least ``dock_min_inliers`` (docking acts on
them) and the share whose verdict (``scale_verdict`` with ``dock_scale_tol``) is right.
Single views, no closed loop: ``bench navigate`` is the judge of docking.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

import numpy as np

from server.bench.common import write_json

METHODS = ("frame", "taught")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--plan", type=Path, nargs="+", default=None, help="floor plans (default: apartment)"
    )
    parser.add_argument(
        "--headings", type=int, default=8, help="headings per place, evenly spaced (default 8)"
    )
    parser.add_argument(
        "--offsets",
        type=float,
        nargs="+",
        default=[-0.8, -0.4, 0.0, 0.4],
        help="metres along the heading from the spot (default -0.8 -0.4 0 0.4)",
    )
    parser.add_argument("--json", type=Path, default=None, help="write the results here")


def verdict(scale: float, tol: float) -> int:
    """+1 short (the taught view looks larger), -1 past, 0 there: docking's reading of one
    fit (:func:`server.navigation.docking.scale_verdict` on a single fit)."""
    log_scale = math.log(scale)
    return 1 if log_scale > math.log1p(tol) else -1 if log_scale < math.log1p(-tol) else 0


def summary(rows: list[dict[str, Any]], offsets: list[float], min_inliers: int) -> dict[str, Any]:
    """Per offset and method: views, mean inliers, share acted on, share right."""
    out: dict[str, Any] = {}
    for d in offsets:
        mine = [r for r in rows if r["offset_m"] == d]
        truth = 1 if d < 0 else -1 if d > 0 else 0
        cell: dict[str, Any] = {"views": len(mine)}
        for m in METHODS:
            inl = np.array([r[m]["inliers"] for r in mine], float)
            acted = inl >= min_inliers
            right = [r[m]["verdict"] == truth and r[m]["inliers"] >= min_inliers for r in mine]
            cell[m] = {
                "mean_inliers": float(inl.mean()) if len(mine) else float("nan"),
                "acted_share": float(acted.mean()) if len(mine) else float("nan"),
                "right_share": float(np.mean(right)) if len(mine) else float("nan"),
            }
        out[f"{d:+.2f}"] = cell
    return out


def run(args: argparse.Namespace) -> int:
    from robot_client.sim.floorplan import load_plan
    from robot_client.sim.world import Pose, SimWorld
    from server.navigation import NavigationParams
    from server.vision.features import extract
    from server.vision.homing import (
        homing_scale_taught_zoomed,
        homing_scale_zoomed,
        taught_zoom_levels,
        zoom_levels,
    )

    p = NavigationParams()
    fp, zooms = p.features, p.dock_zooms
    plans = args.plan or [Path(__file__).resolve().parents[2] / "robot_client/sim/apartment.json"]
    rows: list[dict[str, Any]] = []
    for plan_path in plans:
        plan = load_plan(plan_path)
        with SimWorld(plan) as world:
            for place in plan.places:
                for k in range(args.headings):
                    th = place.yaw + 2 * math.pi * k / args.headings
                    taught = world.render(Pose(place.x, place.y, th))
                    tf = extract(taught, fp)
                    levels = taught_zoom_levels(taught, tf, zooms, fp)
                    for d in args.offsets:
                        x, y = place.x + d * math.cos(th), place.y + d * math.sin(th)
                        if world.collides(x, y, 0.2):
                            continue
                        frame = world.render(Pose(x, y, th))
                        ff = extract(frame, fp)
                        fits = {
                            "frame": homing_scale_zoomed(zoom_levels(frame, ff, zooms, fp), tf),
                            "taught": homing_scale_taught_zoomed(ff, levels),
                        }
                        row: dict[str, Any] = {"plan": plan.name, "place": place.name}
                        row.update({"heading": k, "offset_m": d})
                        for m, fit in fits.items():
                            row[m] = {
                                "inliers": 0 if fit is None else fit.inliers,
                                "scale": None if fit is None else fit.scale,
                                "verdict": None
                                if fit is None
                                else verdict(fit.scale, p.dock_scale_tol),
                            }
                        rows.append(row)
    table = summary(rows, list(args.offsets), p.dock_min_inliers)
    print(f"{len(rows)} views; acted on: >= {p.dock_min_inliers} inliers; right: the verdict")
    print(
        f"{'offset':>7s} {'views':>5s}  "
        + "  ".join(f"{m + ': inliers / acted / right':34s}" for m in METHODS)
    )
    for key, cell in table.items():
        parts = [
            f"{cell[m]['mean_inliers']:6.1f} / {100 * cell[m]['acted_share']:3.0f} % / "
            f"{100 * cell[m]['right_share']:3.0f} %".ljust(34)
            for m in METHODS
        ]
        print(f"{key:>7s} {cell['views']:5d}  " + "  ".join(parts))
    print("(frame: the frame's four zooms; taught: the taught image's, as looking reads them)")
    write_json(
        args.json,
        {
            "plans": [str(x) for x in plans],
            "headings": args.headings,
            "offsets_m": list(args.offsets),
            "dock_min_inliers": p.dock_min_inliers,
            "dock_scale_tol": p.dock_scale_tol,
            "summary": table,
            "rows": rows,
        },
    )
    return 0
