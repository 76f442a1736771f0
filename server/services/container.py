"""Everything the routes and the dashboard share: one object built by ``create_app``."""

from __future__ import annotations

from dataclasses import dataclass

from server.imaging import ImageLimits
from server.services.teaching import TeachingService
from server.services.tours import RobotService, TourService
from server.storage.repo import Repo


@dataclass
class Services:
    repo: Repo
    admin_token: str
    limits: ImageLimits
    tours: TourService
    robots: RobotService
    teaching: TeachingService

    @classmethod
    def build(cls, repo: Repo, *, admin_token: str, limits: ImageLimits) -> Services:
        return cls(
            repo=repo,
            admin_token=admin_token,
            limits=limits,
            tours=TourService(repo),
            robots=RobotService(repo),
            teaching=TeachingService(repo, limits),
        )

    def close(self) -> None:
        self.repo.close()
