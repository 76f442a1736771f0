"""Which way the robot faces at each place, kept from the odometry: a place's views must come
round in the order its spin images were taught.

001 eq. 2 gives a location the best similarity among its spin images: the robot may face any
way there. A spinning robot at a place sees the spin images one after another, each where the
odometry says it should be; at a place that only looks alike (a corridor's end beside another
corridor's place, a room furnished like another) the best-matching spin image jumps about as it
turns. So each location keeps a distribution ``q`` over its spin images (which one the robot
would be facing, were it there), the way the tracker keeps ``b(i | e)`` along an edge:

* **predict**: every spin image's mass moves to the spin images whose taught heading is the
  turn ``w dt`` further on (a Gaussian of ``spread_rad`` plus ``turn_noise`` of the turn,
  normalised over the place's images), and ``forget`` of it to all of them alike;
* **consistency**: the place's likelihood is ``max_i r_i s_i`` with ``s_i`` the similarity of
  spin image ``i`` and ``r_i = max(least_weight, q_i / max q)`` how plausible facing it is;
  with nothing known (``q`` uniform) this is 001 eq. 2 exactly, and a view that matches a
  spin image the turn says the robot cannot face counts ``least_weight`` of it;
* **update**: ``q_i`` times ``s_i``, normalised per place.

The distribution is conditional on being at the place, so it runs for every place on every
frame, whatever the belief says. Taught headings come from the spin images' taught odometry
(:attr:`server.domain.TourGraph.image_pose`); without it, evenly over one anticlockwise turn in
the order taught (how the teaching guide spins).

Pure: NumPy only. Arrays over the ``n_spin`` spin images are in canonical image order (the
locations' images come first, each location's together).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from server.domain import TourGraph

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

__all__ = ["HeadingParams", "SpinLayout", "consistency", "predict_heading", "update_heading"]


@dataclass(frozen=True)
class HeadingParams:
    """How the tracker keeps the way the robot faces at each place (module docstring).

    * ``enabled`` (False): weigh a place's spin images by the heading its odometry allows;
      False: 001 eq. 2 (the best spin image, whichever way it faces). Off by default: it
      gained on the shipped homes (163 against 151 of 216, docs/navigation.md section 3.1) but
      lost where a robot is carried off a place of a short tour into a corridor that looks
      alike both ways (``teachrepeat bench carried``: 3 of 6 against 5 of 7): the belief
      left the place for a look-alike edge the robot faced away from.
    * ``spread_rad`` (0.12 rad): the least spread of the heading per frame (about the spacing
      of the guide's spin images, 10 degrees, so mass reaches the neighbours); at a place with
      fewer spin images, at least half their spacing (with four, 90 degrees apart, a turn of a
      few degrees a frame would otherwise never move the mass to the next one).
    * ``turn_noise`` (0.2): the spread grows by this fraction of the frame's turn.
    * ``forget`` (0.02): per frame, this share of the mass goes to every spin image alike.
    * ``least_weight`` (0.25): the least weight of a spin image the heading makes unlikely.
    """

    enabled: bool = False
    spread_rad: float = 0.12
    turn_noise: float = 0.2
    forget: float = 0.02
    least_weight: float = 0.25

    def __post_init__(self) -> None:
        if not (self.spread_rad > 0 and self.turn_noise >= 0):
            raise ValueError("spread_rad must be > 0 and turn_noise >= 0")
        if not (0 <= self.forget <= 1 and 0 < self.least_weight <= 1):
            raise ValueError("forget must be in [0, 1] and least_weight in (0, 1]")


def _wrap(angle: FloatArray) -> FloatArray:
    out: FloatArray = (angle + np.pi) % (2 * np.pi) - np.pi
    return out


@dataclass(frozen=True)
class SpinLayout:
    """The spin images of a tour's places, for the arrays of this module.

    * ``location``: ``(n_spin,)`` the location of each spin image; ``heading``: ``(n_spin,)``
      its taught heading (rad); ``size``: ``(n_spin,)`` how many spin images its place has.
    * ``starts``: ``(n_places,)`` where each location that has spin images starts;
      ``places``: ``(n_places,)`` which locations those are; ``rank``: ``(n_spin,)`` each
      spin image's place among them.
    * ``src``, ``dst``: ``(n_pairs,)`` every ordered pair of spin images of one place;
      ``delta``: ``(n_pairs,)`` the turn from ``src``'s heading to ``dst``'s, in [-pi, pi).
    """

    location: IntArray
    heading: FloatArray
    size: IntArray
    starts: IntArray
    places: IntArray
    rank: IntArray
    src: IntArray
    dst: IntArray
    delta: FloatArray

    @property
    def n_spin(self) -> int:
        return len(self.location)

    @property
    def spacing(self) -> FloatArray:
        """``(n_spin,)`` one turn over the number of spin images of each image's place (rad)."""
        out: FloatArray = 2 * np.pi / self.size
        return out

    @classmethod
    def of(cls, graph: TourGraph) -> SpinLayout:
        counts = np.array([len(loc.image_ids) for loc in graph.locations], dtype=np.int64)
        n_spin = int(counts.sum())
        location = np.repeat(np.arange(len(counts), dtype=np.int64), counts)
        first = np.cumsum(counts) - counts
        size = counts[location]
        index = np.arange(n_spin, dtype=np.int64) - first[location]
        heading = 2 * np.pi * index / size
        if graph.image_pose is not None and n_spin:
            taught = np.asarray(graph.image_pose, dtype=np.float64)[:n_spin, 2]
            for k in np.flatnonzero(counts):  # per place: its own poses when all are there
                span = slice(int(first[k]), int(first[k] + counts[k]))
                if np.all(np.isfinite(taught[span])):
                    heading[span] = taught[span]
        has = counts > 0
        places = np.flatnonzero(has).astype(np.int64)
        # every spin image pairs with each image of its place
        src = np.repeat(np.arange(n_spin, dtype=np.int64), size)
        within = np.arange(len(src), dtype=np.int64) - np.repeat(np.cumsum(size) - size, size)
        dst = first[location][src] + within
        return cls(
            location=location,
            heading=heading,
            size=size,
            starts=first[has].astype(np.int64),
            places=places,
            rank=np.searchsorted(places, location).astype(np.int64),
            src=src,
            dst=dst,
            delta=_wrap(heading[dst] - heading[src]),
        )

    def uniform(self) -> FloatArray:
        """``(n_spin,)`` nothing known: each place's mass spread evenly over its images."""
        out: FloatArray = 1.0 / self.size
        return out

    def per_place(self, values: FloatArray, ufunc: np.ufunc) -> FloatArray:
        """``(n_places,)`` ``ufunc`` reduced over each place's images (``np.add``, ...)."""
        out: FloatArray = ufunc.reduceat(values, self.starts, axis=-1)
        return out

    def spread(self, per_place: FloatArray) -> FloatArray:
        """``(..., n_spin)`` a per-place value given to each of the place's images."""
        return per_place[..., self.rank]


def predict_heading(
    q: npt.ArrayLike, layout: SpinLayout, turn: float, params: HeadingParams
) -> FloatArray:
    """``(n_spin,)`` the heading distributions after the robot turned ``turn`` rad
    (anticlockwise positive): each spin image's mass to the spin images about ``turn`` further
    on, then ``params.forget`` of it spread evenly. Each place's slice sums to 1."""
    q = np.asarray(q, dtype=np.float64)
    if layout.n_spin == 0:
        return q.copy()
    least = np.maximum(params.spread_rad, layout.spacing[layout.src] / 2)
    sd = np.hypot(least, params.turn_noise * abs(turn))
    kernel = np.exp(-0.5 * (_wrap(layout.delta - turn) / sd) ** 2)
    norm = np.bincount(layout.src, weights=kernel, minlength=layout.n_spin)
    moved = np.bincount(
        layout.dst, weights=q[layout.src] * kernel / norm[layout.src], minlength=layout.n_spin
    )
    out: FloatArray = (1 - params.forget) * moved + params.forget * layout.uniform()
    return out


def consistency(
    q: npt.ArrayLike, sim: npt.ArrayLike, layout: SpinLayout, params: HeadingParams
) -> FloatArray:
    """``(..., n_places)`` how much of a place's best similarity the heading allows, against
    the place it allows most: ``c_p / max_p c_p`` with ``c_p = max_i r_i s_i / max_i s_i`` and
    ``r_i = max(least_weight, q_i / max q)`` (1 where the best spin image is one the robot may
    face, 1 everywhere when ``q`` is uniform). The places are weighed against each other, not
    against the edges' images: weighed alone, a robot carried 0.8 m off a place into a
    corridor that looks alike both ways (``teachrepeat bench carried``), whose views the place's
    spin images follow only in part, lost the place to look-alike images of an edge and
    followed that edge the wrong way (2 of 7 arrived; weighed against the places 3 of 6, the
    seventh not run; seed 700 of the shipped homes 57 of 72 either way).

    Args:
        q: ``(n_spin,)`` the predicted heading distributions (:func:`predict_heading`).
        sim: ``(..., n_spin)`` the spin images' similarities (>= 0), one row per model.
    """
    q = np.asarray(q, dtype=np.float64)
    s = np.asarray(sim, dtype=np.float64)
    top_q = layout.spread(layout.per_place(q, np.maximum))
    r = np.maximum(params.least_weight, q / top_q)
    best = layout.per_place(s, np.maximum)
    weighed = layout.per_place(r * s, np.maximum)
    own = np.divide(weighed, best, out=np.ones_like(best), where=best > 0)
    out: FloatArray = own / own.max(axis=-1, keepdims=True)  # each c_p >= least_weight > 0
    return out


def update_heading(q: npt.ArrayLike, sim: npt.ArrayLike, layout: SpinLayout) -> FloatArray:
    """``(n_spin,)`` the heading distributions given the spin images' similarities ``sim``
    ``(n_spin,)`` (> 0): ``q * sim``, normalised per place (a place whose images all
    have zero similarity keeps ``q``)."""
    q = np.asarray(q, dtype=np.float64)
    post = q * np.asarray(sim, dtype=np.float64)
    total = layout.spread(layout.per_place(post, np.add))
    out: FloatArray = np.divide(post, total, out=q.copy(), where=total > 0)
    return out
