"""Figures of the simulated home for the README, and a render-speed measurement.

``python -m robot_client.sim.figures [OUT_DIR] [PLAN]`` writes into ``docs/img/`` (default; the
packaged apartment unless a plan file is given):

* ``sim_conditions.png`` - one view under ``same``, ``lighting`` and ``moved``;
* ``sim_aliasing.png`` - the two look-alike rooms side by side;

and prints frames per second of :meth:`SimWorld.render` at 320x240. The map of a home with its
teaching route, and the view at every place, are drawn by ``teachrepeat sim check-plan FILE
--png OUT``.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from robot_client.sim.floorplan import FloorPlan, load_plan
from robot_client.sim.world import Pose, SimWorld

DEFAULT_OUT = Path(__file__).resolve().parents[2] / "docs" / "img"


def label_image(img: npt.NDArray[np.uint8], text: str) -> npt.NDArray[np.uint8]:
    """A copy of ``img`` with ``text`` in white on black at its top left."""
    out = img.copy()
    cv2.rectangle(out, (0, 0), (8 + 9 * len(text), 20), (0, 0, 0), -1)
    cv2.putText(out, text, (4, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def contact_sheet(images: list[npt.NDArray[np.uint8]], cols: int) -> npt.NDArray[np.uint8]:
    """Images of one size in rows of ``cols`` (the last row padded with black)."""
    blank = np.zeros_like(images[0])
    rows = []
    for i in range(0, len(images), cols):
        row = images[i : i + cols]
        row += [blank] * (cols - len(row))
        rows.append(np.hstack(row))
    return np.vstack(rows)


def render_fps(world: SimWorld, n: int = 300) -> float:
    """Frames per second of ``world.render`` while turning on the spot at the first place."""
    p = world.plan.places[0]
    world.render(Pose(p.x, p.y, p.yaw))
    t0 = time.perf_counter()
    for i in range(n):
        world.render(Pose(p.x, p.y, p.yaw + 0.02 * i))
    return n / (time.perf_counter() - t0)


def _near_moved(plan: FloorPlan) -> Pose:
    """A named place's pose, turned toward the nearest piece of furniture that moves (so the
    three conditions differ in view); the first place when nothing moves."""
    moving = [f for f in plan.furniture if f.moved is not None]
    if not moving:
        p = plan.places[0]
        return Pose(p.x, p.y, p.yaw)
    p, f = min(
        ((p, f) for p in plan.places for f in moving),
        key=lambda pf: math.dist((pf[0].x, pf[0].y), (pf[1].x, pf[1].y)),
    )
    return Pose(p.x, p.y, math.atan2(f.y - p.y, f.x - p.x))


def save_figures(out_dir: Path = DEFAULT_OUT, plan: FloorPlan | None = None) -> dict[str, Path]:
    """Write the figures listed in the module docstring; returns their paths by short name."""
    plan = plan or load_plan()
    out_dir.mkdir(parents=True, exist_ok=True)
    paths: dict[str, Path] = {}
    with SimWorld(plan) as world:
        if plan.aliases:
            n1, n2 = plan.aliases[0]
            p1, p2 = plan.place(n1), plan.place(n2)
            pair = [
                label_image(world.render(Pose(p.x, p.y, p.yaw + d)), f"{p.name} {k}")
                for d, k in ((0.0, ""), (-1.2, "(turned)"))
                for p in (p1, p2)
            ]
            paths["aliasing"] = out_dir / "sim_aliasing.png"
            cv2.imwrite(str(paths["aliasing"]), contact_sheet(pair, 2))
    spot = _near_moved(plan)
    cond_views = []
    for condition in ("same", "lighting", "moved"):
        with SimWorld(plan, condition=condition) as world:
            cond_views.append(label_image(world.render(spot), condition))
    paths["conditions"] = out_dir / "sim_conditions.png"
    cv2.imwrite(str(paths["conditions"]), contact_sheet(cond_views, 3))
    return paths


def main(argv: list[str] | None = None) -> None:
    """``python -m robot_client.sim.figures [OUT_DIR] [PLAN]`` (defaults: docs/img, the
    packaged apartment)."""
    args = sys.argv[1:] if argv is None else argv
    out = Path(args[0]) if args else DEFAULT_OUT
    plan = load_plan(args[1] if len(args) > 1 else None)
    for name, path in save_figures(out, plan).items():
        print(f"{name}: {path}")
    with SimWorld(plan) as world:
        print(
            f"render: {render_fps(world):.0f} frames/s at "
            f"{world.camera.width}x{world.camera.height}"
        )


if __name__ == "__main__":
    main()
