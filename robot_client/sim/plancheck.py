"""Everything that can be wrong with a floor plan, found at once, each with its JSON path.

:func:`check_plan` is what ``load_plan`` runs on every plan (so ``demo``, the benchmarks and
``teachrepeat sim check-plan`` say the same thing about the same file). It finds:

* names: empty, or used twice (rooms, places, furniture);
* rooms: degenerate, overlapping, with an unknown floor or wall texture;
* doors: not on a side shared by two rooms, narrower than the robot plus a margin, or left
  narrower than that by furniture (as taught or as moved);
* furniture: an unknown kind or texture, a non-positive size, sticking out of the home (as
  taught or as moved);
* places: outside every room, where the robot does not fit, or out of reach: the guide must
  walk from the first place to every other one keeping its clearance in the home as taught,
  and a robot must still pass once the furniture has moved; the pieces that close the way are
  named;
* pictures and extra walls with an unknown texture; aliases and the route naming unknown
  places, a route that never visits a place or names one twice in a row.

Frame and units as in :mod:`robot_client.sim.floorplan` (metres, radians).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from robot_client.sim.floorplan import (
    FLAT_KINDS,
    SOLID_KINDS,
    FloorPlan,
    Furniture,
    Place,
    Problem,
    Room,
)
from robot_client.sim.paths import GUIDE_CLEARANCE_M
from robot_client.sim.robot import RobotParams
from robot_client.sim.textures import TEXTURES
from robot_client.sim.world import PlanGeometry

BoolGrid = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class CheckParams:
    """What a plan must leave room for.

    Attributes:
        robot_radius_m: the simulated robot's radius, metres.
        margin_m: room to spare beside the robot in a doorway or passage, metres.
        guide_clearance_m: how far from obstacles the teaching guide walks, metres.
        resolution_m: grid cell for the reachability checks, metres.
        snap_m: a place this close to free space counts as reachable (the guide's snap), metres.
    """

    robot_radius_m: float = RobotParams().radius_m
    margin_m: float = 0.05
    guide_clearance_m: float = GUIDE_CLEARANCE_M
    resolution_m: float = 0.05
    snap_m: float = 0.5

    @property
    def passage_m(self) -> float:
        """Clearance a moving robot needs from every obstacle: radius plus margin, metres."""
        return self.robot_radius_m + self.margin_m


INTERNAL_TEXTURES = frozenset({"ceiling", "terracotta", "walnut"})
"""Textures the renderer always uses (ceiling, plant pots, bed heads)."""


def check_plan(plan: FloorPlan, params: CheckParams = CheckParams()) -> list[Problem]:
    """Every problem of ``plan``, in the order of the file (empty: the plan is good)."""
    problems = [
        *_names(plan),
        *_rooms(plan),
        *_doors(plan, params),
        *_furniture(plan),
        *_textures(plan),
        *_named_places(plan),
    ]
    if not any(p.path.startswith(("$.rooms", "$.furniture")) for p in problems):
        problems += _reach(plan, params)  # needs a sound layout to mean anything
    return problems


# -- names, rooms, doors, furniture, textures -----------------------------------------------------


def _names(plan: FloorPlan) -> Iterator[Problem]:
    lists: tuple[tuple[str, Sequence[Room | Place | Furniture]], ...] = (
        ("rooms", plan.rooms),
        ("places", plan.places),
        ("furniture", plan.furniture),
    )
    for key, items in lists:
        first: dict[str, int] = {}
        for i, item in enumerate(items):
            name = item.name
            if not name.strip():
                yield Problem(f"$.{key}[{i}].name", "is empty; give it a name")
            elif name in first:
                yield Problem(
                    f"$.{key}[{i}].name",
                    f"{name!r} is also the name of $.{key}[{first[name]}]; names must be unique",
                )
            else:
                first[name] = i


def _rooms(plan: FloorPlan) -> Iterator[Problem]:
    if not plan.rooms:
        yield Problem("$.rooms", "a home needs at least one room")
    if plan.door_height >= plan.wall_height:
        yield Problem("$.door_height", f"must be below wall_height ({plan.wall_height} m)")
    for i, r in enumerate(plan.rooms):
        if not (r.x1 - r.x0 > 0.5 and r.y1 - r.y0 > 0.5):
            yield Problem(
                f"$.rooms[{i}]",
                f"room {r.name!r} is degenerate; need x1 > x0 and y1 > y0 by at least 0.5 m",
            )
    for (i, a), (j, b) in itertools.combinations(enumerate(plan.rooms), 2):
        overlap_x = min(a.x1, b.x1) - max(a.x0, b.x0)
        if overlap_x > 1e-6 and min(a.y1, b.y1) - max(a.y0, b.y0) > 1e-6:
            yield Problem(
                f"$.rooms[{j}]",
                f"room {b.name!r} overlaps $.rooms[{i}] ({a.name!r}); rooms may share a side "
                "but not floor",
            )


def _doors(plan: FloorPlan, params: CheckParams) -> Iterator[Problem]:
    need = 2 * params.passage_m
    for i, d in enumerate(plan.doors):
        rooms = plan.rooms_of_door(d)
        if not rooms:
            yield Problem(
                f"$.doors[{i}]",
                f"door at ({d.x}, {d.y}) is not on any room's wall; put it on a side shared "
                "by two rooms",
            )
        elif len(rooms) == 1:
            yield Problem(
                f"$.doors[{i}]",
                f"door at ({d.x}, {d.y}) is on an outside wall of {plan.rooms[rooms[0]].name!r} "
                "only; a door joins two rooms on a side they share",
            )
        if d.width < need:
            yield Problem(
                f"$.doors[{i}].width",
                f"{d.width} m is too narrow for the robot: it needs {need:.2f} m (radius "
                f"{params.robot_radius_m} m and {params.margin_m} m to spare on each side)",
            )


def _furniture(plan: FloorPlan) -> Iterator[Problem]:
    kinds = SOLID_KINDS | FLAT_KINDS
    for i, f in enumerate(plan.furniture):
        if f.kind not in kinds:
            yield Problem(
                f"$.furniture[{i}].kind",
                f"unknown kind {f.kind!r}; use one of {', '.join(sorted(kinds))}",
            )
        if min(f.sx, f.sy, f.h) <= 0:
            yield Problem(f"$.furniture[{i}]", f"{f.name!r} needs positive sx, sy and h")
            continue
        versions = [(f, "")] + ([(f.displaced(), ".moved")] if f.moved is not None else [])
        for piece, where in versions:
            if any(plan.room_at(cx, cy) is None for cx, cy in piece.corners()):
                yield Problem(
                    f"$.furniture[{i}]{where}",
                    f"{f.name!r} sticks out of the home" + (" when moved" if where else ""),
                )


def _textures(plan: FloorPlan) -> Iterator[Problem]:
    known = set(TEXTURES)
    hint = "names are listed in robot_client/sim/textures.py (TEXTURES)"
    fields: list[tuple[str, str]] = []
    for i, r in enumerate(plan.rooms):
        fields += [(f"$.rooms[{i}].floor", r.floor), (f"$.rooms[{i}].wall", r.wall)]
    fields += [(f"$.furniture[{i}].texture", f.texture) for i, f in enumerate(plan.furniture)]
    fields += [(f"$.pictures[{i}].texture", p.texture) for i, p in enumerate(plan.pictures)]
    fields += [(f"$.extra_walls[{i}].texture", w.texture) for i, w in enumerate(plan.extra_walls)]
    for path, name in fields:
        if name not in known:
            yield Problem(path, f"unknown texture {name!r}; {hint}")


def _named_places(plan: FloorPlan) -> Iterator[Problem]:
    names = {p.name for p in plan.places}
    if len(plan.places) < 2:
        yield Problem("$.places", "a home needs at least two named places")
    for i, p in enumerate(plan.places):
        if plan.room_at(p.x, p.y) is None:
            yield Problem(f"$.places[{i}]", f"{p.name!r} at ({p.x}, {p.y}) is outside every room")
    for i, alias in enumerate(plan.aliases):
        for k, name in enumerate(alias):
            if name not in names:
                yield Problem(f"$.aliases[{i}][{k}]", f"names unknown place {name!r}")
        if alias[0] == alias[1]:
            yield Problem(f"$.aliases[{i}]", "names the same place twice")
    if not plan.route:
        return
    for k, name in enumerate(plan.route):
        if name not in names:
            yield Problem(f"$.route[{k}]", f"names unknown place {name!r}")
        elif k and plan.route[k - 1] == name:
            yield Problem(f"$.route[{k}]", f"{name!r} twice in a row; the guide would not move")
    missed = [p.name for p in plan.places if p.name not in set(plan.route)]
    if missed:
        yield Problem(
            "$.route",
            f"never visits {', '.join(repr(n) for n in missed)}: every place must be taught "
            "(or leave 'route' out and the guide derives one)",
        )


# -- reachability ------------------------------------------------------------------------------


class _Layout:
    """Distances on a grid over the home for one condition: to the walls, and to the nearest and
    second-nearest solid piece of furniture (so that removing one piece is cheap to try)."""

    def __init__(self, plan: FloorPlan, condition: str, resolution: float) -> None:
        geometry = PlanGeometry(plan, condition=condition)
        x0, y0, x1, y1 = plan.bounds
        self.x0, self.y0, self.res = x0, y0, resolution
        nx, ny = math.ceil((x1 - x0) / resolution), math.ceil((y1 - y0) / resolution)
        gx, gy = np.meshgrid(
            x0 + (np.arange(nx) + 0.5) * resolution, y0 + (np.arange(ny) + 0.5) * resolution
        )
        walls = [k for k, o in enumerate(geometry.obstacles) if o.name.startswith("wall ")]
        solid = [k for k, o in enumerate(geometry.obstacles) if not o.name.startswith("wall ")]
        edge = np.minimum.reduce([gx - x0, x1 - gx, gy - y0, y1 - gy])
        self.walls = np.minimum(_min_distance(geometry, gx, gy, walls), edge)
        self.pieces = [geometry.obstacles[k].name for k in solid]
        inf = np.full(gx.shape, np.inf)
        self.first, self.second = inf.copy(), inf.copy()
        self.nearest = np.full(gx.shape, -1, dtype=np.int64)
        for n, k in enumerate(solid):
            d = geometry.distance_map(gx, gy, [k])[0]
            closer = d < self.first
            self.second = np.where(closer, self.first, np.minimum(self.second, d))
            self.nearest = np.where(closer, n, self.nearest)
            self.first = np.where(closer, d, self.first)
        self.geometry = geometry

    def free(self, clearance: float, without: int | None = None) -> BoolGrid:
        """Cells where a disk of ``clearance`` metres fits (``without``: that piece removed)."""
        furniture = (
            self.first
            if without is None
            else np.where(self.nearest == without, self.second, self.first)
        )
        return np.minimum(self.walls, furniture) >= clearance

    def cell(self, x: float, y: float) -> tuple[int, int]:
        ny, nx = self.walls.shape
        i = int(np.clip((y - self.y0) / self.res, 0, ny - 1))
        j = int(np.clip((x - self.x0) / self.res, 0, nx - 1))
        return i, j


def _min_distance(
    geometry: PlanGeometry,
    gx: npt.NDArray[np.float64],
    gy: npt.NDArray[np.float64],
    which: Sequence[int],
) -> npt.NDArray[np.float64]:
    out = np.full(gx.shape, np.inf)
    for k in range(0, len(which), 16):
        out = np.minimum(out, geometry.distance_map(gx, gy, which[k : k + 16]).min(axis=0))
    return out


def _components(free: BoolGrid) -> npt.NDArray[np.int32]:
    labels, _ = ndimage.label(free, structure=np.ones((3, 3), dtype=bool))  # 8-connected, as A*
    return np.asarray(labels, dtype=np.int32)


def _place_label(
    layout: _Layout, labels: npt.NDArray[np.int32], x: float, y: float, snap_m: float
) -> int:
    """The component of the free cell nearest to ``(x, y)`` within ``snap_m`` (0: none)."""
    i, j = layout.cell(x, y)
    r = math.ceil(snap_m / layout.res)
    window = labels[max(0, i - r) : i + r + 1, max(0, j - r) : j + r + 1]
    ii, jj = np.nonzero(window)
    if ii.size == 0:
        return 0
    d = (ii + max(0, i - r) - i) ** 2 + (jj + max(0, j - r) - j) ** 2
    k = int(np.argmin(d))
    return int(window[ii[k], jj[k]]) if d[k] <= r * r else 0


def _reach(plan: FloorPlan, params: CheckParams) -> list[Problem]:
    problems: list[Problem] = []
    index = {f.name: i for i, f in enumerate(plan.furniture)}
    conditions = [("same", params.guide_clearance_m, "the teaching guide's clearance")]
    if any(f.moved is not None for f in plan.furniture):
        conditions.append(("moved", params.passage_m, "the robot's radius and margin"))
    reported: set[str] = set()  # places already found at fault
    blocked: set[tuple[int, str]] = set()  # (door, piece) already found
    for condition, clearance, why in conditions:
        layout = _Layout(plan, condition, params.resolution_m)
        problems += _doorways(plan, layout, params, condition, index, blocked)
        problems += _places_fit(plan, layout, params, condition, index, reported)
        labels = _components(layout.free(clearance))
        if not plan.places:
            continue
        home = plan.places[0]
        home_label = _place_label(layout, labels, home.x, home.y, params.snap_m)
        if home.name in reported or not home_label:
            continue  # the first place itself is at fault (reported), or boxed in (below)
        for i, p in enumerate(plan.places[1:], start=1):
            if p.name in reported or plan.room_at(p.x, p.y) is None:
                continue
            if _place_label(layout, labels, p.x, p.y, params.snap_m) == home_label:
                continue
            reported.add(p.name)
            culprits = _culprits(plan, layout, clearance, params, home, p)
            pieces = ", ".join(f"{n!r} ($.furniture[{index[n]}])" for n in culprits)
            state = " once the furniture has moved" if condition == "moved" else ""
            problems.append(
                Problem(
                    f"$.places[{i}]",
                    f"{p.name!r} cannot be reached from {home.name!r}{state} keeping "
                    f"{clearance:.2f} m from walls and furniture ({why}): "
                    + (
                        f"{pieces} narrow{'s' if len(culprits) == 1 else ''} the passage; move "
                        "or shrink it"
                        if culprits
                        else "no door or passage wide enough joins its room to the others"
                    ),
                )
            )
    return problems


def _culprits(
    plan: FloorPlan,
    layout: _Layout,
    clearance: float,
    params: CheckParams,
    home: Place,
    place: Place,
) -> list[str]:
    """Pieces of furniture whose removal alone lets the robot through."""
    out = []
    for n, name in enumerate(layout.pieces):
        labels = _components(layout.free(clearance, without=n))
        a = _place_label(layout, labels, home.x, home.y, params.snap_m)
        b = _place_label(layout, labels, place.x, place.y, params.snap_m)
        if a and a == b:
            out.append(name)
    return out


def _doorways(
    plan: FloorPlan,
    layout: _Layout,
    params: CheckParams,
    condition: str,
    index: dict[str, int],
    blocked: set[tuple[int, str]],
) -> list[Problem]:
    """A doorway whose widest free point leaves less than the robot plus margin (each piece of
    furniture named once, in the first condition where it blocks the doorway)."""
    out = []
    need = params.passage_m
    for i, d in enumerate(plan.doors):
        rooms = plan.rooms_of_door(d)
        if len(rooms) < 2 or d.width < 2 * need:
            continue  # reported as a door problem already
        r = plan.rooms[rooms[0]]
        along_x = abs(d.y - r.y0) <= plan.wall_thickness or abs(d.y - r.y1) <= plan.wall_thickness
        s = np.linspace(-d.width / 2, d.width / 2, 41)
        xs, ys = (d.x + s, np.full_like(s, d.y)) if along_x else (np.full_like(s, d.x), d.y + s)
        clear = layout.geometry.clearance_map(xs, ys)
        best = int(np.argmax(clear))
        if clear[best] >= need:
            continue
        solid = [
            k for k, o in enumerate(layout.geometry.obstacles) if not o.name.startswith("wall ")
        ]
        # the pieces that come nearer the doorway than a passing robot needs
        dist = layout.geometry.distance_map(xs, ys, solid).min(axis=1)
        names = [layout.geometry.obstacles[solid[k]].name for k in np.flatnonzero(dist < need)]
        state = "once moved " if condition == "moved" else ""
        for name in names:
            if (i, name) in blocked:
                continue
            blocked.add((i, name))
            out.append(
                Problem(
                    f"$.furniture[{index[name]}]" + (".moved" if condition == "moved" else ""),
                    f"{name!r} {state}leaves the doorway at $.doors[{i}] ({d.x}, {d.y}) "
                    f"{2 * clear[best]:.2f} m; the robot needs {2 * need:.2f} m",
                )
            )
    return out


def _places_fit(
    plan: FloorPlan,
    layout: _Layout,
    params: CheckParams,
    condition: str,
    index: dict[str, int],
    reported: set[str],
) -> list[Problem]:
    """A place where the robot's disk overlaps a wall or a piece of furniture."""
    out = []
    for i, p in enumerate(plan.places):
        if p.name in reported or plan.room_at(p.x, p.y) is None:
            continue
        clear = layout.geometry.clearance(p.x, p.y)
        if clear >= params.robot_radius_m:
            continue
        obstacles = layout.geometry.obstacles
        dist = layout.geometry.distance_map([p.x], [p.y], range(len(obstacles)))[:, 0]
        nearest = obstacles[int(np.argmin(dist))]
        what = (
            "a wall"
            if nearest.name.startswith("wall ")
            else (f"{nearest.name!r} ($.furniture[{index[nearest.name]}])")
        )
        state = " once the furniture has moved" if condition == "moved" else ""
        reported.add(p.name)
        out.append(
            Problem(
                f"$.places[{i}]",
                f"{p.name!r} is {clear:.2f} m from {what}{state}; the robot (radius "
                f"{params.robot_radius_m} m) does not fit there",
            )
        )
    return out
