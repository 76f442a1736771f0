"""Figures of the simulated home for the README, and a render-speed measurement.

``python -m robot_client.sim.figures [OUT_DIR]`` writes into ``docs/img/`` (default):

* ``sim_map.png`` - top-down map with the named places and a shortest path;
* ``sim_places.png`` - the robot camera's view at every named place (labelled);
* ``sim_conditions.png`` - one view under ``same``, ``lighting`` and ``moved``;
* ``sim_aliasing.png`` - the two look-alike rooms side by side;

and prints frames per second of :meth:`SimWorld.render` at 320x240.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from robot_client.sim.floorplan import FloorPlan, load_plan
from robot_client.sim.paths import shortest_path
from robot_client.sim.world import Pose, SimWorld, draw_map

DEFAULT_OUT = Path(__file__).resolve().parents[2] / "docs" / "img"


def _label(img: npt.NDArray[np.uint8], text: str) -> npt.NDArray[np.uint8]:
    out = img.copy()
    cv2.rectangle(out, (0, 0), (8 + 9 * len(text), 20), (0, 0, 0), -1)
    cv2.putText(out, text, (4, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def _grid(images: list[npt.NDArray[np.uint8]], cols: int) -> npt.NDArray[np.uint8]:
    blank = np.zeros_like(images[0])
    rows = []
    for i in range(0, len(images), cols):
        row = images[i : i + cols]
        row += [blank] * (cols - len(row))
        rows.append(np.hstack(row))
    return np.vstack(rows)


def render_fps(world: SimWorld, n: int = 300) -> float:
    """Frames per second of ``world.render`` while turning on the spot in the living room."""
    p = world.plan.places[0]
    world.render(Pose(p.x, p.y, p.yaw))
    t0 = time.perf_counter()
    for i in range(n):
        world.render(Pose(p.x, p.y, p.yaw + 0.02 * i))
    return n / (time.perf_counter() - t0)


def save_figures(out_dir: Path = DEFAULT_OUT, plan: FloorPlan | None = None) -> dict[str, Path]:
    """Write the figures listed in the module docstring; returns their paths by short name."""
    plan = plan or load_plan()
    out_dir.mkdir(parents=True, exist_ok=True)
    paths: dict[str, Path] = {}
    with SimWorld(plan) as world:
        a, b = plan.places[0], plan.places[-1]
        route = shortest_path(world, (a.x, a.y), (b.x, b.y))
        paths["map"] = out_dir / "sim_map.png"
        cv2.imwrite(str(paths["map"]), draw_map(world, path=route))
        views = [_label(world.render(Pose(p.x, p.y, p.yaw)), p.name) for p in plan.places]
        paths["places"] = out_dir / "sim_places.png"
        cv2.imwrite(str(paths["places"]), _grid(views, 4))
        if plan.aliases:
            n1, n2 = plan.aliases[0]
            p1, p2 = plan.place(n1), plan.place(n2)
            pair = [
                _label(world.render(Pose(p.x, p.y, p.yaw + d)), f"{p.name} {k}")
                for d, k in ((0.0, ""), (-1.2, "(turned)"))
                for p in (p1, p2)
            ]
            paths["aliasing"] = out_dir / "sim_aliasing.png"
            cv2.imwrite(str(paths["aliasing"]), _grid(pair, 2))
    living = (
        plan.place("living room")
        if "living room" in {p.name for p in plan.places}
        else plan.places[0]
    )
    cond_views = []
    for condition in ("same", "lighting", "moved"):
        with SimWorld(plan, condition=condition) as world:
            cond_views.append(_label(world.render(Pose(living.x, living.y, living.yaw)), condition))
    paths["conditions"] = out_dir / "sim_conditions.png"
    cv2.imwrite(str(paths["conditions"]), _grid(cond_views, 3))
    return paths


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    out = Path(args[0]) if args else DEFAULT_OUT
    for name, path in save_figures(out).items():
        print(f"{name}: {path}")
    with SimWorld(load_plan()) as world:
        print(
            f"render: {render_fps(world):.0f} frames/s at "
            f"{world.camera.width}x{world.camera.height}"
        )


if __name__ == "__main__":
    main()
