"""Everything the routes and the dashboard share: one object built by ``create_app``."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from server import schemas
from server.imaging import ImageLimits
from server.navigation import NavigationParams
from server.recording.recorder import Recorder
from server.recording.store import RecordingStore, Retention
from server.services.control import ControlParams, ControlService
from server.services.households import HouseholdService, Identities, LoginParams
from server.services.navigation import NavigationService
from server.services.questions import QuestionService
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
    households: HouseholdService
    identities: Identities
    teaching: TeachingService
    navigation: NavigationService
    recordings: Recorder
    questions: QuestionService
    control: ControlService

    @classmethod
    def build(
        cls,
        repo: Repo,
        *,
        admin_token: str,
        limits: ImageLimits,
        navigation: NavigationParams | None = None,
        concurrent_steps: int = 1,
        logins: LoginParams | None = None,
        recordings: Path,
        record_all: bool = False,
        retention: Retention | None = None,
        shared_store: bool = False,
        wall_clock: Callable[[], float] = time.time,
        control: ControlParams | None = None,
    ) -> Services:
        """``recordings``: the folder of the recordings (created on first use);
        ``record_all``: record every teaching tour and navigation task; ``shared_store``: other
        server processes write to the same database (:class:`NavigationService`);
        ``wall_clock``: unix seconds, when questions are asked and expire; ``control``: how
        streaming robots are driven outside navigation (:class:`ControlParams`)."""
        teaching = TeachingService(repo, limits)
        nav = NavigationService(
            repo,
            limits,
            navigation,
            is_teaching=lambda robot: repo.teaching(robot) is not None,
            concurrent_steps=concurrent_steps,
            shared_store=shared_store,
        )
        teaching.is_navigating = nav.is_navigating
        teaching.on_change = nav.tour_changed
        recorder = Recorder(
            RecordingStore(recordings, retention),
            repo,
            record_all=record_all,
            params=nav.params,
        )
        nav.observers.append(recorder)
        teaching.observers.append(recorder)
        questions = QuestionService(
            repo, teaching, nav, limits, nav.params.questions, clock=wall_clock
        )
        nav.observers.append(questions)
        teaching.observers.append(questions)
        identities = Identities(repo)
        driving = ControlService(repo, teaching, nav, limits, control)
        teaching.observers.append(driving)
        return cls(
            repo=repo,
            admin_token=admin_token,
            limits=limits,
            tours=TourService(repo),
            robots=RobotService(repo, identities),
            households=HouseholdService(repo, identities, logins or LoginParams()),
            identities=identities,
            teaching=teaching,
            navigation=nav,
            recordings=recorder,
            questions=questions,
            control=driving,
        )

    def frame(self, robot: str, data: bytes, meta: schemas.FrameMeta) -> schemas.AnyFrameResult:
        """A robot's frame, answered with the command to obey in every mode: kept while
        teaching, stepped while navigating (:meth:`ControlService.frame`)."""
        return self.control.frame(robot, data, meta)

    def robot_state(self, robot: str) -> schemas.RobotState:
        teaching = self.teaching.state(robot)
        navigation = None if teaching else self.navigation.state(robot)
        mode: Literal["idle", "teaching", "navigating"] = "teaching" if teaching else "idle"
        if navigation and navigation.task and navigation.task.state == "underway":
            mode = "navigating"
        return schemas.RobotState(
            name=robot,
            mode=mode,
            teaching=teaching,
            navigation=navigation,
            control=self.control.public(robot),
        )

    def close(self) -> None:
        self.recordings.close()
        self.navigation.close()
        self.repo.close()
