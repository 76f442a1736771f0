"""Tours, robots and images: create, list, read."""

from __future__ import annotations

from collections.abc import Sequence

from server import schemas
from server.errors import Conflict, IntegrityViolation, NotFound
from server.security import hash_token, new_token
from server.services.households import Identities
from server.storage.repo import EdgeRow, LocationRow, Pose, Repo, RobotRow


def location_public(loc: LocationRow) -> schemas.LocationPublic:
    return schemas.LocationPublic(
        id=loc.id,
        name=loc.name,
        image_count=len(loc.image_ids),
        image_ids=list(loc.image_ids),
        poses=_poses(loc.poses),
        entropy=_entropy(loc.entropy),
    )


def _poses(poses: Sequence[Pose | None]) -> list[list[float]] | None:
    """Every image's pose, or ``None`` unless every image has one."""
    if not poses or any(p is None for p in poses):
        return None
    return [[round(v, 4) for v in p] for p in poses if p is not None]


def _entropy(entropy: Sequence[float | None]) -> list[float] | None:
    """Every image's entropy, or ``None`` unless every image has one."""
    if not entropy or any(h is None for h in entropy):
        return None
    return [round(h, 4) for h in entropy if h is not None]


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
        poses=_poses(edge.poses),
        entropy=_entropy(edge.entropy),
    )


def robot_public(row: RobotRow, household: str) -> schemas.RobotPublic:
    return schemas.RobotPublic(
        name=row.name,
        created_at=row.created_at,
        household=household,
        token_active=row.token_active,
        token_issued_at=row.token_issued_at,
    )


class TourService:
    """Tours of one household at a time: every call names the household that asks."""

    def __init__(self, repo: Repo) -> None:
        self.repo = repo

    def create(self, body: schemas.TourCreate, household: int) -> schemas.TourSummary:
        with self.repo.transaction():
            if self.repo.tour_by_name(body.name, household) is not None:
                raise Conflict(f"a tour named {body.name!r} exists already; pick another name")
            row = self.repo.add_tour(body.name, household)
        return schemas.TourSummary(id=row.id, name=row.name, locations=0, edges=0, images=0)

    def list(self, household: int) -> list[schemas.TourSummary]:
        return [
            schemas.TourSummary(id=t.id, name=t.name, locations=nl, edges=ne, images=ni)
            for t, nl, ne, ni in self.repo.tours(household)
        ]

    def graph(self, tour_id: int, household: int | None) -> schemas.TourGraphPublic:
        """The tour's graph; 404 when ``household`` (unless ``None``) does not own it."""
        with self.repo.snapshot():
            tour = self.repo.tour(tour_id, household)
            locations = self.repo.locations(tour_id)
            edges = self.repo.edges(tour_id)
        names = {loc.id: loc.name for loc in locations}
        return schemas.TourGraphPublic(
            id=tour.id,
            name=tour.name,
            locations=[location_public(loc) for loc in locations],
            edges=[edge_public(e, names) for e in edges],
        )

    def image_jpeg(self, image_id: int, household: int) -> bytes:
        """The stored JPEG; 404 when it does not exist or another household owns it."""
        if self.repo.image_household(image_id) != household:
            raise NotFound(f"no image with id {image_id}")
        return self.repo.image_jpeg(image_id)


class RobotService:
    """Registration and the token lifecycle (list, rotate, revoke) of robots."""

    def __init__(self, repo: Repo, identities: Identities) -> None:
        self.repo = repo
        self.identities = identities

    def register(self, body: schemas.RobotCreate, household: int) -> schemas.RobotRegistered:
        token = new_token()
        try:
            with self.repo.transaction():
                self.repo.household(household)  # 404 when unknown
                if self.repo.robot_exists(body.name):
                    raise Conflict(
                        f"a robot named {body.name!r} is registered already; pick another name"
                    )
                self.repo.add_robot(body.name, hash_token(token), household)
        except IntegrityViolation as exc:  # pragma: no cover - token hash collision
            raise Conflict("could not register the robot; retry") from exc
        return schemas.RobotRegistered(name=body.name, token=token)

    def list(self, household: int | None) -> list[schemas.RobotPublic]:
        """The robots of ``household`` (every robot with ``None``: the admin), no secrets."""
        with self.repo.snapshot():
            names = {h.id: h.name for h in self.repo.households()}
            rows = self.repo.robots(household)
        return [robot_public(r, names[r.household_id]) for r in rows]

    def rotate(self, robot: str) -> schemas.RobotRegistered:
        """A new token for ``robot``; the old one fails from now on."""
        token = new_token()
        with self.repo.transaction():
            self.repo.robot(robot)
            self.repo.set_robot_token(robot, hash_token(token))
        self.identities.forget_robot(robot)
        return schemas.RobotRegistered(name=robot, token=token)

    def revoke(self, robot: str) -> schemas.RobotPublic:
        """The robot's token fails from now on (cached ones too), until it is rotated."""
        with self.repo.transaction():
            self.repo.robot(robot)
            self.repo.set_robot_token(robot, None)
            row = self.repo.robot(robot)
            household = self.repo.household(row.household_id).name
        self.identities.forget_robot(robot)
        return robot_public(row, household)
