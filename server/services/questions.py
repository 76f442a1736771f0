"""Questions to a person, and what their answers teach the map (issue 25 parts 1 and 5).

One mechanism for two kinds (docs/learning.md):

* ``same_place`` (001 section 10.2), while teaching: after each frame of the open path the
  tracker runs on the tour taught so far (:class:`SamePlaceDetector`); when it is confident the
  robot is at a known place it was not marked at, the robot asks "are we at the kitchen?".
  *Yes* closes the open path there, as if the person had marked that name (a loop closure);
  *no* stores the frame and the place's image as look-alikes, and that place is not asked
  about again on this path, nor again when the same image of it is the best match.
* ``new_path`` (001 section 10.4), while navigating: the frames between leaving one known
  place and reaching another that no taught edge explains (:class:`NewPathDetector`) are kept;
  *yes* adds them as a new edge the planner uses, *no* discards them.

Every answer that changes the map is a learned change of the tour, listed and undone with
``GET/DELETE /tours/{id}/learned`` (:meth:`QuestionService.changes`,
:meth:`QuestionService.remove_change`): the tour's runtime is rebuilt from what remains, so
removing every change gives back exactly the taught behaviour. Questions expire after
``QuestionParams.expiry_s`` on the app's wall clock; an answer to an expired, answered, unknown
or foreign question is refused and changes nothing.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from server import schemas
from server.belief.model import Action
from server.belief.questions import NewPathDetector, QuestionParams, SamePlaceDetector
from server.belief.tracker import Tracker
from server.domain import TourGraph
from server.errors import Conflict, DomainError, Gone, NotFound
from server.imaging import ImageLimits, decode_jpeg, jpeg_size
from server.navigation import TourRuntime
from server.navigation.runtime import preferred
from server.services.navigation import NavigationObserver, NavigationService
from server.services.teaching import MIN_EDGE_IMAGES, TeachingObserver, TeachingService
from server.session import RobotSession, StepRecord
from server.storage.repo import FrameRow, LearnedChangeRow, QuestionRow, Repo
from server.vision.features import ImageFeatures, extract
from server.vision.homing import homing_scale

log = logging.getLogger(__name__)


def change_public(row: LearnedChangeRow) -> schemas.LearnedChange:
    """A stored learned change as the API answers it."""
    return schemas.LearnedChange(
        id=row.id,
        tour=row.tour_id,
        kind=row.kind,  # type: ignore[arg-type]  # repo.LEARNED_KINDS, checked on insert
        created_at=row.created_at,
        source=row.source,
        summary=row.summary,
        images=row.images,
        edge=row.edge_id,
    )


@dataclass
class _Teaching:
    """One teaching robot's tracker on the tour taught so far."""

    runtime: TourRuntime
    tracker: Tracker
    detector: SamePlaceDetector
    start: int | None  # location id the open path starts from
    last_timestamp: float | None = None


@dataclass
class _Exploring:
    """One navigating robot's search for new paths."""

    runtime: TourRuntime
    detector: NewPathDetector
    frames: dict[int, FrameRow] = field(default_factory=dict)
    count: int = 0
    last_timestamp: float | None = None


class QuestionService(TeachingObserver, NavigationObserver):
    """Raises questions (an observer of teaching and of navigation) and applies answers.
    ``clock``: unix seconds (``create_app(wall_clock=...)``)."""

    def __init__(
        self,
        repo: Repo,
        teaching: TeachingService,
        navigation: NavigationService,
        limits: ImageLimits,
        params: QuestionParams,
        *,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.repo = repo
        self.teaching = teaching
        self.navigation = navigation
        self.limits = limits
        self.params = params
        self.clock = clock
        self._teach: dict[str, _Teaching] = {}
        self._explore: dict[str, _Exploring] = {}
        self._lock = threading.Lock()

    # --- teaching: 'same_place' -----------------------------------------------------------

    def teaching_started(self, robot: str, tour_id: int, *, record: bool | None) -> None:
        with self._lock:
            self._teach.pop(robot, None)

    def teaching_marked(self, robot: str, tour_id: int, result: schemas.MarkResult) -> None:
        """A mark answers every open 'same_place' question of the robot (withdrawn) and starts
        a new open path."""
        self.repo.withdraw_questions(robot, "same_place", self.clock())
        with self._lock:
            self._teach.pop(robot, None)

    def teaching_ended(
        self, robot: str, tour_id: int, ended: schemas.TeachingEnded, *, finished: bool
    ) -> None:
        self.repo.withdraw_questions(robot, "same_place", self.clock())
        with self._lock:
            self._teach.pop(robot, None)

    def teaching_image(
        self, robot: str, tour_id: int, data: bytes, meta: schemas.FrameMeta, *, spin: bool
    ) -> None:
        if spin or not self.params.teaching:
            return
        try:
            self._teaching_frame(robot, tour_id, data, meta)
        except DomainError as exc:  # e.g. a tour with no image yet: nothing to recognise
            log.debug("no question for %s: %s", robot, exc.message)

    def _teaching_frame(
        self, robot: str, tour_id: int, data: bytes, meta: schemas.FrameMeta
    ) -> None:
        row = self.repo.teaching(robot)
        if row is None or row.current_location_id is None:
            return
        # never wait for a rebuild here (a robot's frame would time out): the snapshot as last
        # built; the places marked since join when the background rebuild is done
        rt = self.navigation.latest_runtime(tour_id)
        graph = rt.graph
        state = self._teach.get(robot)
        if state is None or state.runtime is not rt:
            state = self._start_tracking(rt, row.current_location_id, state)
            with self._lock:
                self._teach[robot] = state
        image, _, _ = decode_jpeg(data, self.limits)
        features = extract(image, rt.params.features)
        sims, likelihood = rt.observe(features)
        last = state.last_timestamp
        dt = 0.0 if last is None else float(np.clip(meta.timestamp - last, 0.0, rt.params.max_dt_s))
        state.last_timestamp = meta.timestamp
        summary = rt.believe(
            state.tracker, Action.explore(), sims, likelihood, v=meta.v, w=meta.w, dt=dt
        )
        index = {loc.id: k for k, loc in enumerate(graph.locations)}
        start = index.get(state.start) if state.start is not None else None
        now = self.clock()
        self.repo.expire_questions(robot, now)
        asked = {q.location_id for q in self.repo.questions(robot) if q.kind == "same_place"}
        best = preferred(sims, summary).best_image
        declined = self.repo.declined_locations(robot)  # 'no' on this open path, not undone
        skip = {index[i] for i in asked | declined if i in index}
        for k, loc in enumerate(graph.locations):
            b = int(best[k]) if k < len(best) else -1
            if 0 <= b < graph.n_images and int(graph.image_ids[b]) in self.repo.look_alike_images(
                loc.id
            ):
                skip.add(k)
        hit = state.detector.step(
            summary.state,
            graph.n_locations,
            localised_state=summary.localised_state if summary.localised else None,
            start=start,
            skip=frozenset(skip),
        )
        if hit is None or self.repo.pending_count(robot) < MIN_EDGE_IMAGES:
            return
        k, mass = hit
        b = int(best[k]) if k < len(best) else -1
        if not self._view_agrees(features, rt, b):
            return
        place = graph.locations[k]
        self.repo.add_question(
            robot=robot,
            tour_id=tour_id,
            kind="same_place",
            text=f"Are we at {place.name!r}?",
            location_id=place.id,
            source_location_id=state.start,
            image_id=self.repo.last_pending_image(robot),
            match_image_id=int(graph.image_ids[b]) if 0 <= b < graph.n_images else None,
            confidence=mass,
            now=now,
            expires_at=now + self.params.expiry_s,
        )

    def _view_agrees(self, features: ImageFeatures, rt: TourRuntime, image: int) -> bool:
        """Whether the frame and the place's image ``image`` (canonical index) show the same
        scene from about the same spot (``same_place_inliers``, ``same_place_scale``)."""
        p = self.params
        if p.same_place_inliers == 0:
            return True
        if not 0 <= image < len(rt.features):
            return False
        fit = homing_scale(features, rt.features[image])
        return (
            fit is not None
            and fit.inliers >= p.same_place_inliers
            and 1.0 / p.same_place_scale <= fit.scale <= p.same_place_scale
        )

    def _start_tracking(
        self, rt: TourRuntime, location_id: int, previous: _Teaching | None
    ) -> _Teaching:
        """A tracker on ``rt`` that starts at the place the open path leaves from."""
        tracker = Tracker(rt.model, rt.params.tracker)
        k = _location_index(rt.graph, location_id)
        if k is not None:
            belief = np.zeros(rt.model.n_fine)
            belief[k] = 1.0  # a location's fine state is its index
            tracker.set_belief(belief)
        return _Teaching(
            runtime=rt,
            tracker=tracker,
            detector=SamePlaceDetector(self.params),
            start=location_id,
            last_timestamp=previous.last_timestamp if previous is not None else None,
        )

    # --- navigation: 'new_path' -----------------------------------------------------------

    def task_started(
        self, robot: str, session: RobotSession, tour_id: int, *, record: bool | None, resumed: bool
    ) -> None:
        with self._lock:
            self._explore.pop(robot, None)

    def stepped(
        self,
        robot: str,
        session: RobotSession,
        step: StepRecord,
        result: schemas.NavigationFrameResult,
        meta: schemas.FrameMeta,
        wall: float,
    ) -> None:
        if not self.params.exploration or not step.jpeg:
            return
        rt = session.runtime
        state = self._explore.get(robot)
        if state is None or state.runtime is not rt:
            state = _Exploring(rt, NewPathDetector(self.params))
            with self._lock:
                self._explore[robot] = state
        frame = state.count
        state.count += 1
        last, state.last_timestamp = state.last_timestamp, meta.timestamp
        dt = 0.0 if last is None else float(np.clip(meta.timestamp - last, 0.0, rt.params.max_dt_s))
        s = step.summary
        found = state.detector.step(
            frame,
            s.state,
            rt.graph.n_locations,
            localised_state=s.localised_state if s.localised else None,
            evidence=s.evidence,
            v=meta.v,
            w=meta.w,
            dt=dt,
        )
        kept = set(state.detector.frames)
        if frame in kept:
            width, height = jpeg_size(step.jpeg)
            state.frames[frame] = FrameRow(
                meta.timestamp, meta.v, meta.w, width, height, step.jpeg, step.features.to_bytes()
            )
        keep = kept | set(found.frames if found is not None else ())
        for old in [f for f in state.frames if f not in keep]:
            del state.frames[old]
        if found is None:
            return
        frames = [state.frames.pop(f) for f in found.frames if f in state.frames]
        origin, target = rt.graph.locations[found.origin], rt.graph.locations[found.target]
        now = self.clock()
        self.repo.expire_questions(robot, now)
        if any(
            q.kind == "new_path" and (q.source_location_id, q.location_id) == (origin.id, target.id)
            for q in self.repo.questions(robot)
        ):
            return
        self.repo.add_question(
            robot=robot,
            tour_id=self.navigation.tour_of(robot),
            kind="new_path",
            text=(
                f"I found a way from {origin.name!r} to {target.name!r} that I was not taught "
                f"({len(frames)} images). Keep it?"
            ),
            location_id=target.id,
            source_location_id=origin.id,
            image_id=None,
            match_image_id=None,
            confidence=found.confidence,
            now=now,
            expires_at=now + self.params.expiry_s,
            frames=frames,
        )

    # --- requests -------------------------------------------------------------------------

    def open_questions(self, robot: str) -> list[schemas.QuestionPublic]:
        """The robot's questions still waiting for an answer (none past its expiry)."""
        now = self.clock()
        return [self._public(q) for q in self.repo.questions(robot) if q.expires_at > now]

    def answer(
        self, robot: str, question_id: int, body: schemas.QuestionAnswer
    ) -> schemas.QuestionPublic:
        """Apply a person's answer; 404 for a question of another robot or none, 409 when it
        was answered or withdrawn, 410 when it expired. A refused answer changes nothing."""
        with self.repo.transaction():
            q = self.repo.question(question_id)
            if q is None or q.robot != robot:
                raise NotFound(
                    f"robot {robot!r} has no question {question_id}; "
                    f"GET /robots/{robot}/questions lists its open ones"
                )
            now = self.clock()
            if q.state != "open":
                what = {
                    "withdrawn": "was withdrawn (the robot marked a place or stopped teaching "
                    "meanwhile)",
                    "expired": "expired",
                }.get(q.state, f"was already answered {q.state!r}")
                raise Conflict(f"question {question_id} {what}; nothing to answer")
            if q.expires_at <= now:
                raise Gone(
                    f"question {question_id} expired {now - q.expires_at:.0f} s ago (questions "
                    f"stay open {self.params.expiry_s:.0f} s); nothing was changed"
                )
            yes = body.answer == "yes"
            if q.kind == "same_place":
                changed = self._same_place(q, yes, now)
            else:
                changed = self._new_path(q, yes, now)
            answered = self.repo.question(question_id)
        if changed:
            self.navigation.tour_changed(q.tour_id)
        assert answered is not None  # written in the transaction above
        return self._public(answered)

    def changes(self, tour_id: int, household: int) -> list[schemas.LearnedChange]:
        """The tour's learned changes, oldest first (404: not the household's tour)."""
        self.repo.tour(tour_id, household)
        return [change_public(r) for r in self.repo.learned_changes(tour_id)]

    def remove_change(self, tour_id: int, change_id: int, household: int) -> None:
        """Undo one learned change (404: no such change of the household's tour); the tour's
        runtime is rebuilt without it."""
        self.repo.tour(tour_id, household)
        self.repo.remove_learned_change(tour_id, change_id)
        self.navigation.tour_changed(tour_id)

    def _same_place(self, q: QuestionRow, yes: bool, now: float) -> bool:
        place = self.repo.location_name(q.location_id)
        source = f"question {q.id} to robot {q.robot}, asked {_iso(q.created_at)}"
        if not yes:
            change = self.repo.add_learned_change(
                q.tour_id,
                "look_alike",
                source=source,
                summary=f"a view of the path taught only looks like {place!r} (answered no)",
                now=now,
            )
            if q.match_image_id is not None:
                self.repo.add_look_alike(change, q.location_id, q.image_id, q.match_image_id)
            self.repo.close_question(q.id, "no", now=now, change_id=change)
            return False
        row = self.repo.teaching(q.robot)
        if row is None or row.tour_id != q.tour_id:  # pragma: no cover - withdrawn at the end
            raise Conflict(f"robot {q.robot!r} no longer teaches tour {q.tour_id}")
        self.repo.close_question(q.id, "yes", now=now)
        mark = self.teaching.mark(q.robot, schemas.LocationMark(name=place))
        if mark.edge is None:  # pragma: no cover - a question needs an open path
            raise Conflict(f"robot {q.robot!r} has no open path to close at {place!r}")
        start = mark.edge.source_name
        change = self.repo.add_learned_change(
            q.tour_id,
            "loop_closure",
            source=source,
            summary=f"the path taught from {start!r} ends at {place!r} (answered yes)",
            now=now,
            edge_id=mark.edge.id,
        )
        self.repo.set_question_change(q.id, change)
        return True

    def _new_path(self, q: QuestionRow, yes: bool, now: float) -> bool:
        if not yes:
            self.repo.close_question(q.id, "no", now=now)
            return False
        frames = self.repo.question_frames(q.id)
        if len(frames) < MIN_EDGE_IMAGES or q.source_location_id is None:
            raise Conflict(f"question {q.id} has no path left to add")
        edge = self.repo.add_edge_with_images(
            q.tour_id, q.source_location_id, q.location_id, frames
        )
        origin = self.repo.location_name(q.source_location_id)
        target = self.repo.location_name(q.location_id)
        change = self.repo.add_learned_change(
            q.tour_id,
            "new_path",
            source=f"question {q.id} to robot {q.robot}, asked {_iso(q.created_at)}",
            summary=f"a path found by exploration from {origin!r} to {target!r}",
            now=now,
            edge_id=edge,
        )
        self.repo.close_question(q.id, "yes", now=now, change_id=change)
        return True

    def _public(self, q: QuestionRow) -> schemas.QuestionPublic:
        return schemas.QuestionPublic(
            id=q.id,
            robot=q.robot,
            tour=q.tour_id,
            kind=q.kind,  # type: ignore[arg-type]  # written by this service only
            text=q.text,
            location=self.repo.location_name(q.location_id),
            source_location=None
            if q.source_location_id is None
            else self.repo.location_name(q.source_location_id),
            image_id=q.image_id,
            match_image_id=q.match_image_id,
            frames=self.repo.question_frame_count(q.id),
            confidence=round(q.confidence, 4),
            created_at=q.created_at,
            expires_at=q.expires_at,
            state=q.state,  # type: ignore[arg-type]
            change=q.change_id,
        )


def _location_index(graph: TourGraph, location_id: int) -> int | None:
    for k, loc in enumerate(graph.locations):
        if loc.id == location_id:
            return k
    return None


def _iso(t: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t))
