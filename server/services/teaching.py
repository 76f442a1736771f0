"""Teaching: a small state machine per robot, persisted so a crash loses at most one frame.

``start`` -> mark the starting place -> frames are appended to the open path ->
``mark "X"`` closes the open path as the edge (previous place -> X), creating X when new ->
spin images belong to X -> more frames open the next path from X -> ... -> ``finish``.

Every place needs an image to be recognised and driven to. A place reached by a path that has
none yet gets the path's last frame (what the robot saw arriving); the first spin image posted
there replaces that copy, so a client that posts spin images (``robot teach``, the guide) gets
exactly its spin images. The starting place has no path: it needs a spin image, and ``finish``
(like ``goto``) refuses a place without an image, saying how to give it one.

Every step that changes the graph is one transaction: an edge appears with all its images or
not at all, and an aborted path is discarded, never stored as a broken edge.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from server import schemas
from server.errors import Conflict, Invalid
from server.imaging import ImageLimits, decode_jpeg
from server.services.tours import TourService, edge_public, location_public
from server.storage.repo import Repo, TeachingRow

MIN_EDGE_IMAGES = 2

log = logging.getLogger(__name__)


class TeachingObserver:
    """Told of every teaching step after it committed (the recordings: :mod:`server.recording`).
    Each method does nothing here; an observer overrides those it needs. A method that raises
    is logged and never fails the robot's request."""

    def teaching_started(self, robot: str, tour_id: int, *, record: bool | None) -> None:
        """``robot`` began teaching ``tour_id``; ``record``: the tour's own recording choice
        (``None``: the server's setting)."""

    def teaching_image(
        self, robot: str, tour_id: int, data: bytes, meta: schemas.FrameMeta, *, spin: bool
    ) -> None:
        """A frame of the open path, or a spin image of the current place, was stored."""

    def teaching_marked(self, robot: str, tour_id: int, result: schemas.MarkResult) -> None:
        """A place was named ("this is the kitchen")."""

    def teaching_ended(
        self, robot: str, tour_id: int, ended: schemas.TeachingEnded, *, finished: bool
    ) -> None:
        """Teaching finished (``finished``) or was aborted."""


class TeachingService:
    """Teaching steps of every robot. ``on_change(tour_id)`` runs after each change to a graph."""

    def __init__(
        self,
        repo: Repo,
        limits: ImageLimits,
        *,
        is_navigating: Callable[[str], bool] = lambda robot: False,
        on_change: Callable[[int], None] = lambda tour_id: None,
    ) -> None:
        self.repo = repo
        self.limits = limits
        self.tours = TourService(repo)
        self.is_navigating = is_navigating
        self.on_change = on_change
        self.observers: list[TeachingObserver] = []

    def _tell(self, call: Callable[[TeachingObserver], None]) -> None:
        """``call(observer)`` for every observer; an observer's error is logged, never raised."""
        for observer in self.observers:
            try:
                call(observer)
            except Exception:
                log.exception("teaching observer %s failed", type(observer).__name__)

    # --- queries --------------------------------------------------------------------------

    def state(self, robot: str) -> schemas.TeachingState | None:
        with self.repo.snapshot():
            row = self.repo.teaching(robot)
            return None if row is None else self._state(row)

    def _state(self, row: TeachingRow) -> schemas.TeachingState:
        tour = self.repo.tour(row.tour_id)
        current = (
            None
            if row.current_location_id is None
            else self.repo.location_name(row.current_location_id)
        )
        n_locations, n_edges = self.repo.tour_counts(row.tour_id)
        return schemas.TeachingState(
            tour=tour.id,
            tour_name=tour.name,
            current_location=current,
            open_path_images=self.repo.pending_count(row.robot),
            last_timestamp=row.last_timestamp,
            locations=n_locations,
            edges=n_edges,
        )

    def _teaching(self, robot: str, doing: str) -> TeachingRow:
        row = self.repo.teaching(robot)
        if row is None:
            raise Conflict(
                f"robot {robot!r} is not teaching, so it cannot {doing}; "
                f"start with POST /robots/{robot}/teach/start"
            )
        return row

    def _check_timestamp(self, row: TeachingRow, timestamp: float) -> None:
        if row.last_timestamp is not None and timestamp < row.last_timestamp:
            raise Invalid(
                f"timestamp {timestamp} goes backwards: the previous image was taken at "
                f"{row.last_timestamp}. Send frames in capture order with a monotonic clock"
            )

    # --- steps ----------------------------------------------------------------------------

    def start(self, robot: str, body: schemas.TeachStart) -> schemas.TeachingState:
        if self.is_navigating(robot):
            raise Conflict(f"robot {robot!r} is navigating; stop it before teaching")
        with self.repo.transaction():
            # 404 when unknown or another household's
            self.repo.tour(body.tour, self.repo.robot_household(robot))
            row = self.repo.teaching(robot)
            if row is not None:
                raise Conflict(
                    f"robot {robot!r} is already teaching tour {row.tour_id}; "
                    "finish or abort that tour first"
                )
            self.repo.start_teaching(robot, body.tour)
            state = self._state(self._teaching(robot, "start"))
        self._tell(lambda o: o.teaching_started(robot, body.tour, record=body.record))
        return state

    def frame(self, robot: str, data: bytes, meta: schemas.FrameMeta) -> schemas.FrameResult:
        """Append one frame to the open path."""
        row, stored, pending = self._store(robot, data, meta, spin=False)
        self._tell(lambda o: o.teaching_image(robot, row.tour_id, data, meta, spin=False))
        return schemas.FrameResult(mode="teaching", image=stored, open_path_images=pending)

    def spin_image(self, robot: str, data: bytes, meta: schemas.FrameMeta) -> schemas.ImageStored:
        """Add one image taken while spinning at the current place."""
        row, stored, _ = self._store(robot, data, meta, spin=True)
        self.on_change(row.tour_id)
        self._tell(lambda o: o.teaching_image(robot, row.tour_id, data, meta, spin=True))
        return stored

    def _store(
        self, robot: str, data: bytes, meta: schemas.FrameMeta, *, spin: bool
    ) -> tuple[TeachingRow, schemas.ImageStored, int]:
        """Check and store one image on the open path (``spin`` False) or as a spin image of the
        current place; one transaction. Returns the teaching row, the stored image and the
        number of images now on the open path."""
        doing = "upload spin images" if spin else "upload frames"
        self._ready_for_frames(self._teaching(robot, doing), robot)
        _, width, height = decode_jpeg(data, self.limits)  # outside the transaction: CPU only
        with self.repo.transaction():
            row = self._teaching(robot, doing)
            self._ready_for_frames(row, robot)
            self._check_timestamp(row, meta.timestamp)
            if spin:  # the spin images replace the path frame the mark gave the place
                self.repo.drop_path_copies(row.current_location_id)  # type: ignore[arg-type]
            image_id = self.repo.add_image(
                tour_id=row.tour_id,
                jpeg=data,
                width=width,
                height=height,
                timestamp=meta.timestamp,
                v=meta.v,
                w=meta.w,
                location_id=row.current_location_id if spin else None,
                pending_robot=None if spin else robot,
                pose=None if meta.pose is None else (meta.pose[0], meta.pose[1], meta.pose[2]),
                depth=meta.depth,
            )
            self.repo.set_teaching(
                robot, current_location_id=row.current_location_id, last_timestamp=meta.timestamp
            )
            pending = self.repo.pending_count(robot)
        return row, schemas.ImageStored(image_id=image_id, width=width, height=height), pending

    def _ready_for_frames(self, row: TeachingRow, robot: str) -> None:
        if row.current_location_id is None:
            raise Conflict(
                "no place has been marked yet, so a path has nowhere to start: name the "
                f"starting place first with POST /robots/{robot}/teach/locations"
            )

    def mark(self, robot: str, body: schemas.LocationMark) -> schemas.MarkResult:
        """ "This is the kitchen": close the open path into the named place (new or existing)."""
        name = body.name
        with self.repo.transaction():
            row = self._teaching(robot, "mark a place")
            pending = self.repo.pending_count(robot)
            target = self.repo.location_by_name(row.tour_id, name)
            # a mark closes the open path unless it merely names the place we are at again
            closes_path = row.current_location_id is not None and (
                pending > 0 or target != row.current_location_id
            )
            if closes_path and pending < MIN_EDGE_IMAGES:  # well-formed; the path is short
                here = self.repo.location_name(row.current_location_id)  # type: ignore[arg-type]
                raise Conflict(
                    f"an edge needs at least {MIN_EDGE_IMAGES} images, but only {pending} "
                    f"were uploaded since {here!r}; upload the frames of the path to "
                    f"{name!r} first, or abort"
                )
            created = target is None
            if target is None:
                target = self.repo.add_location(row.tour_id, name)
            edge_id: int | None = None
            if closes_path:
                if not self._has_image(row.tour_id, target):
                    # what the robot saw arriving; a mark on an empty path (the first one, or
                    # the current place named again) has nothing to give
                    self.repo.copy_last_pending_to_location(robot, target)
                edge_id = self.repo.add_edge(row.tour_id, row.current_location_id, target)  # type: ignore[arg-type]
                self.repo.move_pending_to_edge(robot, edge_id)
            self.repo.set_teaching(
                robot, current_location_id=target, last_timestamp=row.last_timestamp
            )
            locations = {loc.id: loc for loc in self.repo.locations(row.tour_id)}
            names = {i: loc.name for i, loc in locations.items()}
            edge = None
            if edge_id is not None:
                edge_row = next(e for e in self.repo.edges(row.tour_id) if e.id == edge_id)
                edge = edge_public(edge_row, names)
            result = schemas.MarkResult(
                location=location_public(locations[target]),
                created=created,
                edge=edge,
                teaching=self._state(self._teaching(robot, "mark a place")),
            )
        self.on_change(row.tour_id)
        self._tell(lambda o: o.teaching_marked(robot, row.tour_id, result))
        return result

    def _has_image(self, tour_id: int, location_id: int) -> bool:
        return any(loc.image_ids for loc in self.repo.locations(tour_id) if loc.id == location_id)

    def finish(self, robot: str) -> schemas.TeachingEnded:
        with self.repo.transaction():
            row = self._teaching(robot, "finish")
            pending = self.repo.pending_count(robot)
            if pending:
                raise Conflict(
                    f"the open path has {pending} frames that do not end at a place: mark the "
                    f"place where it ends (POST /robots/{robot}/teach/locations) or abort "
                    f"(POST /robots/{robot}/teach/abort) to discard them"
                )
            blind = [loc.name for loc in self.repo.locations(row.tour_id) if not loc.image_ids]
            if blind:
                at = row.current_location_id
                here = "" if at is None else f": it is at {self.repo.location_name(at)!r} now"
                raise Conflict(
                    f"{_places(blind)} no image, so a robot could neither recognise nor be sent "
                    f"there. Post a spin image (POST /robots/{robot}/teach/spin) while the "
                    f"robot stands at the place{here}; to reach another, drive there with "
                    "frames and mark it again (the path's last frame becomes its image). Or "
                    f"abort teaching (POST /robots/{robot}/teach/abort) to end without them"
                )
            self.repo.end_teaching(robot)
            graph = self.tours.graph(row.tour_id, None)
        ended = schemas.TeachingEnded(tour=graph, discarded_images=0)
        self._tell(lambda o: o.teaching_ended(robot, row.tour_id, ended, finished=True))
        return ended

    def abort(self, robot: str) -> schemas.TeachingEnded:
        """End teaching, discarding the open path only; marked places and edges stay."""
        with self.repo.transaction():
            row = self._teaching(robot, "abort")
            discarded = self.repo.discard_pending(robot)
            self.repo.end_teaching(robot)
            graph = self.tours.graph(row.tour_id, None)
        ended = schemas.TeachingEnded(tour=graph, discarded_images=discarded)
        self._tell(lambda o: o.teaching_ended(robot, row.tour_id, ended, finished=False))
        return ended


def _places(names: list[str]) -> str:
    """``place 'hall' has`` / ``places 'hall', 'attic' have``."""
    quoted = ", ".join(repr(n) for n in names)
    return f"place {quoted} has" if len(names) == 1 else f"places {quoted} have"
