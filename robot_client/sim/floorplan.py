"""The floor plan of a simulated home: data, not code.

A plan is a JSON file (``apartment.json`` beside this module is the default) with axis-aligned
rectangular rooms, doorways cut into their walls, furniture, pictures on walls and named places.
:func:`load_plan` reads and validates it; everything else (the MuJoCo scene, collision geometry,
shortest paths) is derived from the :class:`FloorPlan`.

Frame and units: x east, y north, z up, metres; yaw in radians counter-clockwise from +x.

Walls are derived: every room gets a thin panel (``wall_thickness``) just inside each of its four
sides, painted with the room's wall texture; a wall between two rooms is therefore two panels back
to back, each painted for its own room. A :class:`Door` at a point on a room side removes ``width``
metres of every panel it lies on.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

DEFAULT_PLAN = Path(__file__).with_name("apartment.json")

CONDITIONS = ("same", "lighting", "moved")
"""Conditions of a repeat run: as taught, dimmer and warmer light, some furniture moved."""

SOLID_KINDS = frozenset(
    {
        "box",
        "bed",
        "sofa",
        "table",
        "desk",
        "chair",
        "shelf",
        "cabinet",
        "counter",
        "fridge",
        "plant",
        "bath",
        "toilet",
        "sink",
        "tv",
        "bench",
    }
)
FLAT_KINDS = frozenset({"rug"})
"""Furniture kinds the robot drives over (no collision)."""


class PlanError(ValueError):
    """The floor plan is malformed; the message says which element and what to change."""


@dataclass(frozen=True)
class Place:
    """A named place the guide stops at and names ("kitchen").

    Attributes:
        name: unique name.
        x, y: position in metres.
        yaw: heading the guide faces when naming it, radians.
    """

    name: str
    x: float
    y: float
    yaw: float = 0.0


@dataclass(frozen=True)
class Room:
    """An axis-aligned rectangular room ``[x0, x1] x [y0, y1]`` (metres)."""

    name: str
    x0: float
    y0: float
    x1: float
    y1: float
    floor: str = "parquet"
    """Texture name of the floor (see ``textures.TEXTURES``)."""
    wall: str = "paint_beige"
    """Texture name of the room's wall panels."""

    def contains(self, x: float, y: float, margin: float = 0.0) -> bool:
        """Whether ``(x, y)`` is inside the room shrunk by ``margin`` metres."""
        inside_x = self.x0 + margin <= x <= self.x1 - margin
        return inside_x and self.y0 + margin <= y <= self.y1 - margin


@dataclass(frozen=True)
class Door:
    """A doorway: a gap of ``width`` metres centred at ``(x, y)`` in every wall panel it lies on."""

    x: float
    y: float
    width: float = 0.9


@dataclass(frozen=True)
class Wall:
    """A wall panel: the segment ``(x0, y0) - (x1, y1)`` (axis-aligned), ``thickness`` metres thick
    (centred on the segment) and ``height`` metres tall, painted with ``texture`` on both faces.

    Derived from the rooms by :meth:`FloorPlan.walls`, or given explicitly (``extra_walls``).
    """

    x0: float
    y0: float
    x1: float
    y1: float
    thickness: float = 0.06
    height: float = 2.5
    texture: str = "paint_beige"
    z0: float = 0.0
    """Bottom of the panel (a lintel above a doorway starts at the door height)."""

    @property
    def length(self) -> float:
        return math.hypot(self.x1 - self.x0, self.y1 - self.y0)


@dataclass(frozen=True)
class Furniture:
    """A piece of furniture: a box ``sx x sy`` metres (footprint, before ``yaw``) and ``h`` tall.

    Attributes:
        name: unique name ("sofa", "bedroom/bed").
        kind: rendering style and whether it blocks the robot (``rug`` does not).
        x, y: footprint centre, metres. yaw: rotation, radians.
        texture: texture name of its surfaces.
        moved: ``(dx, dy, dyaw)`` applied under the ``moved`` condition, or ``None`` (stays put).
    """

    name: str
    kind: str
    x: float
    y: float
    sx: float
    sy: float
    h: float
    yaw: float = 0.0
    texture: str = "walnut"
    moved: tuple[float, float, float] | None = None
    z: float = 0.0
    """Height of the bottom above the floor (a television on its stand), metres."""

    @property
    def solid(self) -> bool:
        """Whether the robot collides with it (and the depth sensor sees it)."""
        return self.kind not in FLAT_KINDS

    def displaced(self) -> Furniture:
        """This piece as it stands under the ``moved`` condition."""
        if self.moved is None:
            return self
        dx, dy, dyaw = self.moved
        return replace(self, x=self.x + dx, y=self.y + dy, yaw=self.yaw + dyaw)

    def corners(self) -> list[tuple[float, float]]:
        """The footprint's four corners, counter-clockwise, metres."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        hx, hy = self.sx / 2, self.sy / 2
        return [
            (self.x + c * px - s * py, self.y + s * px + c * py)
            for px, py in ((-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy))
        ]


@dataclass(frozen=True)
class Picture:
    """A framed picture hung flat on a wall.

    Attributes:
        x, y: centre of the picture on the wall surface, metres.
        yaw: direction the picture faces (into the room), radians.
        width, height: metres. z: height of its centre above the floor, metres.
        texture: texture name of the image.
    """

    x: float
    y: float
    yaw: float
    width: float
    height: float
    z: float
    texture: str


@dataclass(frozen=True)
class FloorPlan:
    """A whole home: rooms, doors, furniture, pictures and named places (metres, radians)."""

    name: str
    rooms: tuple[Room, ...]
    doors: tuple[Door, ...]
    furniture: tuple[Furniture, ...]
    pictures: tuple[Picture, ...]
    places: tuple[Place, ...]
    extra_walls: tuple[Wall, ...] = ()
    wall_height: float = 2.5
    wall_thickness: float = 0.06
    door_height: float = 2.05
    aliases: tuple[tuple[str, str], ...] = ()
    """Pairs of place names that are meant to look alike (perceptual aliasing)."""
    notes: str = ""
    _cache: dict[str, Any] = field(default_factory=dict, compare=False, repr=False, hash=False)

    # -- queries ---------------------------------------------------------------------------

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(x0, y0, x1, y1)`` of the union of the rooms, metres."""
        return (
            min(r.x0 for r in self.rooms),
            min(r.y0 for r in self.rooms),
            max(r.x1 for r in self.rooms),
            max(r.y1 for r in self.rooms),
        )

    def place(self, name: str) -> Place:
        """The place called ``name``; :class:`KeyError` listing the known names otherwise."""
        for p in self.places:
            if p.name == name:
                return p
        raise KeyError(f"no place {name!r}; places are: {', '.join(p.name for p in self.places)}")

    def room_at(self, x: float, y: float) -> Room | None:
        """The room containing ``(x, y)``, or ``None`` outside the home."""
        for r in self.rooms:
            if r.contains(x, y):
                return r
        return None

    def furniture_for(self, condition: str = "same") -> tuple[Furniture, ...]:
        """Furniture as it stands under ``condition`` (``moved`` displaces some pieces)."""
        check_condition(condition)
        if condition == "moved":
            return tuple(f.displaced() for f in self.furniture)
        return self.furniture

    def walls(self) -> tuple[Wall, ...]:
        """All wall panels (full height), with doorways cut out, plus ``extra_walls``.

        Lintels above doorways are in :meth:`lintels` (they do not block the robot).
        """
        if "walls" not in self._cache:
            self._cache["walls"], self._cache["lintels"] = self._derive_walls()
        return self._cache["walls"]

    def lintels(self) -> tuple[Wall, ...]:
        """Wall panels above doorways, from ``door_height`` to ``wall_height``."""
        self.walls()
        return self._cache["lintels"]

    def _derive_walls(self) -> tuple[tuple[Wall, ...], tuple[Wall, ...]]:
        t = self.wall_thickness
        walls: list[Wall] = []
        lintels: list[Wall] = []
        for r in self.rooms:
            # (fixed coordinate of the side, the panel centre line, along-x?, start, end)
            sides = (
                (r.y0, r.y0 + t / 2, True, r.x0, r.x1),
                (r.y1, r.y1 - t / 2, True, r.x0, r.x1),
                (r.x0, r.x0 + t / 2, False, r.y0, r.y1),
                (r.x1, r.x1 - t / 2, False, r.y0, r.y1),
            )
            for side, centre, along_x, a0, a1 in sides:
                gaps = []
                for d in self.doors:
                    across, along = (d.y, d.x) if along_x else (d.x, d.y)
                    if abs(across - side) <= t + 1e-6 and a0 < along < a1:
                        gaps.append((along - d.width / 2, along + d.width / 2))
                pieces = _subtract(a0, a1, gaps)
                for s0, s1 in pieces:
                    walls.append(_panel(along_x, centre, s0, s1, t, self.wall_height, r.wall, 0.0))
                for g0, g1 in gaps:
                    lintels.append(
                        _panel(
                            along_x,
                            centre,
                            g0,
                            g1,
                            t,
                            self.wall_height - self.door_height,
                            r.wall,
                            self.door_height,
                        )
                    )
        walls.extend(self.extra_walls)
        return tuple(walls), tuple(lintels)


def _panel(
    along_x: bool, centre: float, s0: float, s1: float, t: float, h: float, texture: str, z0: float
) -> Wall:
    if along_x:
        return Wall(s0, centre, s1, centre, t, h, texture, z0)
    return Wall(centre, s0, centre, s1, t, h, texture, z0)


def _subtract(
    a0: float, a1: float, gaps: Iterable[tuple[float, float]]
) -> list[tuple[float, float]]:
    """The interval ``[a0, a1]`` minus ``gaps``, as pieces longer than 1 cm."""
    pieces = [(a0, a1)]
    for g0, g1 in gaps:
        out = []
        for p0, p1 in pieces:
            if g1 <= p0 or g0 >= p1:
                out.append((p0, p1))
                continue
            if g0 > p0:
                out.append((p0, g0))
            if g1 < p1:
                out.append((g1, p1))
        pieces = out
    return [(p0, p1) for p0, p1 in pieces if p1 - p0 > 0.01]


def check_condition(condition: str) -> None:
    """Raise :class:`PlanError` unless ``condition`` is one of :data:`CONDITIONS`."""
    if condition not in CONDITIONS:
        raise PlanError(f"unknown condition {condition!r}; use one of {', '.join(CONDITIONS)}")


# -- loading and validation ----------------------------------------------------------------------


def load_plan(path: Path | str | None = None) -> FloorPlan:
    """Read and validate a floor plan JSON file.

    Args:
        path: the JSON file; ``None`` loads the packaged ``apartment.json``.

    Raises:
        PlanError: the file is missing, is not valid JSON, or describes an impossible home;
            the message names the element at fault.
    """
    path = DEFAULT_PLAN if path is None else Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise PlanError(f"floor plan {path} not found") from None
    except json.JSONDecodeError as exc:
        raise PlanError(f"floor plan {path} is not valid JSON: {exc}") from None
    return plan_from_dict(data, source=str(path))


def plan_from_dict(data: Mapping[str, Any], *, source: str = "<dict>") -> FloorPlan:
    """Build and validate a :class:`FloorPlan` from its JSON form (see ``apartment.json``)."""

    def items(key: str) -> list[Mapping[str, Any]]:
        value = data.get(key, [])
        if not isinstance(value, list):
            raise PlanError(f"{source}: {key!r} must be a list")
        return value

    def build(cls: type, item: Mapping[str, Any], where: str) -> Any:
        try:
            kwargs = dict(item)
            if cls is Furniture and kwargs.get("moved") is not None:
                kwargs["moved"] = tuple(float(v) for v in kwargs["moved"])
            return cls(**kwargs)
        except TypeError as exc:
            raise PlanError(f"{source}: {where}: {exc}") from None

    try:
        plan = FloorPlan(
            name=str(data.get("name", "home")),
            rooms=tuple(build(Room, r, f"rooms[{i}]") for i, r in enumerate(items("rooms"))),
            doors=tuple(build(Door, d, f"doors[{i}]") for i, d in enumerate(items("doors"))),
            furniture=tuple(
                build(Furniture, f, f"furniture[{i}]") for i, f in enumerate(items("furniture"))
            ),
            pictures=tuple(
                build(Picture, p, f"pictures[{i}]") for i, p in enumerate(items("pictures"))
            ),
            places=tuple(build(Place, p, f"places[{i}]") for i, p in enumerate(items("places"))),
            extra_walls=tuple(
                build(Wall, w, f"extra_walls[{i}]") for i, w in enumerate(items("extra_walls"))
            ),
            wall_height=float(data.get("wall_height", 2.5)),
            wall_thickness=float(data.get("wall_thickness", 0.06)),
            door_height=float(data.get("door_height", 2.05)),
            aliases=tuple(tuple(a) for a in data.get("aliases", [])),
            notes=str(data.get("notes", "")),
        )
    except (TypeError, ValueError) as exc:
        if isinstance(exc, PlanError):
            raise
        raise PlanError(f"{source}: {exc}") from None
    validate(plan, source=source)
    return plan


def validate(plan: FloorPlan, *, source: str = "plan", robot_radius: float = 0.2) -> None:
    """Check a plan for the mistakes a hand-edited JSON file tends to have.

    Raises:
        PlanError: with the offending element and what to change.
    """
    if not plan.rooms:
        raise PlanError(f"{source}: no rooms")
    if plan.door_height >= plan.wall_height:
        raise PlanError(f"{source}: door_height must be below wall_height")
    _unique(source, "room", [r.name for r in plan.rooms])
    _unique(source, "place", [p.name for p in plan.places])
    _unique(source, "furniture", [f.name for f in plan.furniture])
    for r in plan.rooms:
        if not (r.x1 - r.x0 > 0.5 and r.y1 - r.y0 > 0.5):
            raise PlanError(
                f"{source}: room {r.name!r} is degenerate; need x1 > x0 and y1 > y0 "
                "by at least 0.5 m"
            )
    for i, a in enumerate(plan.rooms):
        for b in plan.rooms[i + 1 :]:
            overlap_x = min(a.x1, b.x1) - max(a.x0, b.x0)
            if overlap_x > 1e-6 and min(a.y1, b.y1) - max(a.y0, b.y0) > 1e-6:
                raise PlanError(f"{source}: rooms {a.name!r} and {b.name!r} overlap")
    for d in plan.doors:
        on_side = [r.name for r in plan.rooms if _on_boundary(r, d, plan.wall_thickness)]
        if not on_side:
            raise PlanError(
                f"{source}: door at ({d.x}, {d.y}) is not on any room's wall; "
                "put it on a shared side of two rooms"
            )
        if d.width < 2 * robot_radius + 0.1:
            raise PlanError(
                f"{source}: door at ({d.x}, {d.y}) is {d.width} m wide, too narrow for "
                f"a robot of radius {robot_radius} m"
            )
    for f in plan.furniture:
        if f.kind not in SOLID_KINDS | FLAT_KINDS:
            raise PlanError(
                f"{source}: furniture {f.name!r} has unknown kind {f.kind!r}; use one "
                f"of {', '.join(sorted(SOLID_KINDS | FLAT_KINDS))}"
            )
        if min(f.sx, f.sy, f.h) <= 0:
            raise PlanError(f"{source}: furniture {f.name!r} needs positive sx, sy and h")
        for g in (f, f.displaced()):
            if any(plan.room_at(cx, cy) is None for cx, cy in g.corners()):
                raise PlanError(
                    f"{source}: furniture {f.name!r} sticks out of the home"
                    + (" when moved" if g is not f else "")
                )
    for p in plan.places:
        if plan.room_at(p.x, p.y) is None:
            raise PlanError(f"{source}: place {p.name!r} at ({p.x}, {p.y}) is outside every room")
    names = {p.name for p in plan.places}
    for alias in plan.aliases:
        if len(alias) != 2 or not set(alias) <= names:
            raise PlanError(f"{source}: alias {alias!r} must name two places")
    if len(plan.places) < 2:
        raise PlanError(f"{source}: a home needs at least two named places")


def _unique(source: str, what: str, names: list[str]) -> None:
    seen: set[str] = set()
    for n in names:
        if n in seen:
            raise PlanError(f"{source}: two {what}s are called {n!r}; names must be unique")
        seen.add(n)


def _on_boundary(r: Room, d: Door, t: float) -> bool:
    on_x_side = (abs(d.y - r.y0) <= t or abs(d.y - r.y1) <= t) and r.x0 < d.x < r.x1
    on_y_side = (abs(d.x - r.x0) <= t or abs(d.x - r.x1) <= t) and r.y0 < d.y < r.y1
    return on_x_side or on_y_side
