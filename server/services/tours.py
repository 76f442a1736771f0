"""Tours, robots and images: create, list, read."""

from __future__ import annotations

import sqlite3

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
        with self.repo.transaction():  # one consistent snapshot
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


class RobotService:
    def __init__(self, repo: Repo) -> None:
        self.repo = repo

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
