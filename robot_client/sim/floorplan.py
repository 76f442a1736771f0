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


@dataclass(frozen=True)
class Problem:
    """One thing wrong with a plan: where (a JSON path such as ``$.furniture[3].texture``) and
    what to change."""

    path: str
    message: str

    def __str__(self) -> str:
        return f"{self.path}: {self.message}"


class PlanError(ValueError):
    """The floor plan cannot be used. ``problems`` lists every problem found, each with the
    JSON path of the element at fault; the message lists them all."""

    def __init__(self, message: str, problems: Iterable[Problem] = ()) -> None:
        self.problems: tuple[Problem, ...] = tuple(problems)
        if self.problems:
            n = len(self.problems)
            lines = "\n".join(f"  {p}" for p in self.problems)
            message = f"{message}: {n} problem{'s' if n > 1 else ''}\n{lines}"
        super().__init__(message)


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
    route: tuple[str, ...] = ()
    """The teaching guide's walk (place names in order); empty: derived from the plan
    (:func:`robot_client.sim.route.teaching_route`)."""
    notes: str = ""
    source: str = field(default="<dict>", compare=False)
    """Where the plan was read from (a file path), for messages and benchmark records."""
    sha256: str = field(default="", compare=False)
    """SHA-256 of the file's bytes (empty for a plan built in code): benchmarks record it."""
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

    def rooms_of_door(self, door: Door) -> tuple[int, ...]:
        """Indices of the rooms on whose wall ``door`` lies (two for a door that joins rooms)."""
        t = self.wall_thickness
        out = []
        for i, r in enumerate(self.rooms):
            on_x_side = (
                abs(door.y - r.y0) <= t or abs(door.y - r.y1) <= t
            ) and r.x0 < door.x < r.x1
            on_y_side = (
                abs(door.x - r.x0) <= t or abs(door.x - r.x1) <= t
            ) and r.y0 < door.y < r.y1
            if on_x_side or on_y_side:
                out.append(i)
        return tuple(out)

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


# -- reading a plan ------------------------------------------------------------------------------


_LISTS: dict[str, type] = {
    "rooms": Room,
    "doors": Door,
    "furniture": Furniture,
    "pictures": Picture,
    "places": Place,
    "extra_walls": Wall,
}
_NUMBERS = ("wall_height", "wall_thickness", "door_height")
_TEXTS = ("name", "notes")
_TOP_LEVEL = (*_TEXTS, *_NUMBERS, *_LISTS, "aliases", "route")


def load_plan(path: Path | str | None = None, *, check: bool = True) -> FloorPlan:
    """Read a floor plan JSON file and check it (:func:`robot_client.sim.plancheck.check_plan`).

    Args:
        path: the JSON file; ``None`` loads the packaged ``apartment.json``.
        check: run every check (rooms, doors, furniture, reachability, textures, route);
            ``False`` only parses (for tools that show what is wrong with a plan).

    Raises:
        PlanError: the file is missing or is not valid JSON, or the plan has problems; the
            error lists every one with its JSON path.
    """
    path = DEFAULT_PLAN if path is None else Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise PlanError(f"floor plan {path} not found") from None
    except OSError as exc:
        raise PlanError(f"floor plan {path} cannot be read: {exc}") from None
    try:
        data = json.loads(raw)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise PlanError(f"floor plan {path} is not valid JSON: {exc}") from None
    import hashlib

    plan = plan_from_dict(
        data, source=str(path), sha256=hashlib.sha256(raw).hexdigest(), check=check
    )
    return plan


def plan_from_dict(
    data: Any, *, source: str = "<dict>", sha256: str = "", check: bool = True
) -> FloorPlan:
    """Build a :class:`FloorPlan` from its JSON form (see ``apartment.json``) and check it.

    Raises:
        PlanError: listing every problem found, each with its JSON path.
    """
    plan, problems = parse_plan(data, source=source, sha256=sha256)
    if plan is not None and check:
        from robot_client.sim.plancheck import check_plan  # geometry lives there

        problems = [*problems, *check_plan(plan)]
    if plan is None or problems:
        raise PlanError(f"floor plan {source}", problems)
    return plan


def parse_plan(
    data: Any, *, source: str = "<dict>", sha256: str = ""
) -> tuple[FloorPlan | None, list[Problem]]:
    """The plan's structure: every element an object with the right fields and types.

    Returns:
        the plan (``None`` when an element could not be built) and the problems found.
    """
    problems: list[Problem] = []
    if not isinstance(data, Mapping):
        return None, [Problem("$", "a floor plan is a JSON object with 'rooms', 'places', ...")]
    for key in data:
        if key not in _TOP_LEVEL:
            problems.append(
                Problem(f"$.{key}", f"unknown key; known keys: {', '.join(_TOP_LEVEL)}")
            )
    built: dict[str, list[Any]] = {}
    for key, cls in _LISTS.items():
        value = data.get(key, [])
        if not isinstance(value, list):
            problems.append(Problem(f"$.{key}", "must be a list"))
            value = []
        built[key] = [_build(cls, item, f"$.{key}[{i}]", problems) for i, item in enumerate(value)]
    scalars: dict[str, Any] = {}
    for key in _NUMBERS:
        if key in data:
            scalars[key] = _number(data[key], f"$.{key}", problems)
    for key in _TEXTS:
        if key in data:
            scalars[key] = _text(data[key], f"$.{key}", problems)
    aliases = _name_lists(data.get("aliases", []), "$.aliases", problems, pairs=True)
    route = _name_lists([data.get("route", [])], "$.route", problems, pairs=False)
    complete = not problems and all(None not in items for items in built.values())
    if not complete:
        return None, problems
    plan = FloorPlan(
        name=scalars.get("name", "home"),
        rooms=tuple(built["rooms"]),
        doors=tuple(built["doors"]),
        furniture=tuple(built["furniture"]),
        pictures=tuple(built["pictures"]),
        places=tuple(built["places"]),
        extra_walls=tuple(built["extra_walls"]),
        wall_height=scalars.get("wall_height", 2.5),
        wall_thickness=scalars.get("wall_thickness", 0.06),
        door_height=scalars.get("door_height", 2.05),
        aliases=tuple((a[0], a[1]) for a in aliases),
        route=tuple(route[0]) if route else (),
        notes=scalars.get("notes", ""),
        source=source,
        sha256=sha256,
    )
    return plan, problems


def _number(value: Any, path: str, problems: list[Problem]) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        problems.append(Problem(path, f"must be a number, not {json.dumps(value)}"))
        return None
    return float(value)


def _text(value: Any, path: str, problems: list[Problem]) -> str | None:
    if not isinstance(value, str):
        problems.append(Problem(path, f"must be a string, not {json.dumps(value)}"))
        return None
    return value


def _name_lists(value: Any, path: str, problems: list[Problem], *, pairs: bool) -> list[list[str]]:
    """``aliases`` (a list of two-name lists) or ``[route]`` (one list of names)."""
    if not isinstance(value, list):
        problems.append(Problem(path, "must be a list"))
        return []
    out = []
    for i, item in enumerate(value):
        where = f"{path}[{i}]" if pairs else path
        if not isinstance(item, list) or not all(isinstance(n, str) for n in item):
            problems.append(Problem(where, "must be a list of place names"))
            continue
        if pairs and len(item) != 2:
            problems.append(Problem(where, f"an alias names two places, not {len(item)}"))
            continue
        out.append(list(item))
    return out


def _build(cls: type, item: Any, path: str, problems: list[Problem]) -> Any:
    """One element of a plan list, its fields checked by the dataclass's annotations."""
    import dataclasses

    fields = {f.name: f for f in dataclasses.fields(cls)}
    required = [
        n
        for n, f in fields.items()
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    if not isinstance(item, Mapping):
        problems.append(Problem(path, f"must be an object with {', '.join(required)}"))
        return None
    before = len(problems)
    missing = [n for n in required if n not in item]
    if missing:
        problems.append(Problem(path, f"missing {', '.join(repr(n) for n in missing)}"))
    kwargs: dict[str, Any] = {}
    for key, value in item.items():
        where = f"{path}.{key}"
        f = fields.get(key)
        if f is None:
            problems.append(
                Problem(
                    where, f"unknown field; {cls.__name__.lower()} fields are {', '.join(fields)}"
                )
            )
            continue
        kind = str(f.type)
        if kind == "float":
            kwargs[key] = _number(value, where, problems)
        elif kind == "str":
            kwargs[key] = _text(value, where, problems)
        elif value is None:
            kwargs[key] = None  # ``moved: null``: stays put
        elif isinstance(value, list) and len(value) == 3:
            triple = [_number(v, f"{where}[{k}]", problems) for k, v in enumerate(value)]
            kwargs[key] = tuple(triple)
        else:
            problems.append(Problem(where, "must be [dx, dy, dyaw] (metres, metres, radians)"))
    if len(problems) > before:
        return None
    return cls(**kwargs)


def check_condition(condition: str) -> None:
    """Raise :class:`PlanError` unless ``condition`` is one of :data:`CONDITIONS`."""
    if condition not in CONDITIONS:
        raise PlanError(f"unknown condition {condition!r}; use one of {', '.join(CONDITIONS)}")
