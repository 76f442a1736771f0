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
    * ``new_path_edge_mass`` (0.5) and ``new_path_evidence`` (0.75): a navigating frame is
      *on a taught edge* when one edge holds at least this much of the belief and the images
      agree with the belief's prediction (the tracker's evidence ratio at least this, as for
      ``TrackerParams.localised_evidence``); a traversal with such a frame is not new. (Mass
      alone is not enough: a robot sent along an edge keeps pushing the belief onto it while
      the images match nothing.)
    * ``new_path_min_frames`` (10) and ``new_path_max_frames`` (600): a new path is proposed
      only when at least this many frames (none on a taught edge) lie between leaving one known
      place and being localised at another; a longer run is dropped (memory bound).
    """

    teaching: bool = False
    exploration: bool = False
    expiry_s: float = 120.0
    same_place_mass: float = 0.9
    same_place_steps: int = 3
    new_path_edge_mass: float = 0.5
    new_path_evidence: float = 0.75
    new_path_min_frames: int = 10
    new_path_max_frames: int = 600

    def __post_init__(self) -> None:
        if not (np.isfinite(self.expiry_s) and self.expiry_s > 0):
            raise ValueError(f"expiry_s must be > 0 seconds, got {self.expiry_s}")
        for name in ("same_place_mass", "new_path_edge_mass", "new_path_evidence"):
            value = getattr(self, name)
            if not 0.0 < value <= 1.0:
                raise ValueError(f"{name} must be in (0, 1], got {value}")
        if self.same_place_steps < 1 or self.new_path_min_frames < 1:
            raise ValueError("same_place_steps and new_path_min_frames must be >= 1")
        if self.new_path_max_frames < self.new_path_min_frames:
            raise ValueError("new_path_max_frames must be >= new_path_min_frames")


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
    """Per navigating robot: :meth:`step` once per frame. The rule (documented in
    :class:`QuestionParams`): the robot is localised at a known place A; it leaves; no
    following frame is on a taught edge (an edge holding ``new_path_edge_mass`` of the belief
    with the evidence at least ``new_path_evidence``); it is then
    localised at another known place B after at least ``new_path_min_frames`` such frames:
    the frames in between are a :class:`Traversal` from A to B. A frame on a taught edge, a
    return to A, or a run longer than ``new_path_max_frames`` drops the frames."""

    params: QuestionParams = field(default_factory=QuestionParams)
    _origin: int | None = None
    _frames: list[int] = field(default_factory=list)
    _broken: bool = False

    def reset(self) -> None:
        """Forget everything (a new task, or a new tour snapshot)."""
        self._origin, self._frames, self._broken = None, [], False

    @property
    def frames(self) -> tuple[int, ...]:
        """The frames kept so far (the caller keeps their images, and drops the others)."""
        return tuple(self._frames)

    def step(
        self,
        frame: int,
        state_mass: npt.ArrayLike,
        n_locations: int,
        *,
        localised_state: int | None,
        evidence: float = 1.0,
    ) -> Traversal | None:
        """``frame``: the caller's index of this frame; ``state_mass``: ``(n_states,)``;
        ``localised_state``: the tracker's localised state or ``None``; ``evidence``: the
        tracker's evidence ratio (0..1, :class:`server.belief.tracker.BeliefSummary`)."""
        mass = np.asarray(state_mass, dtype=np.float64)
        at = (
            int(localised_state)
            if localised_state is not None and 0 <= localised_state < n_locations
            else None
        )
        if at is not None:
            found = None
            if (
                self._origin is not None
                and at != self._origin
                and not self._broken
                and len(self._frames) >= self.params.new_path_min_frames
            ):
                found = Traversal(self._origin, at, tuple(self._frames), float(mass[at]))
            self._origin, self._frames, self._broken = at, [], False
            return found
        if self._origin is None or self._broken:
            return None
        edges = mass[n_locations:]
        on_edge = (
            bool(len(edges))
            and float(edges.max()) >= self.params.new_path_edge_mass
            and evidence >= self.params.new_path_evidence
        )
        if on_edge or len(self._frames) >= self.params.new_path_max_frames:
            self._broken, self._frames = True, []
            return None
        self._frames.append(frame)
        return None
