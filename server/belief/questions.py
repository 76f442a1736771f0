"""When the robot should ask a person something (001 sections 10.2 and 10.4; docs/learning.md).

Two small detectors over the tracker's belief, pure and stateful per robot (NumPy only):

* :class:`SamePlaceDetector` (while teaching): the belief over the tour taught so far says,
  confidently and for a few frames in a row, that the robot is at a known place it was not
  marked at: ask "are we at the kitchen?".
* :class:`NewPathDetector` (while navigating or exploring): the robot left a known place and
  reached another along frames that no taught edge explains: propose those frames as a new
  edge.

They only say *when* to ask; the service (:mod:`server.services.questions`) stores the
question, and only a person's answer changes the map.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class QuestionParams:
    """Questions to a person. Both kinds are off by default: asking runs the tracker on every
    teaching frame (one feature extraction and engine query, plus a rebuild of the tour's
    runtime after every mark), which the teaching flow does not need otherwise.

    * ``teaching`` (False): ask 'same_place' questions while a tour is taught.
    * ``exploration`` (False): propose 'new_path' questions while navigating.
    * ``expiry_s`` (120 s): an unanswered question expires this long after it was asked (the
      app's wall clock); answering it afterwards is refused (410).
    * ``same_place_mass`` (0.9) and ``same_place_steps`` (3 frames): ask when the tracker is
      localised (its own conservative test: ``TrackerParams.localised_mass`` for
      ``localised_steps`` frames, and evidence) at a known place other than the one the open
      path starts from, with at least this belief mass there on this many frames in a row.
      Set once by hand, not tuned per home (docs/learning.md says what was measured).
    * ``same_place_inliers`` (10) and ``same_place_scale`` (1.5): and the view agrees: the
      frame and the place's best-matching image share at least this many corner matches that
      fit one similarity transform (:func:`server.vision.homing.homing_scale`), at a scale
      within this factor of 1 (the robot stands about where the place was photographed). The
      belief alone is often sure of a place while the robot drives a new path, which the tour
      does not know (in the simulated apartment 16 of 20 questions came 1.9-8.6 m from the
      place). 10 is ``NavigationParams.dock_min_inliers`` (what docking trusts a scale with);
      on the apartment (``bench questions``, the tuning home) it kept 4 of the 5 questions
      asked within 1 m of the place and 2 of the 15 asked elsewhere (both in the bedroom,
      about the guest room furnished alike: the look-alikes a 'no' is for). 0 turns it off.
    * ``new_path_edge_mass`` (0.5) and ``new_path_evidence`` (0.75): a navigating frame is
      *on a taught edge* when one edge holds at least this much of the belief and the images
      agree with the belief's prediction (the tracker's evidence ratio at least this, as for
      ``TrackerParams.localised_evidence``); a traversal with such a frame is not new. (Mass
      alone is not enough: a robot sent along an edge keeps pushing the belief onto it while
      the images match nothing.)
    * ``new_path_min_frames`` (10), ``new_path_min_m`` (1.0 m) and ``new_path_max_frames``
      (600): a new path is proposed only when it has at least this many frames in which the
      robot moved and it drove at least this far (odometry, sum of ``|v| dt``); only its last
      ``new_path_max_frames`` frames are kept (memory bound: a robot that wandered long gives
      the end of its way).
    * ``still_v`` (0.01 m/s) and ``still_w`` (0.02 rad/s): a frame below both is the robot
      standing; standing at the place it was localised at starts the way afresh from there.

    Which frames make the new path (:class:`NewPathDetector`): places are rooms, and the
    belief says "at the living room" while the robot crosses it (its spin images see all of
    it), so the way starts where the robot last stood at the place it left (or where it was
    first localised there), not where the belief let go of it; in the simulated apartment the
    belief went from the living room to the kitchen in 5 frames, 75 frames after the robot set
    off across the living room.
    """

    teaching: bool = False
    exploration: bool = False
    expiry_s: float = 120.0
    same_place_mass: float = 0.9
    same_place_steps: int = 3
    same_place_inliers: int = 10
    same_place_scale: float = 1.5
    new_path_edge_mass: float = 0.5
    new_path_evidence: float = 0.75
    new_path_min_frames: int = 10
    new_path_min_m: float = 1.0
    new_path_max_frames: int = 600
    still_v: float = 0.01
    still_w: float = 0.02

    def __post_init__(self) -> None:
        if not (np.isfinite(self.expiry_s) and self.expiry_s > 0):
            raise ValueError(f"expiry_s must be > 0 seconds, got {self.expiry_s}")
        for name in ("same_place_mass", "new_path_edge_mass", "new_path_evidence"):
            value = getattr(self, name)
            if not 0.0 < value <= 1.0:
                raise ValueError(f"{name} must be in (0, 1], got {value}")
        if self.same_place_inliers < 0 or not self.same_place_scale >= 1.0:
            raise ValueError("same_place_inliers must be >= 0 and same_place_scale >= 1")
        if self.same_place_steps < 1 or self.new_path_min_frames < 1:
            raise ValueError("same_place_steps and new_path_min_frames must be >= 1")
        if self.new_path_max_frames < self.new_path_min_frames:
            raise ValueError("new_path_max_frames must be >= new_path_min_frames")
        for name in ("new_path_min_m", "still_v", "still_w"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {value}")


@dataclass
class SamePlaceDetector:
    """Per teaching robot: :meth:`step` once per frame of the open path with the belief's
    upper-state masses. Returns the location to ask about (index among the graph's
    locations) and its mass, or ``None``."""

    params: QuestionParams = field(default_factory=QuestionParams)
    _location: int = -1
    _streak: int = 0

    def reset(self) -> None:
        """A new open path (or a new tour snapshot): forget the streak."""
        self._location, self._streak = -1, 0

    def step(
        self,
        state_mass: npt.ArrayLike,
        n_locations: int,
        *,
        localised_state: int | None,
        start: int | None,
        skip: frozenset[int] = frozenset(),
    ) -> tuple[int, float] | None:
        """``state_mass``: ``(n_states,)`` the belief's mass per upper state (locations
        first); ``localised_state``: the tracker's localised state (``None``: not localised);
        ``start``: the location the open path starts from (never asked about); ``skip``:
        locations not to ask about (an open question, a 'no' on this path)."""
        mass = np.asarray(state_mass, dtype=np.float64)
        if localised_state is None or not 0 <= localised_state < n_locations:
            self.reset()
            return None
        k = int(localised_state)
        if k == start or float(mass[k]) < self.params.same_place_mass:
            self.reset()
            return None
        self._streak = self._streak + 1 if k == self._location else 1
        self._location = k
        if self._streak < self.params.same_place_steps or k in skip:
            return None
        return k, float(mass[k])


@dataclass(frozen=True)
class Traversal:
    """A proposed new path: from location ``origin`` to location ``target`` (graph indices)
    along ``frames``, the indices (as given to :meth:`NewPathDetector.step`) of its frames."""

    origin: int
    target: int
    frames: tuple[int, ...]
    confidence: float


@dataclass
class NewPathDetector:
    """Per navigating robot: :meth:`step` once per frame. The rule (parameters in
    :class:`QuestionParams`):

    * the robot's *origin* is the last known place the tracker was localised at; a frame on a
      taught edge (``new_path_edge_mass`` with ``new_path_evidence``) forgets it (that way is
      taught already);
    * from the origin on, every frame in which the robot moves is kept, and a frame in which
      it stands while localised at the origin drops what was kept (the way starts there);
      only the last ``new_path_max_frames`` are kept;
    * when the tracker is localised at another known place, the kept frames are a
      :class:`Traversal` from the origin to it if there are at least ``new_path_min_frames``
      of them and they drove at least ``new_path_min_m``; that place is the new origin.
    """

    params: QuestionParams = field(default_factory=QuestionParams)
    _origin: int | None = None
    _frames: list[tuple[int, float]] = field(default_factory=list)  # (frame, metres in it)

    def reset(self) -> None:
        """Forget everything (a new task, or a new tour snapshot)."""
        self._origin, self._frames = None, []

    @property
    def frames(self) -> tuple[int, ...]:
        """The frames kept so far (the caller keeps their images, and drops the others)."""
        return tuple(f for f, _ in self._frames)

    def step(
        self,
        frame: int,
        state_mass: npt.ArrayLike,
        n_locations: int,
        *,
        localised_state: int | None,
        evidence: float = 1.0,
        v: float = 0.0,
        w: float = 0.0,
        dt: float = 0.0,
    ) -> Traversal | None:
        """``frame``: the caller's index of this frame; ``state_mass``: ``(n_states,)``;
        ``localised_state``: the tracker's localised state or ``None``; ``evidence``: the
        tracker's evidence ratio (0..1, :class:`server.belief.tracker.BeliefSummary`);
        ``v`` (m/s), ``w`` (rad/s): the robot's odometry; ``dt`` (s) since the last frame."""
        p = self.params
        mass = np.asarray(state_mass, dtype=np.float64)
        edges = mass[n_locations:]
        if (
            len(edges)
            and float(edges.max()) >= p.new_path_edge_mass
            and evidence >= (p.new_path_evidence)
        ):
            self.reset()
            return None
        at = (
            int(localised_state)
            if localised_state is not None and 0 <= localised_state < n_locations
            else None
        )
        if at is not None and at != self._origin:
            found = None
            kept = self._frames
            if (
                self._origin is not None
                and len(kept) >= p.new_path_min_frames
                and sum(m for _, m in kept) >= p.new_path_min_m
            ):
                found = Traversal(self._origin, at, tuple(f for f, _ in kept), float(mass[at]))
            self._origin, self._frames = at, []
            return found
        if self._origin is None:
            return None
        if abs(v) < p.still_v and abs(w) < p.still_w:
            if at == self._origin:
                self._frames = []
            return None
        self._frames.append((frame, abs(v) * max(dt, 0.0)))
        if len(self._frames) > p.new_path_max_frames:
            del self._frames[0]
        return None
