"""``teachrepeat sim generate --seed S --out FILE [--png OUT]``: a home nobody designed.

A generated home is an ordinary floor plan (:mod:`robot_client.sim.floorplan`) drawn by
:func:`generate_plan` from ``numpy.random.default_rng(seed)`` alone and the generator's own
vocabulary, ``generate_catalogue.toml`` (room kinds, their sizes, textures and furniture):

1. **rooms**: 3 to 10 (a day room and a cooking room, one open-plan room at some rate, a wet
   room, a sleeping room, then more sleeping rooms, studies, a second wet room, a hall), in one
   or two rows, along a corridor between the rows in most homes of 5 rooms or more;
2. **doors**: a spanning tree over the rooms that share enough wall (through the corridor, hall
   or day room first; a wet room gets one door), plus a few second ways between rooms;
3. **furniture** of each kind against the walls and clear of the doorways (a bed with its
   nightstands, a sofa with its coffee table, counters with wall cabinets, a table with chairs,
   ...), some pieces standing elsewhere under ``moved``; a room is furnished again until every
   spot where a robot could start is joined to its doorways, as taught and as moved;
4. **textures and pictures**: floors and wall paints from the kind's lists (dry rooms often share
   the home's main paint), pictures on free stretches of wall;
5. **look-alike rooms** at some rate: two rooms of one kind, of one size, furnished, textured and
   hung alike (mirrored when their doors are), declared as ``aliases``;
6. **places**: one or two per room, named after the room (``"<kind> 2"``; a second place in a room
   adds the side of the room it is on, ``"<kind> 2 east"``), where the robot fits with room to
   spare as taught and as moved; the first place is in the hall (or the day room).

The layout is turned and mirrored at random. A draw is kept only if the plan passes every check
of ``check-plan`` (:func:`robot_client.sim.plancheck.check_plan`) and a teaching route can be
derived from it; otherwise the same generator draws again, :attr:`GenerateParams.max_draws`
times at most. The JSON is written with a fixed key order and rounding (:func:`plan_json`): a
seed gives the same bytes on any machine with the same NumPy (whose ``Generator`` streams do not
depend on the platform).

``bench navigate --generated K --seed S`` runs the homes of seeds ``1000 * S + k`` for
k = 0 .. K-1 (:func:`derived_seed`); ``sim generate --seed 1000 * S + k`` makes one of them alone.

Frame and units as in :mod:`robot_client.sim.floorplan` (metres, radians, x east, y north).
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import itertools
import json
import math
import os
import sys
import time
import tomllib
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

CATALOGUE = Path(__file__).with_name("generate_catalogue.toml")
"""The generator's vocabulary: room kinds, sizes, textures, furniture."""

SEED_STRIDE = 1000
"""Home ``k`` of ``bench navigate --generated K --seed S`` has seed ``SEED_STRIDE * S + k``."""

DEFAULT_FOLDER = Path("data") / "cache" / "generated"
"""Where ``bench navigate --generated`` writes its homes (relative to the working directory)."""

WALL_T = 0.06
"""Wall panel thickness of a generated home, metres (the plans' default)."""
GAP = 0.03
"""A piece against a wall stands this far from its face, metres."""

Vec = tuple[int, int]
"""A direction as an integer vector, ``(1, 0)`` east ... ``(-1, -1)`` south-west: exact under
the layout's turns and mirrors."""

_NORMALS: dict[str, Vec] = {"S": (0, 1), "N": (0, -1), "W": (1, 0), "E": (-1, 0)}
"""Into the room from each of its walls."""


class GenerateError(RuntimeError):
    """No draw from the seed gave a valid home; the message says what the last draws lacked."""


@dataclass(frozen=True)
class GenerateParams:
    """How the generator checks a draw (the home's proportions are in the catalogue).

    Attributes:
        max_draws: draws from the seed's generator before giving up.
        room_draws: times a room is furnished again before the draw is abandoned.
        piece_tries: positions tried for one piece of furniture.
        door_depth_m: nothing stands this far into a room in front of a doorway, metres.
        door_side_m: ... nor this far beside its jambs, metres.
        guide_clearance_m: the teaching guide's clearance: doorways of a room are joined at it
            as taught, metres (:data:`robot_client.sim.paths.GUIDE_CLEARANCE_M`).
        passage_m: a robot's radius plus margin: every start spot is joined to the doorways at
            it, as taught and as moved, metres.
        start_clearance_m: where a trial may start (``robot_client.trial.START_CLEARANCE_M``).
        place_clearance_m: a place keeps this far from walls and furniture, as taught and as
            moved, metres.
        place_from_door_m: and this far from a doorway's centre, metres.
        grid_m: cell of the rooms' clearance grids, metres.
    """

    max_draws: int = 25
    room_draws: int = 8
    piece_tries: int = 14
    door_depth_m: float = 0.9
    door_side_m: float = 0.2
    guide_clearance_m: float = 0.3
    passage_m: float = 0.23
    start_clearance_m: float = 0.35
    place_clearance_m: float = 0.45
    place_from_door_m: float = 0.9
    grid_m: float = 0.05


@dataclass(frozen=True)
class GeneratedHome:
    """A generated plan: ``data`` is its JSON form, ``text`` the bytes written (UTF-8);
    ``rejected`` says why each earlier draw from the seed was not kept."""

    seed: int
    draws: int
    data: dict[str, Any]
    text: str
    rejected: tuple[str, ...] = ()

    @property
    def sha256(self) -> str:
        """SHA-256 of the file's bytes (what ``load_plan`` and the benchmarks record)."""
        return hashlib.sha256(self.text.encode()).hexdigest()


def derived_seed(seed: int, k: int) -> int:
    """The seed of home ``k`` (from 0) of ``bench navigate --generated K --seed seed``."""
    if not 0 <= k < SEED_STRIDE:
        raise ValueError(f"at most {SEED_STRIDE} generated homes per seed, not home {k}")
    return SEED_STRIDE * seed + k


@functools.cache
def catalogue() -> dict[str, Any]:
    """The generator's vocabulary (``generate_catalogue.toml``), read once."""
    with CATALOGUE.open("rb") as f:
        return tomllib.load(f)


# -- geometry ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Rect:
    """An axis-aligned rectangle ``[x0, x1] x [y0, y1]``, metres."""

    x0: float
    y0: float
    x1: float
    y1: float

    @property
    def w(self) -> float:
        return self.x1 - self.x0

    @property
    def h(self) -> float:
        return self.y1 - self.y0

    @property
    def cx(self) -> float:
        return (self.x0 + self.x1) / 2

    @property
    def cy(self) -> float:
        return (self.y0 + self.y1) / 2

    def overlaps(self, o: _Rect, margin: float = 0.0) -> bool:
        return (
            self.x0 < o.x1 + margin
            and o.x0 < self.x1 + margin
            and self.y0 < o.y1 + margin
            and o.y0 < self.y1 + margin
        )

    def within(self, o: _Rect) -> bool:
        e = 1e-9
        return (
            self.x0 >= o.x0 - e
            and self.x1 <= o.x1 + e
            and self.y0 >= o.y0 - e
            and self.y1 <= o.y1 + e
        )

    def shrink(self, west: float, south: float, east: float, north: float) -> _Rect:
        return _Rect(self.x0 + west, self.y0 + south, self.x1 - east, self.y1 - north)


def _box(cx: float, cy: float, ex: float, ey: float) -> _Rect:
    """The rectangle centred at ``(cx, cy)`` extending ``ex`` by ``ey`` metres."""
    return _Rect(cx - ex / 2, cy - ey / 2, cx + ex / 2, cy + ey / 2)


@dataclass(frozen=True)
class _Affine:
    """``p -> m @ p + c`` with ``m`` a signed permutation (turns and mirrors of the layout)."""

    m: tuple[tuple[int, int], tuple[int, int]] = ((1, 0), (0, 1))
    c: tuple[float, float] = (0.0, 0.0)

    def point(self, x: float, y: float) -> tuple[float, float]:
        (a, b), (d, e) = self.m
        return a * x + b * y + self.c[0], d * x + e * y + self.c[1]

    def vec(self, v: Vec) -> Vec:
        (a, b), (d, e) = self.m
        return a * v[0] + b * v[1], d * v[0] + e * v[1]

    def rect(self, r: _Rect) -> _Rect:
        ax, ay = self.point(r.x0, r.y0)
        bx, by = self.point(r.x1, r.y1)
        return _Rect(min(ax, bx), min(ay, by), max(ax, bx), max(ay, by))

    @property
    def det(self) -> int:
        (a, b), (d, e) = self.m
        return a * e - b * d

    def inverse(self) -> _Affine:
        (a, b), (d, e) = self.m
        inv = _Affine(((a, d), (b, e)))  # a signed permutation's inverse is its transpose
        cx, cy = inv.point(*self.c)
        return _Affine(inv.m, (-cx, -cy))


def _side(r: _Rect, x: float, y: float) -> str:
    """Which wall of the rectangle ``r`` the point ``(x, y)`` (a doorway) is on."""
    if abs(y - r.y0) < 1e-6:
        return "S"
    if abs(y - r.y1) < 1e-6:
        return "N"
    return "W" if abs(x - r.x0) < 1e-6 else "E"


def _angle(v: Vec) -> float:
    """The heading of an integer direction, radians in (-pi, pi]."""
    return math.atan2(v[1], v[0])


# -- what a draw is made of ------------------------------------------------------------------------


@dataclass
class _Piece:
    """A piece of furniture while it is placed (``up``: its local +y, the way a sofa faces)."""

    name: str
    kind: str
    rect: _Rect
    up: Vec
    h: float
    texture: str
    sx: float
    sy: float
    z: float = 0.0
    moved: tuple[float, float, float] | None = None
    movable: bool = False
    side: str | None = None  # the wall it stands against
    rests_on: str | None = None  # the piece it stands on (overlap allowed)

    @property
    def solid(self) -> bool:
        return self.kind != "rug"

    def moved_rect(self) -> _Rect:
        """Its footprint's bounding box under ``moved``."""
        if self.moved is None:
            return self.rect
        dx, dy, dyaw = self.moved
        c, s = abs(math.cos(dyaw)), abs(math.sin(dyaw))
        ex = c * self.rect.w + s * self.rect.h
        ey = s * self.rect.w + c * self.rect.h
        return _box(self.rect.cx + dx, self.rect.cy + dy, ex, ey)


@dataclass
class _Zone:
    """A part of a room furnished as one kind (an open-plan room has two)."""

    kind: str
    rect: _Rect
    walls: tuple[str, ...]  # sides of the zone that are the room's walls


@dataclass
class _Door:
    x: float
    y: float
    width: float
    rooms: tuple[int, int]


@dataclass
class _Picture:
    x: float
    y: float
    facing: Vec
    width: float
    height: float
    z: float
    texture: str


@dataclass
class _Place:
    zone_kind: str
    x: float
    y: float
    facing: Vec
    name: str = ""


@dataclass
class _Room:
    kinds: tuple[str, ...]  # one per zone; the first names the room
    rect: _Rect
    floor: str = ""
    wall: str = ""
    zones: list[_Zone] = field(default_factory=list)
    pieces: list[_Piece] = field(default_factory=list)
    pictures: list[_Picture] = field(default_factory=list)
    places: list[_Place] = field(default_factory=list)
    name: str = ""

    @property
    def kind(self) -> str:
        return self.kinds[0]


class _Reject(Exception):
    """This draw cannot become a home (the generator draws again)."""


# -- the draw --------------------------------------------------------------------------------------


class _Draw:
    """One attempt at a home from the shared generator."""

    def __init__(self, rng: np.random.Generator, params: GenerateParams) -> None:
        self.rng = rng
        self.params = params
        self.cat = catalogue()
        self.home = self.cat["home"]
        self.kinds: dict[str, dict[str, Any]] = self.cat["kinds"]
        self.rooms: list[_Room] = []
        self.doors: list[_Door] = []
        self.alike: tuple[int, int] | None = None
        self.alike_map: _Affine | None = None
        self.wall_height = 2.5

    # random helpers
    def u(self, lo_hi: Sequence[float], step: float = 0.01) -> float:
        lo, hi = float(lo_hi[0]), float(lo_hi[1])
        return round(round(float(self.rng.uniform(lo, hi)) / step) * step, 4)

    def between(self, lo: float, hi: float) -> float:
        """Uniform in ``[lo, hi]`` (``lo`` when rounding left ``hi`` a hair below it)."""
        return float(self.rng.uniform(lo, max(lo, hi)))

    def pick(self, items: Sequence[Any]) -> Any:
        return items[int(self.rng.integers(len(items)))]

    def chance(self, p: float) -> bool:
        return bool(self.rng.random() < p)

    def role(self, kind: str) -> str:
        return str(self.kinds[kind]["role"])

    # 1. rooms ------------------------------------------------------------------------------------

    def programme(self) -> tuple[list[tuple[str, ...]], bool]:
        """The rooms' kinds (a tuple of zone kinds per room) and whether there is a corridor."""
        lo, hi = self.home["rooms"]
        n = int(self.rng.integers(lo, hi + 1))
        rates = self.home["corridor"]
        corridor = n >= 5 and self.chance(rates[0] if n <= 6 else rates[1])
        by_role = {self.role(k): k for k in self.kinds}
        open_plan = n == 3 or self.chance(self.home["open_plan"])
        rooms: list[tuple[str, ...]] = (
            [(by_role["day"], by_role["cook"])]
            if open_plan
            else [(by_role["day"],), (by_role["cook"],)]
        )
        rooms += [(by_role["wet"],), (by_role["sleep"],)]
        counts = {k: sum(r == (k,) for r in rooms) for k in self.kinds}
        while len(rooms) + corridor < n:
            extra = [k for k, v in self.kinds.items() if v.get("extra") and counts[k] < v["max"]]
            weights = np.array([self.kinds[k]["extra"] for k in extra], dtype=np.float64)
            kind = extra[int(self.rng.choice(len(extra), p=weights / weights.sum()))]
            counts[kind] += 1
            rooms.append((kind,))
        return rooms, corridor

    def layout(self) -> None:
        """Rooms as rectangles in one or two rows (with a corridor between them)."""
        specs, corridor = self.programme()
        self.wall_height = self.u(self.home["wall_height"], 0.05)
        sizes = []
        for kinds in specs:
            w = sum(self.u(self.kinds[k]["width"], 0.05) for k in kinds)
            if len(kinds) > 1:
                w = round(w * 0.9 / 0.05) * 0.05
            d = max(self.u(self.kinds[k]["depth"], 0.05) for k in kinds)
            sizes.append([w, d])
        # look-alike rooms: two of an alike kind, the same size, in one row
        alike_kinds = [k for k, v in self.kinds.items() if v.get("alike")]
        pair = None
        for k in alike_kinds:
            idx = [i for i, s in enumerate(specs) if s == (k,)]
            if len(idx) >= 2:
                pair = (idx[0], idx[1])
                break
        if pair is not None and self.chance(self.home["alike"]):
            sizes[pair[1]] = list(sizes[pair[0]])
        else:
            pair = None
        public = {"day", "cook", "hub"}
        rows: list[list[int]]
        if corridor or len(specs) > 3 or not self.chance(self.home["one_row"]):
            rows = [
                [i for i, s in enumerate(specs) if self.role(s[0]) in public],
                [i for i, s in enumerate(specs) if self.role(s[0]) not in public],
            ]
            self._balance(rows, sizes, pair)
        else:
            rows = [list(range(len(specs)))]
        for row in rows:
            order = list(self.rng.permutation(len(row)))
            row[:] = [row[int(k)] for k in order]
            if pair is not None and pair[0] in row:  # side by side, like a guest room
                row.remove(pair[1])
                row.insert(row.index(pair[0]) + 1, pair[1])
        lengths = [sum(sizes[i][0] for i in row) for row in rows]
        length = max(lengths)
        depth_lo, depth_hi = self.home["row_depth_m"]
        jagged = self.chance(self.home["jagged"])
        y = 0.0
        placed: dict[int, _Rect] = {}
        passage: _Rect | None = None
        for r, row in enumerate(rows):
            if r == 1 and corridor:
                width = self.u(self.home["passage_m"], 0.05)
                passage = _Rect(0.0, y, round(length, 2), round(y + width, 2))
                y = passage.y1
            depth = min(max(max(sizes[i][1] for i in row), depth_lo), depth_hi)
            depth = round(depth / 0.05) * 0.05
            stretch = min(length / lengths[r], 1.2)
            widths = [round(sizes[i][0] * stretch / 0.05) * 0.05 for i in row]
            total = sum(widths)
            x = 0.0 if total >= length - 1e-6 or self.chance(0.5) else length - total
            for i, w in zip(row, widths, strict=True):
                d = depth
                if jagged:  # each room as deep as it wants; the rows meet along a straight line
                    d = round(min(max(sizes[i][1], depth_lo), depth_hi) / 0.05) * 0.05
                y0 = y + depth - d if r == 0 and len(rows) > 1 else y
                placed[i] = _Rect(round(x, 2), round(y0, 2), round(x + w, 2), round(y0 + d, 2))
                x += w
            y += depth
        self.rooms = [_Room(tuple(specs[i]), placed[i]) for i in range(len(specs))]
        if passage is not None:
            kind = next(k for k in self.kinds if self.role(k) == "passage")
            self.rooms.append(_Room((kind,), passage))
        self.alike = pair
        for room in self.rooms:
            room.zones = self._zones(room)

    def _balance(self, rows: list[list[int]], sizes: list[list[float]], pair: Any) -> None:
        """Move rooms from the longer row to the shorter while that evens them out."""
        for _ in range(10):
            lengths = [sum(sizes[i][0] for i in row) for row in rows]
            long, short = (0, 1) if lengths[0] > lengths[1] else (1, 0)
            gap = lengths[long] - lengths[short]
            best = None
            for i in rows[long]:
                group = [i] if pair is None or i not in pair else list(pair)
                if not all(g in rows[long] for g in group) or len(rows[long]) <= len(group):
                    continue
                w = sum(sizes[g][0] for g in group)
                if abs(gap - 2 * w) < gap - 1e-6 and (best is None or w < best[0]):
                    best = (w, group)
            if best is None:
                return
            for g in best[1]:
                rows[long].remove(g)
                rows[short].append(g)

    def _zones(self, room: _Room) -> list[_Zone]:
        r = room.rect
        if len(room.kinds) == 1:
            return [_Zone(room.kind, r, ("S", "N", "W", "E"))]
        # open plan: split along the longer side, the cooking zone the smaller part
        share = self.u((0.38, 0.45), 0.05)
        cook_first = self.chance(0.5)
        if r.w >= r.h:
            cut = round(r.x0 + r.w * (share if cook_first else 1 - share), 2)
            west, east = _Rect(r.x0, r.y0, cut, r.y1), _Rect(cut, r.y0, r.x1, r.y1)
            parts = [(west, ("S", "N", "W")), (east, ("S", "N", "E"))]
        else:
            cut = round(r.y0 + r.h * (share if cook_first else 1 - share), 2)
            south, north = _Rect(r.x0, r.y0, r.x1, cut), _Rect(r.x0, cut, r.x1, r.y1)
            parts = [(south, ("S", "W", "E")), (north, ("N", "W", "E"))]
        if cook_first:
            parts.reverse()
        day, cook = room.kinds
        return [_Zone(day, *parts[1]), _Zone(cook, *parts[0])]

    # 2. doors ------------------------------------------------------------------------------------

    def shared_walls(self) -> dict[tuple[int, int], tuple[str, float, float, float]]:
        """For rooms that touch: (axis of the wall, its coordinate, the shared stretch)."""
        out = {}
        for i, j in itertools.combinations(range(len(self.rooms)), 2):
            a, b = self.rooms[i].rect, self.rooms[j].rect
            for ax, bx in ((a.x1, b.x0), (a.x0, b.x1)):
                if abs(ax - bx) < 1e-6:
                    lo, hi = max(a.y0, b.y0), min(a.y1, b.y1)
                    if hi > lo:
                        out[(i, j)] = ("x", ax, lo, hi)
            for ay, by in ((a.y1, b.y0), (a.y0, b.y1)):
                if abs(ay - by) < 1e-6:
                    lo, hi = max(a.x0, b.x0), min(a.x1, b.x1)
                    if hi > lo:
                        out[(i, j)] = ("y", ay, lo, hi)
        return out

    def connect(self) -> None:
        """Doors: a spanning tree (cheapest through corridors and halls), then second ways."""
        shared = self.shared_walls()
        widths = self.home["door_widths"]
        wide = self.home["wide_door_widths"]
        cost: dict[tuple[int, int], float] = {}
        width: dict[tuple[int, int], float] = {}
        for (i, j), (_, _, lo, hi) in shared.items():
            roles = {self.role(self.rooms[i].kind), self.role(self.rooms[j].kind)}
            w = float(self.pick(wide if _wide(roles) else widths))
            if hi - lo < w + 0.7:
                continue
            cost[(i, j)] = float(self.rng.random()) + _door_cost(roles)
            width[(i, j)] = w
        parent = list(range(len(self.rooms)))

        def root(k: int) -> int:
            while parent[k] != k:
                parent[k] = parent[parent[k]]
                k = parent[k]
            return k

        degree = [0] * len(self.rooms)
        chosen: list[tuple[int, int]] = []
        order = sorted(cost, key=lambda e: cost[e])
        for strict in (True, False):
            for i, j in order:
                if root(i) == root(j):
                    continue
                wet = [k for k in (i, j) if self.role(self.rooms[k].kind) == "wet"]
                if strict and any(degree[k] >= 1 for k in wet):
                    continue
                parent[root(i)] = root(j)
                degree[i] += 1
                degree[j] += 1
                chosen.append((i, j))
        if len({root(k) for k in range(len(self.rooms))}) > 1:
            raise _Reject("the rooms cannot all be joined by doors")
        for e in order:
            roles = {self.role(self.rooms[k].kind) for k in e}
            if e in chosen or "wet" in roles or not roles & {"day", "cook", "hub", "passage"}:
                continue  # one door to a wet room; no second way between bedrooms
            common = roles in ({"day", "cook"}, {"hub", "passage"})
            rate = 0.7 if common else self.home["extra_door"]
            if self.chance(rate):
                chosen.append(e)
        for i, j in sorted(chosen):
            axis, at, lo, hi = shared[(i, j)]
            w = width[(i, j)]
            a, b = lo + w / 2 + 0.35, hi - w / 2 - 0.35
            along = self.pick((a, b)) if self.chance(0.4) else self.between(a, b)
            along = round(along / 0.05) * 0.05
            along = min(max(along, math.ceil(a / 0.05) * 0.05), math.floor(b / 0.05) * 0.05)
            x, y = (at, along) if axis == "x" else (along, at)
            self.doors.append(_Door(round(x, 2), round(y, 2), w, (i, j)))

    def doors_of(self, room: int) -> list[_Door]:
        return [d for d in self.doors if room in d.rooms]

    def keep_outs(self, room: _Room, doors: Sequence[_Door]) -> list[_Rect]:
        """In front of and beside each doorway of the room: no furniture (a door swings)."""
        p = self.params
        out = []
        for d in doors:
            half = d.width / 2 + p.door_side_m
            side = _side(room.rect, d.x, d.y)
            r = room.rect
            if side == "S":
                out.append(_Rect(d.x - half, r.y0, d.x + half, r.y0 + p.door_depth_m))
            elif side == "N":
                out.append(_Rect(d.x - half, r.y1 - p.door_depth_m, d.x + half, r.y1))
            elif side == "W":
                out.append(_Rect(r.x0, d.y - half, r.x0 + p.door_depth_m, d.y + half))
            else:
                out.append(_Rect(r.x1 - p.door_depth_m, d.y - half, r.x1, d.y + half))
        return out

    def align_alike_doors(self) -> None:
        """Give the second look-alike room its door where the first has its own (mirrored),
        when both have one door and the wall there allows it."""
        if self.alike is None:
            return
        a, b = self.alike
        ra, rb = self.rooms[a].rect, self.rooms[b].rect
        da, db = self.doors_of(a), self.doors_of(b)
        if len(da) != 1 or len(db) != 1:
            return
        shared = self.shared_walls()
        other = db[0].rooms[0] if db[0].rooms[1] == b else db[0].rooms[1]
        axis, at, lo, hi = shared[tuple(sorted((b, other)))]  # type: ignore[index]
        for mirror in (False, True):
            m = self._room_map(ra, rb, mirror)
            x, y = m.point(da[0].x, da[0].y)
            along, across = (y, x) if axis == "x" else (x, y)
            w = db[0].width
            if abs(across - at) < 1e-6 and lo + w / 2 + 0.35 <= along <= hi - w / 2 - 0.35:
                db[0].x, db[0].y = round(x, 2), round(y, 2)
                db[0].width = da[0].width
                return

    def _room_map(self, a: _Rect, b: _Rect, mirror: bool) -> _Affine:
        """Room ``a`` onto room ``b`` (of the same size), mirrored across the rows' direction."""
        if not mirror:
            return _Affine(((1, 0), (0, 1)), (b.x0 - a.x0, b.y0 - a.y0))
        return _Affine(((-1, 0), (0, 1)), (a.x1 + b.x0, b.y0 - a.y0))

    # 3. furniture --------------------------------------------------------------------------------

    def furnish(self) -> None:
        textures = self.home["paints"]
        main_paint = self.pick(textures)
        for k, room in enumerate(self.rooms):
            if self.alike is not None and k == self.alike[1]:
                continue
            spec = self.kinds[room.kind]
            room.floor = self.pick(spec["floors"])
            dry = self.role(room.kind) not in ("wet", "cook")
            if dry and main_paint in spec["walls"] and self.chance(self.home["main_paint"]):
                room.wall = main_paint
            else:
                room.wall = self.pick(spec["walls"])
            self._furnish_room(k)
        if self.alike is not None:
            self._copy_alike()

    def _furnish_room(self, k: int) -> None:
        room = self.rooms[k]
        doors = self.doors_of(k)
        blocked = self.keep_outs(room, doors)
        partner = None
        if self.alike is not None and k == self.alike[0]:
            partner = self.alike[1]
            self.alike_map = self._alike_map()
            back = self.alike_map.inverse()
            other = self.rooms[partner]
            blocked += [back.rect(r) for r in self.keep_outs(other, self.doors_of(partner))]
        for _ in range(self.params.room_draws):
            room.pieces = []
            for zone in room.zones:
                for spec in self.kinds[zone.kind].get("furniture", []):
                    self._place_spec(room, zone, spec, blocked)
            self._move_some(room, blocked)
            view = self.check_room(room, doors)
            if view is None or not all(view.spots(z, self.params).any() for z in room.zones):
                continue
            if partner is not None and self.alike_map is not None:
                copy = self._mapped_pieces(room.pieces, self.alike_map)
                other = self.rooms[partner]
                trial = replace(other, pieces=copy)
                if self.check_room(trial, self.doors_of(partner)) is None:
                    continue
            return
        raise _Reject(f"no furnishing of a {room.kind} keeps it passable")

    def _alike_map(self) -> _Affine:
        """The room map between the look-alike rooms that best lines their doors up."""
        assert self.alike is not None
        a, b = self.alike
        ra, rb = self.rooms[a].rect, self.rooms[b].rect
        best = None
        for mirror in (False, True):
            m = self._room_map(ra, rb, mirror)
            cost = 0.0
            for d in self.doors_of(a):
                x, y = m.point(d.x, d.y)
                cost += min((math.dist((x, y), (e.x, e.y)) for e in self.doors_of(b)), default=9)
            if best is None or cost < best[0] - 1e-9:
                best = (cost, m)
        assert best is not None
        return best[1]

    def _place_spec(
        self, room: _Room, zone: _Zone, spec: dict[str, Any], blocked: list[_Rect]
    ) -> None:
        if "p" in spec and not self.chance(spec["p"]):
            return
        if "unless" in spec and any(p.name == spec["unless"] for p in room.pieces):
            return
        lo, hi = spec.get("count", [1, 1])
        count = int(self.rng.integers(lo, hi + 1))
        rule = spec["rule"]
        flip = self.chance(0.5)  # which side of its anchor a "beside" piece takes first
        anchor = None
        if "of" in spec:
            anchor = next((p for p in room.pieces if p.name == spec["of"]), None)
            if anchor is None and rule in ("beside", "front", "on"):
                return
        for n in range(count):
            name = spec["name"] if n == 0 else f"{spec['name']} {n + 1}"
            for _ in range(self.params.piece_tries):
                piece = self._candidate(zone, spec, name, anchor, n != flip)
                if piece is None:
                    continue
                if self._fits(room, zone, piece, blocked):
                    room.pieces.append(piece)
                    if rule == "island":
                        self._chairs(room, zone, spec, piece, blocked)
                    break

    def _inner(self, zone: _Zone) -> _Rect:
        """Where furniture may stand in a zone: off the walls' faces (and off an open side)."""
        g = WALL_T + GAP
        s = {side: (g if side in zone.walls else 0.1) for side in ("W", "S", "E", "N")}
        return zone.rect.shrink(s["W"], s["S"], s["E"], s["N"])

    def _against(
        self, zone: _Zone, side: str, along: float, sx: float, sy: float, offset: float = 0.0
    ) -> _Rect:
        """The footprint of a piece ``sx`` wide and ``sy`` deep, its back ``offset`` off the
        wall ``side`` of the zone, centred at ``along`` on it."""
        i = self._inner(zone)
        if side == "S":
            return _Rect(along - sx / 2, i.y0 + offset, along + sx / 2, i.y0 + offset + sy)
        if side == "N":
            return _Rect(along - sx / 2, i.y1 - offset - sy, along + sx / 2, i.y1 - offset)
        if side == "W":
            return _Rect(i.x0 + offset, along - sx / 2, i.x0 + offset + sy, along + sx / 2)
        return _Rect(i.x1 - offset - sy, along - sx / 2, i.x1 - offset, along + sx / 2)

    def _along_range(self, zone: _Zone, side: str) -> tuple[float, float]:
        i = self._inner(zone)
        return (i.x0, i.x1) if side in ("S", "N") else (i.y0, i.y1)

    def _candidate(
        self,
        zone: _Zone,
        spec: dict[str, Any],
        name: str,
        anchor: _Piece | None,
        first_side: bool,
    ) -> _Piece | None:
        """A position for one piece by its rule (:func:`_fits` says whether it may stand there)."""
        rule = spec["rule"]
        sx = self.u(spec["sx"]) if "sx" in spec else 0.0
        sy, h = self.u(spec["sy"]), self.u(spec["h"], 0.005)
        texture = self.pick(spec["textures"])
        wall_facing = spec.get("facing") == "wall"
        movable = bool(spec.get("moves"))

        def piece(rect: _Rect, side: str | None, up: Vec, **kw: Any) -> _Piece:
            size = kw.pop("sx", sx)
            return _Piece(
                name, spec["kind"], rect, up, h, texture, size, sy, movable=movable, side=side, **kw
            )

        if rule in ("wall", "corner"):
            if not zone.walls:
                return None
            side = self.pick(zone.walls)
            a, b = self._along_range(zone, side)
            if b - a < sx:
                return None
            end = rule == "corner" or self.chance(0.4)
            if end:
                along = self.pick((a + sx / 2, b - sx / 2))
            else:
                along = self.between(a + sx / 2, b - sx / 2)
            along = round(along, 2)
            normal = _NORMALS[side]
            up = (-normal[0], -normal[1]) if wall_facing else normal
            offset = 0.0 if rule == "wall" else 0.02
            return piece(self._against(zone, side, along, sx, sy, offset), side, up)
        if anchor is None or anchor.side is None:
            if rule == "island":
                return self._island(zone, spec, name, sx, sy, h, texture)
            if rule == "rug":
                i = self._inner(zone).shrink(0.3, 0.3, 0.3, 0.3)
                if i.w < sx or i.h < sy:
                    return None
                x = self.between(i.x0 + sx / 2, i.x1 - sx / 2)
                y = self.between(i.y0 + sy / 2, i.y1 - sy / 2)
                return piece(_box(round(x, 2), round(y, 2), sx, sy), None, (0, 1))
            return None
        side, normal = anchor.side, _NORMALS[anchor.side]
        along_a = anchor.rect.cx if side in ("S", "N") else anchor.rect.cy
        depth_a = anchor.sy
        up = (-normal[0], -normal[1]) if wall_facing else normal
        if rule == "beside":
            half = anchor.sx / 2 + 0.04 + sx / 2
            along = along_a + (half if first_side else -half)
            head = anchor.up != normal  # a bed's head is at the wall: nightstands there
            offset = 0.0 if head else depth_a - sy
            return piece(self._against(zone, side, round(along, 2), sx, sy, offset), side, up)
        if rule == "front":
            gap = self.u(spec["gap"])
            return piece(
                self._against(zone, side, round(along_a, 2), sx, sy, depth_a + gap), side, up
            )
        if rule == "on":
            if "z" in spec:  # above its whole length, against the wall (wall cabinets)
                rect = self._against(zone, side, round(along_a, 2), anchor.sx, sy, 0.0)
                z = self.u(spec["z"])
                return piece(rect, side, normal, sx=anchor.sx, z=z, rests_on=anchor.name)
            width = min(sx, anchor.sx - 0.1)
            offset = min(0.1, max(0.0, (depth_a - sy) / 2))
            rect = self._against(zone, side, round(along_a, 2), width, sy, offset)
            return piece(rect, side, normal, sx=width, z=anchor.h, rests_on=anchor.name)
        if rule == "rug":  # in front of the anchor
            rect = self._against(zone, side, round(along_a, 2), sx, sy, depth_a - 0.2)
            return piece(rect, None, normal)
        return None

    def _island(
        self,
        zone: _Zone,
        spec: dict[str, Any],
        name: str,
        sx: float,
        sy: float,
        h: float,
        texture: str,
    ) -> _Piece | None:
        i = self._inner(zone).shrink(0.75, 0.75, 0.75, 0.75)
        along_x = self.chance(0.5)
        ex, ey = (sx, sy) if along_x else (sy, sx)
        if i.w < ex or i.h < ey:
            return None
        x = round(self.between(i.x0 + ex / 2, i.x1 - ex / 2), 2)
        y = round(self.between(i.y0 + ey / 2, i.y1 - ey / 2), 2)
        up: Vec = (0, 1) if along_x else (1, 0)
        return _Piece(
            name,
            spec["kind"],
            _box(x, y, ex, ey),
            up,
            h,
            texture,
            sx,
            sy,
            movable=bool(spec.get("moves")),
        )

    def _chairs(
        self, room: _Room, zone: _Zone, spec: dict[str, Any], table: _Piece, blocked: list[_Rect]
    ) -> None:
        lo, hi = spec.get("chairs", [0, 0])
        want = int(self.rng.integers(lo, hi + 1))
        t = table.rect
        size = self.u((0.42, 0.47))
        h = self.u((0.86, 0.94), 0.005)
        texture = self.pick(spec.get("chair_textures", spec["textures"]))
        gap = 0.06 + size / 2
        slots: list[tuple[float, float, Vec]] = [
            (t.cx, t.y0 - gap, (0, 1)),
            (t.cx, t.y1 + gap, (0, -1)),
            (t.x0 - gap, t.cy, (1, 0)),
            (t.x1 + gap, t.cy, (-1, 0)),
        ]
        order = [int(k) for k in self.rng.permutation(len(slots))]
        placed = 0
        for k in order:
            if placed >= want:
                break
            x, y, up = slots[k]
            name = f"{table.name} chair" + ("" if placed == 0 else f" {placed + 1}")
            chair = _Piece(
                name,
                "chair",
                _box(round(x, 2), round(y, 2), size, size),
                up,
                h,
                texture,
                size,
                size,
                movable=table.movable,
            )
            if self._fits(room, zone, chair, blocked):
                room.pieces.append(chair)
                placed += 1

    def _fits(self, room: _Room, zone: _Zone, piece: _Piece, blocked: list[_Rect]) -> bool:
        inner = self._inner(zone)
        if not piece.rect.within(inner):
            return False
        if not piece.solid:
            return True
        if any(piece.rect.overlaps(b) for b in blocked):
            return False
        for other in room.pieces:
            if not other.solid or piece.rests_on == other.name or other.rests_on == piece.name:
                continue
            if other.rests_on is not None:
                continue  # it stands on a piece that is checked
            for a, b in ((piece.rect, other.rect), (piece.rect, other.moved_rect())):
                if a.overlaps(b, 0.04):
                    return False
        return True

    def _move_some(self, room: _Room, blocked: list[_Rect]) -> None:
        """Some movable pieces get where they stand under ``moved``: each at the catalogue's
        rate, and at least one in every room that has any (as in the shipped homes)."""
        movable = [p for p in room.pieces if p.movable]
        order = [movable[int(k)] for k in self.rng.permutation(len(movable))]
        chosen = [p for p in order if self.chance(self.home["moved"])]
        for piece in chosen + [p for p in order if p not in chosen]:
            if piece not in chosen and any(p.moved is not None for p in movable):
                break  # the rest stay put once one has moved
            self._move(room, piece, blocked)

    def _move(self, room: _Room, piece: _Piece, blocked: list[_Rect]) -> None:
        """Where ``piece`` stands under ``moved``: 0.2-0.6 m away, turned, clear of the rest."""
        zone = next(z for z in room.zones if piece.rect.within(z.rect))
        inner = self._inner(zone)
        lo, hi = self.home["moved_m"]
        for _ in range(10):
            dx, dy = (round(float(v), 2) for v in self.rng.uniform(-hi, hi, 2))
            if not lo <= math.hypot(dx, dy) <= hi:
                continue
            turn = 0.0 if piece.kind == "plant" else self.u(self.home["moved_yaw"])
            piece.moved = (dx, dy, round(turn if self.chance(0.5) else -turn, 2))
            rect = piece.moved_rect()
            clash = not rect.within(inner) or any(rect.overlaps(b) for b in blocked)
            for other in room.pieces:
                if clash or other is piece or not other.solid:
                    continue
                clash = rect.overlaps(other.rect, 0.04) or rect.overlaps(other.moved_rect(), 0.04)
            if not clash:
                return
            piece.moved = None

    def check_room(self, room: _Room, doors: Sequence[_Door]) -> _RoomView | None:
        """The room's clearance as taught and as moved, if every start spot is joined to its
        doorways (and the doorways to each other at the guide's clearance); else ``None``."""
        return _RoomView.build(room, doors, self.params)

    def _mapped_pieces(self, pieces: Sequence[_Piece], m: _Affine) -> list[_Piece]:
        out = []
        for p in pieces:
            moved = None
            if p.moved is not None:
                dx, dy = m.vec((1, 0)), m.vec((0, 1))
                mx = dx[0] * p.moved[0] + dy[0] * p.moved[1]
                my = dx[1] * p.moved[0] + dy[1] * p.moved[1]
                moved = (round(mx, 2) + 0.0, round(my, 2) + 0.0, p.moved[2] * m.det + 0.0)
            side = None
            if p.side is not None:
                normal = m.vec(_NORMALS[p.side])
                side = next(s for s, v in _NORMALS.items() if v == normal)
            out.append(replace(p, rect=m.rect(p.rect), up=m.vec(p.up), moved=moved, side=side))
        return out

    def _copy_alike(self) -> None:
        assert self.alike is not None and self.alike_map is not None
        a, b = (self.rooms[k] for k in self.alike)
        b.floor, b.wall = a.floor, a.wall
        b.pieces = self._mapped_pieces(a.pieces, self.alike_map)

    # 4. pictures ---------------------------------------------------------------------------------

    def hang(self) -> None:
        textures = list(self.home["picture_textures"])
        order = [textures[int(k)] for k in self.rng.permutation(len(textures))]
        for k, room in enumerate(self.rooms):
            if self.alike is not None and k == self.alike[1]:
                continue
            doors = self.doors_of(k)
            if self.alike is not None and k == self.alike[0] and self.alike_map is not None:
                back = self.alike_map.inverse()
                other = self.doors_of(self.alike[1])
                doors = doors + [_Door(*back.point(d.x, d.y), d.width, d.rooms) for d in other]
            for zone in room.zones:
                lo, hi = self.kinds[zone.kind]["pictures"]
                for _ in range(int(self.rng.integers(lo, hi + 1))):
                    if not order:
                        order = [textures[int(k)] for k in self.rng.permutation(len(textures))]
                    picture = self._picture(room, zone, doors, order[-1])
                    if picture is not None:
                        room.pictures.append(picture)
                        order.pop()
        if self.alike is not None and self.alike_map is not None:
            a, b = (self.rooms[k] for k in self.alike)
            m = self.alike_map
            b.pictures = [
                replace(p, x=m.point(p.x, p.y)[0], y=m.point(p.x, p.y)[1], facing=m.vec(p.facing))
                for p in a.pictures
            ]

    def _picture(
        self, room: _Room, zone: _Zone, doors: Sequence[_Door], texture: str
    ) -> _Picture | None:
        home = self.home
        for _ in range(8):
            if not zone.walls:
                return None
            side = self.pick(zone.walls)
            width, height = self.u(home["picture_widths"]), self.u(home["picture_heights"])
            z = self.u(home["picture_z"])
            bottom = z - height / 2
            a, b = self._along_range(zone, side)
            if b - a < width + 0.4:
                continue
            along = round(self.between(a + width / 2 + 0.2, b - width / 2 - 0.2), 2)
            span = (along - width / 2 - 0.1, along + width / 2 + 0.1)
            if any(
                _side(room.rect, d.x, d.y) == side and _hits(span, d, side, d.width / 2)
                for d in doors
            ):
                continue
            behind = [
                p for p in room.pieces if p.solid and p.side == side and p.z + p.h > bottom - 0.05
            ]
            if any(_covers(p, side, span) for p in behind):
                continue
            if any(
                q.facing == _NORMALS[side]
                and abs(_along(q, side) - along) < (q.width + width) / 2 + 0.25
                for q in room.pictures
            ):
                continue
            r = room.rect
            x, y = {
                "S": (along, r.y0 + WALL_T),
                "N": (along, r.y1 - WALL_T),
                "W": (r.x0 + WALL_T, along),
                "E": (r.x1 - WALL_T, along),
            }[side]
            return _Picture(round(x, 3), round(y, 3), _NORMALS[side], width, height, z, texture)
        return None

    # 6. places -----------------------------------------------------------------------------------

    def name_places(self) -> None:
        for k, room in enumerate(self.rooms):
            if self.alike is not None and k == self.alike[1]:
                continue
            view = self.check_room(room, self.doors_of(k))
            if view is None:
                raise _Reject("a furnished room is no longer passable")
            area = room.rect.w * room.rect.h
            alike = self.alike is not None and k in self.alike
            for zone in room.zones:
                two = (
                    len(room.zones) == 1
                    and not alike
                    and self.role(zone.kind) != "passage"
                    and len(self.doors_of(k)) <= 2
                    and area >= self.home["two_places_m2"]
                    and self.chance(self.home["two_places"])
                )
                for _ in range(2 if two else 1):
                    spot = view.place(self.rng, zone, room.places, self.params)
                    if spot is None:
                        if not room.places or zone.kind not in {p.zone_kind for p in room.places}:
                            raise _Reject(f"no room for a place in a {zone.kind}")
                        break
                    x, y, facing = spot
                    room.places.append(_Place(zone.kind, x, y, facing))
        if self.alike is not None and self.alike_map is not None:
            a, b = (self.rooms[k] for k in self.alike)
            m = self.alike_map
            b.places = [
                replace(p, x=m.point(p.x, p.y)[0], y=m.point(p.x, p.y)[1], facing=m.vec(p.facing))
                for p in a.places
            ]
            view = self.check_room(b, self.doors_of(self.alike[1]))
            if view is None or not all(view.fits(p.x, p.y, self.params) for p in b.places):
                raise _Reject("the look-alike room's places do not fit")


def _wide(roles: set[str]) -> bool:
    return "day" in roles and bool(roles & {"cook", "hub", "passage"})


def _door_cost(roles: set[str]) -> float:
    """How unlikely a door between rooms of these roles is (added to a random draw)."""
    if roles == {"hub", "passage"}:
        return -0.5  # a hall opens onto the corridor
    if roles & {"passage", "hub"}:
        return 0.0 if "wet" not in roles or "passage" in roles else 1.0
    if roles == {"day", "cook"}:
        return 0.2
    if "day" in roles:
        return 1.5 if "wet" in roles else 0.8
    if roles == {"wet", "sleep"}:
        return 1.8
    if "wet" in roles:
        return 4.0
    if "cook" in roles:
        return 2.5
    return 2.0


def _hits(span: tuple[float, float], d: _Door, side: str, half: float) -> bool:
    c = d.x if side in ("S", "N") else d.y
    return span[0] < c + half and c - half < span[1]


def _along(p: _Picture, side: str) -> float:
    return p.x if side in ("S", "N") else p.y


def _covers(p: _Piece, side: str, span: tuple[float, float]) -> bool:
    lo, hi = (p.rect.x0, p.rect.x1) if side in ("S", "N") else (p.rect.y0, p.rect.y1)
    return span[0] < hi and lo < span[1]


# -- a room's clearance ----------------------------------------------------------------------------


@dataclass
class _RoomView:
    """Clearance over a room's grid as taught and as moved, and the component of its doors."""

    room: _Room
    doors: tuple[_Door, ...]
    xs: np.ndarray
    ys: np.ndarray
    same: np.ndarray
    moved: np.ndarray
    joined: np.ndarray  # cells joined to the doorways: by a robot as taught and as moved, and
    # by the guide as taught

    @classmethod
    def build(cls, room: _Room, doors: Sequence[_Door], params: GenerateParams) -> _RoomView | None:
        from scipy import ndimage

        from robot_client.sim.floorplan import Door, FloorPlan, Room
        from robot_client.sim.world import PlanGeometry

        r = room.rect
        plan = FloorPlan(
            name="room",
            rooms=(Room("room", r.x0, r.y0, r.x1, r.y1),),
            doors=tuple(Door(d.x, d.y, d.width) for d in doors),
            furniture=tuple(_furniture(p, p.name) for p in room.pieces if p.solid),
            pictures=(),
            places=(),
            wall_thickness=WALL_T,
        )
        g = params.grid_m
        xs = r.x0 + (np.arange(max(1, math.ceil(r.w / g))) + 0.5) * g
        ys = r.y0 + (np.arange(max(1, math.ceil(r.h / g))) + 0.5) * g
        gx, gy = np.meshgrid(xs, ys)
        clear = {
            c: PlanGeometry(plan, condition=c).clearance_map(gx, gy) for c in ("same", "moved")
        }
        eight = np.ones((3, 3), dtype=bool)

        def cell(x: float, y: float) -> tuple[int, int]:
            i = int(np.clip((y - r.y0) / g, 0, len(ys) - 1))
            j = int(np.clip((x - r.x0) / g, 0, len(xs) - 1))
            return i, j

        inside = []  # a cell just inside each doorway
        for d in doors:
            nx, ny = _NORMALS[_side(r, d.x, d.y)]
            inside.append(cell(d.x + nx * 0.12, d.y + ny * 0.12))
        start = (clear["same"] >= params.start_clearance_m) & (
            clear["moved"] >= params.start_clearance_m
        )
        joined = np.ones(gx.shape, dtype=bool)
        checks = [
            ("same", params.guide_clearance_m, False),
            ("same", params.passage_m, True),
            ("moved", params.passage_m, True),
        ]
        for condition, clearance, starts in checks:
            labels, _ = ndimage.label(clear[condition] >= clearance, structure=eight)
            at_doors = {int(labels[c]) for c in inside}
            if 0 in at_doors or len(at_doors) > 1:
                return None
            (label,) = at_doors
            if starts and np.any(start & (labels != label)):
                return None
            joined &= labels == label
        return cls(room, tuple(doors), xs, ys, clear["same"], clear["moved"], joined)

    def fits(self, x: float, y: float, params: GenerateParams) -> bool:
        r = self.room.rect
        g = params.grid_m
        i = int(np.clip((y - r.y0) / g, 0, len(self.ys) - 1))
        j = int(np.clip((x - r.x0) / g, 0, len(self.xs) - 1))
        need = params.place_clearance_m - g
        return bool(self.joined[i, j] and min(self.same[i, j], self.moved[i, j]) >= need)

    def spots(self, zone: _Zone, params: GenerateParams) -> np.ndarray:
        """Cells of ``zone`` where a place may be: joined to the doorways, with room to spare as
        taught and as moved, away from the doorways (a boolean grid)."""
        gx, gy = np.meshgrid(self.xs, self.ys)
        z = zone.rect
        ok = (
            self.joined
            & (np.minimum(self.same, self.moved) >= params.place_clearance_m)
            & (gx > z.x0)
            & (gx < z.x1)
            & (gy > z.y0)
            & (gy < z.y1)
        )
        for d in self.doors:
            ok &= np.hypot(gx - d.x, gy - d.y) >= params.place_from_door_m
        return ok

    def place(
        self,
        rng: np.random.Generator,
        zone: _Zone,
        taken: Sequence[_Place],
        params: GenerateParams,
    ) -> tuple[float, float, Vec] | None:
        """A spot for a place in ``zone`` (:meth:`spots`) at least 1.8 m from the places
        already there, and facing across the room (one of the longest wall-wise views)."""
        gx, gy = np.meshgrid(self.xs, self.ys)
        ok = self.spots(zone, params)
        for p in taken:
            ok &= np.hypot(gx - p.x, gy - p.y) >= 1.8
        ii, jj = np.nonzero(ok)
        if ii.size == 0:
            return None
        k = int(rng.integers(ii.size))
        x, y = round(float(self.xs[jj[k]]), 2), round(float(self.ys[ii[k]]), 2)
        # face across the room: one of the wall-wise directions with the longest views
        reach = []
        dirs: list[Vec] = [(1, 0), (0, 1), (-1, 0), (0, -1)]
        for v in dirs:
            i, j = ii[k], jj[k]
            t = 0
            while 0 <= i < len(self.ys) and 0 <= j < len(self.xs) and self.same[i, j] >= 0.05:
                i, j, t = i + v[1], j + v[0], t + 1
            reach.append(t)
        best = max(reach)
        good = [v for v, t in zip(dirs, reach, strict=True) if t >= 0.7 * best]
        return x, y, good[int(rng.integers(len(good)))]


def _furniture(p: _Piece, name: str) -> Any:
    from robot_client.sim.floorplan import Furniture

    return Furniture(
        name=name,
        kind=p.kind,
        x=p.rect.cx,
        y=p.rect.cy,
        sx=p.sx,
        sy=p.sy,
        h=p.h,
        yaw=_yaw(p.up),
        texture=p.texture,
        moved=p.moved,
        z=p.z,
    )


def _yaw(up: Vec) -> float:
    """The yaw of a piece whose local +y points along ``up`` (radians, in (-pi, pi])."""
    yaw = _angle(up) - math.pi / 2
    if yaw <= -math.pi:
        yaw += 2 * math.pi
    return yaw


# -- the plan as JSON ------------------------------------------------------------------------------


def _num(v: float, digits: int = 3) -> float:
    return round(float(v), digits) + 0.0  # no -0.0


def _layout_map(rng: np.random.Generator, rooms: Sequence[_Room]) -> _Affine:
    """A random turn or mirror of the whole layout, keeping it in the first quadrant."""
    w = max(r.rect.x1 for r in rooms)
    h = max(r.rect.y1 for r in rooms)
    transpose, flip_x, flip_y = (bool(b) for b in rng.random(3) < 0.5)
    rows = [[1, 0], [0, 1]]
    if transpose:
        rows = [[0, 1], [1, 0]]
        w, h = h, w
    c = [0.0, 0.0]
    if flip_x:
        rows[0] = [-v for v in rows[0]]
        c[0] = w
    if flip_y:
        rows[1] = [-v for v in rows[1]]
        c[1] = h
    return _Affine(((rows[0][0], rows[0][1]), (rows[1][0], rows[1][1])), (c[0], c[1]))


def _assemble(draw: _Draw, seed: int, attempt: int) -> dict[str, Any]:
    """The draw as a plan's JSON form, turned and mirrored at random, rooms and places named."""
    _turn(draw, _layout_map(draw.rng, draw.rooms))
    rooms = sorted(draw.rooms, key=lambda r: (round(r.rect.y0, 2), round(r.rect.x0, 2)))
    zone_names = _name(draw, rooms)
    furniture = [f for room in rooms for f in _furniture_json(room, zone_names)]
    pictures = [_picture_json(q) for room in rooms for q in room.pictures]
    places = [q for room in rooms for q in room.places]
    for role in ("hub", "day"):  # the tour starts in the hall, or else in the day room
        lead = [q for q in places if draw.role(q.zone_kind) == role]
        if lead:
            places.remove(lead[0])
            places.insert(0, lead[0])
            break
    aliases, alike = [], ""
    if draw.alike is not None:
        a, b = (draw.rooms[k] for k in draw.alike)
        aliases = [[a.places[0].name, b.places[0].name]]
        alike = f"Look-alike rooms: {a.name} and {b.name}. "
    notes = (
        f"Generated by `teachrepeat sim generate --seed {seed}` (draw {attempt}): "
        f"{', '.join(r.name for r in rooms)}. {alike}Units: metres, radians; x east, y north. "
        "Textures are names from robot_client/sim/textures.py."
    )
    return {
        "name": f"generated {seed}",
        "notes": notes,
        "wall_height": _num(draw.wall_height),
        "wall_thickness": WALL_T,
        "aliases": aliases,
        "rooms": [
            {
                "name": r.name,
                "x0": _num(r.rect.x0),
                "y0": _num(r.rect.y0),
                "x1": _num(r.rect.x1),
                "y1": _num(r.rect.y1),
                "floor": r.floor,
                "wall": r.wall,
            }
            for r in rooms
        ],
        "doors": [
            {"x": _num(d.x), "y": _num(d.y), "width": _num(d.width)}
            for d in sorted(draw.doors, key=lambda d: (round(d.y, 2), round(d.x, 2)))
        ],
        "places": [
            {"name": q.name, "x": _num(q.x), "y": _num(q.y), "yaw": _num(_angle(q.facing), 4)}
            for q in places
        ],
        "furniture": furniture,
        "pictures": pictures,
    }


def _turn(draw: _Draw, m: _Affine) -> None:
    """Apply ``m`` to everything the draw placed."""
    for room in draw.rooms:
        room.rect = m.rect(room.rect)
        for zone in room.zones:
            zone.rect = m.rect(zone.rect)
        room.pieces = draw._mapped_pieces(room.pieces, m)
        for picture in room.pictures:
            picture.x, picture.y = m.point(picture.x, picture.y)
            picture.facing = m.vec(picture.facing)
        for place in room.places:
            place.x, place.y = m.point(place.x, place.y)
            place.facing = m.vec(place.facing)
    for door in draw.doors:
        door.x, door.y = m.point(door.x, door.y)


def _name(draw: _Draw, rooms: Sequence[_Room]) -> dict[int, str]:
    """Name rooms and places ``"<kind> <n>"`` in reading order (two places in a room add the
    side of the room each is on); returns each zone's name by ``id``."""
    counters: Counter[str] = Counter()
    zone_names: dict[int, str] = {}
    for room in rooms:
        for zone in room.zones:
            counters[zone.kind] += 1
            zone_names[id(zone)] = f"{draw.kinds[zone.kind]['name']} {counters[zone.kind]}"
        room.name = zone_names[id(room.zones[0])]
        for zone in room.zones:
            mine = [q for q in room.places if q.zone_kind == zone.kind]
            for q in mine:
                q.name = zone_names[id(zone)]
            if len(mine) == 2:
                a, b = mine
                if abs(a.x - b.x) >= abs(a.y - b.y):
                    west, east = (a, b) if a.x < b.x else (b, a)
                    west.name, east.name = f"{west.name} west", f"{east.name} east"
                else:
                    south, north = (a, b) if a.y < b.y else (b, a)
                    south.name, north.name = f"{south.name} south", f"{north.name} north"
    return zone_names


def _furniture_json(room: _Room, zone_names: dict[int, str]) -> list[dict[str, Any]]:
    """The room's pieces, each named after its zone (``"<kind> <n>/<piece>"``, unique)."""
    out, taken = [], set()
    for piece in room.pieces:
        cx, cy = piece.rect.cx, piece.rect.cy
        zone = next(
            (
                z
                for z in room.zones
                if z.rect.x0 <= cx <= z.rect.x1 and z.rect.y0 <= cy <= z.rect.y1
            ),
            room.zones[0],
        )
        name, k = f"{zone_names[id(zone)]}/{piece.name}", 2
        while name in taken:
            name, k = f"{zone_names[id(zone)]}/{piece.name} {k}", k + 1
        taken.add(name)
        out.append(_piece_json(piece, name))
    return out


def _picture_json(q: _Picture) -> dict[str, Any]:
    return {
        "x": _num(q.x),
        "y": _num(q.y),
        "yaw": _num(_angle(q.facing), 4),
        "width": _num(q.width),
        "height": _num(q.height),
        "z": _num(q.z),
        "texture": q.texture,
    }


def _piece_json(p: _Piece, name: str) -> dict[str, Any]:
    out: dict[str, Any] = {
        "name": name,
        "kind": p.kind,
        "x": _num(p.rect.cx),
        "y": _num(p.rect.cy),
        "sx": _num(p.sx),
        "sy": _num(p.sy),
        "h": _num(p.h),
    }
    yaw = _num(_yaw(p.up), 4)
    if yaw:
        out["yaw"] = yaw
    if p.z:
        out["z"] = _num(p.z)
    out["texture"] = p.texture
    if p.moved is not None:
        out["moved"] = [_num(v) for v in p.moved]
    return out


def plan_json(data: dict[str, Any]) -> str:
    """A plan's JSON text as the shipped plans are written: top-level keys in a fixed order,
    one room, door, place, piece or picture per line; the same data gives the same bytes."""
    lines = ["{"]
    items = list(data.items())
    for k, (key, value) in enumerate(items):
        end = "," if k < len(items) - 1 else ""
        if isinstance(value, list) and value and isinstance(value[0], dict):
            inner = ",\n".join(f"    {json.dumps(v, ensure_ascii=False)}" for v in value)
            lines.append(f"  {json.dumps(key)}: [\n{inner}\n  ]{end}")
        else:
            lines.append(f"  {json.dumps(key)}: {json.dumps(value, ensure_ascii=False)}{end}")
    lines.append("}")
    return "\n".join(lines) + "\n"


# -- generating ------------------------------------------------------------------------------------


def _problems(text: str) -> list[str]:
    """Why the plan written as ``text`` cannot be used (empty: it passes every check)."""
    from robot_client.sim.floorplan import PlanError, plan_from_dict
    from robot_client.sim.route import RouteError, derive_route

    try:
        plan = plan_from_dict(json.loads(text))
    except PlanError as exc:
        return [str(p) for p in exc.problems] or [str(exc)]
    try:
        derive_route(plan)
    except RouteError as exc:
        return [str(exc)]
    return []


def generate_plan(seed: int, params: GenerateParams = GenerateParams()) -> GeneratedHome:
    """A valid random home from ``seed`` alone (see the module docstring).

    Raises:
        GenerateError: no draw of ``params.max_draws`` passed the checks; the message says
            what the last draws lacked.
    """
    if seed < 0:
        raise ValueError(f"a seed is a whole number >= 0, not {seed}")
    rng = np.random.default_rng(seed)
    reasons: list[str] = []
    for attempt in range(1, params.max_draws + 1):
        draw = _Draw(rng, params)
        try:
            draw.layout()
            draw.connect()
            draw.align_alike_doors()
            draw.furnish()
            draw.hang()
            draw.name_places()
        except _Reject as exc:
            reasons.append(str(exc))
            continue
        data = _assemble(draw, seed, attempt)
        text = plan_json(data)
        problems = _problems(text)
        if problems:
            reasons.append("; ".join(problems[:3]))
            continue
        return GeneratedHome(seed, attempt, data, text, tuple(reasons))
    last = "\n".join(
        f"  draw {len(reasons) - k}: {r}" for k, r in enumerate(reversed(reasons[-3:]))
    )
    raise GenerateError(
        f"no valid home from seed {seed} in {params.max_draws} draws; the last ones:\n{last}"
    )


def write_home(home: GeneratedHome, out: Path) -> Path:
    """Write the plan's bytes to ``out`` (its folder created; replaced whole, never half)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    part = out.with_name(f"{out.name}.{os.getpid()}.part")
    part.write_text(home.text, encoding="utf-8")
    part.replace(out)
    return out


def summary(home: GeneratedHome, route_m: float | None = None, legs: int | None = None) -> str:
    """The one-line summary ``sim generate`` prints."""
    data = home.data
    alias = len(data["aliases"])
    line = (
        f"home {data['name']!r} (seed {home.seed}, draw {home.draws}): {len(data['rooms'])} "
        f"rooms, {len(data['doors'])} doors, {len(data['places'])} places, {alias} look-alike "
        f"pair{'' if alias == 1 else 's'}"
    )
    if legs is not None and route_m is not None:
        line += f", teaching route {legs} legs {route_m:.1f} m"
    return line + f"; sha256 {home.sha256[:12]}"


def generated_homes(
    count: int, seed: int, folder: Path, *, log: Any = print
) -> list[tuple[Path, GeneratedHome]]:
    """Homes ``0 .. count-1`` of ``seed`` (:func:`derived_seed`), each written to
    ``folder/generated_<its seed>.json``.

    Raises:
        ValueError: ``count`` is negative or above :data:`SEED_STRIDE`, or ``seed`` negative.
        GenerateError: a seed gave no valid home.
    """
    if count < 0 or count > SEED_STRIDE:
        raise ValueError(f"a run takes 0 to {SEED_STRIDE} generated homes, not {count}")
    out = []
    for k in range(count):
        home = generate_plan(derived_seed(seed, k))
        path = write_home(home, folder / f"generated_{home.seed}.json")
        log(f"{path}: {summary(home)}")
        out.append((path, home))
    return out


def add_bench_arguments(parser: argparse.ArgumentParser) -> None:
    """``--generated K`` and ``--generated-dir DIR`` for a benchmark over generated homes."""
    parser.add_argument(
        "--generated",
        type=int,
        default=0,
        metavar="K",
        help=f"also run K generated homes, of seeds {SEED_STRIDE} x SEED + k for k = 0..K-1 "
        "(teachrepeat sim generate --seed X makes one alone)",
    )
    parser.add_argument(
        "--generated-dir",
        type=Path,
        default=DEFAULT_FOLDER,
        metavar="DIR",
        help=f"where the generated homes are written (default {DEFAULT_FOLDER})",
    )


# -- the command -----------------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seed", type=int, required=True, help="the home's seed (>= 0)")
    parser.add_argument("--out", type=Path, required=True, metavar="FILE", help="plan to write")
    parser.add_argument(
        "--png",
        type=Path,
        default=None,
        metavar="OUT",
        help="draw the map with the teaching route to OUT and the view at every place to "
        "OUT_places.png (as check-plan does)",
    )


def run(args: argparse.Namespace) -> int:
    from robot_client.sim.check_plan import draw
    from robot_client.sim.floorplan import load_plan
    from robot_client.sim.paths import NoPathError
    from robot_client.sim.route import leg_lengths_m, teaching_route

    prog = "teachrepeat sim generate"
    if args.seed < 0:
        print(f"{prog}: --seed must be >= 0, not {args.seed}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    try:
        home = generate_plan(args.seed)
    except GenerateError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 1
    took = time.perf_counter() - t0
    write_home(home, args.out)
    plan = load_plan(args.out)
    route = teaching_route(plan)
    try:
        legs = leg_lengths_m(plan, route)
    except NoPathError as exc:  # check-plan's reachability makes this unreachable
        print(f"{prog}: {exc}", file=sys.stderr)
        return 1
    print(f"{args.out}: {summary(home, sum(legs), len(legs))} ({took:.1f} s)")
    if args.png is not None:
        for path in draw(plan, route, args.png):
            print(f"wrote {path}")
    return 0
