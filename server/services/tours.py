"""Tours, robots and images: create, list, read."""

from __future__ import annotations

import sqlite3
import threading
import time
from collections.abc import Callable

from server import schemas
from server.errors import Conflict
from server.security import hash_token, new_token
from server.storage.repo import EdgeRow, LocationRow, Repo


def location_public(loc: LocationRow) -> schemas.LocationPublic:
    return schemas.LocationPublic(
        id=loc.id, name=loc.name, image_count=len(loc.image_ids), image_ids=list(loc.image_ids)
    )


def edge_public(edge: EdgeRow, names: dict[int, str]) -> schemas.EdgePublic:
    return schemas.EdgePublic(
        id=edge.id,
        source=edge.source_id,
        target=edge.target_id,
        source_name=names[edge.source_id],
        target_name=names[edge.target_id],
        image_count=len(edge.image_ids),
        duration_s=edge.duration,
        length_m=edge.length,
        first_image_id=edge.image_ids[0],
        last_image_id=edge.image_ids[-1],
    )


class TourService:
    def __init__(self, repo: Repo) -> None:
        self.repo = repo

    def create(self, body: schemas.TourCreate) -> schemas.TourSummary:
        with self.repo.transaction():
            if self.repo.tour_by_name(body.name) is not None:
                raise Conflict(f"a tour named {body.name!r} exists already; pick another name")
            row = self.repo.add_tour(body.name)
        return schemas.TourSummary(id=row.id, name=row.name, locations=0, edges=0, images=0)

    def list(self) -> list[schemas.TourSummary]:
        return [
            schemas.TourSummary(id=t.id, name=t.name, locations=nl, edges=ne, images=ni)
            for t, nl, ne, ni in self.repo.tours()
        ]

    def graph(self, tour_id: int) -> schemas.TourGraphPublic:
        with self.repo.snapshot():
            tour = self.repo.tour(tour_id)
            locations = self.repo.locations(tour_id)
            edges = self.repo.edges(tour_id)
        names = {loc.id: loc.name for loc in locations}
        return schemas.TourGraphPublic(
            id=tour.id,
            name=tour.name,
            locations=[location_public(loc) for loc in locations],
            edges=[edge_public(e, names) for e in edges],
        )


TOKEN_CACHE_S = 60.0
"""Seconds a token found in the database is remembered. Tokens are never reissued by the API;
a robot row removed by hand stops authenticating within this time."""


class RobotService:
    def __init__(self, repo: Repo, *, clock: Callable[[], float] = time.monotonic) -> None:
        self.repo = repo
        self.clock = clock
        self._tokens: dict[str, tuple[str, float]] = {}  # token hash -> (robot, found at)
        self._tokens_lock = threading.Lock()

    def cached_robot(self, token_hash: str) -> str | None:
        """The robot of ``token_hash`` if it was found in the database within the last
        :data:`TOKEN_CACHE_S` seconds (no I/O: safe on the event loop); else ``None``."""
        with self._tokens_lock:
            hit = self._tokens.get(token_hash)
            if hit is None:
                return None
            if self.clock() - hit[1] > TOKEN_CACHE_S:
                del self._tokens[token_hash]
                return None
            return hit[0]

    def robot_for_token(self, token_hash: str) -> str | None:
        """The robot whose token hashes to ``token_hash`` (database), or ``None``. Found ones
        are remembered for :meth:`cached_robot`; unknown hashes are not (no memory for a
        caller that tries random tokens)."""
        robot = self.repo.robot_by_token_hash(token_hash)
        if robot is not None:
            with self._tokens_lock:
                self._tokens[token_hash] = (robot, self.clock())
        return robot

    def register(self, body: schemas.RobotCreate) -> schemas.RobotRegistered:
        token = new_token()
        try:
            with self.repo.transaction():
                if self.repo.robot_exists(body.name):
                    raise Conflict(f"a robot named {body.name!r} is registered already")
                self.repo.add_robot(body.name, hash_token(token))
        except sqlite3.IntegrityError as exc:  # pragma: no cover - token hash collision
            raise Conflict("could not register the robot; retry") from exc
        return schemas.RobotRegistered(name=body.name, token=token)

    def list(self) -> list[schemas.RobotPublic]:
        return [
            schemas.RobotPublic(name=r.name, created_at=r.created_at) for r in self.repo.robots()
        ]
