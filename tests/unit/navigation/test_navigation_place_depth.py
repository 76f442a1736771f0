"""The depth profile's word on the places the belief is about to favour
(``TopometricParams.place_depth``, :meth:`TourRuntime.place_evidence`): a place whose spin
profiles the frame's does not align with weighs less; every other state as it was."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from navigation_testkit import WALLS, A, B, C, room_profile, runtime

from server.navigation.pathtrack import TopometricParams
from server.navigation.runtime import TourRuntime

SPOT = (1.2, 1.0)
"""Where B's spin images were taught, in the room ``WALLS``."""
ELSEWHERE = [(3.0, -0.3, 3.0, 0.3), (-3.0, -0.3, -3.0, 0.3), (-0.3, 3.0, 0.3, 3.0)]
"""An open hall: pillars 3 m away, nothing else within the depth's reach (the robot sees too
little of anything to align with the room's walls)."""


def taught(**changes: object) -> TourRuntime:
    """The synthetic tour with ``place_depth`` on (and ``changes``), B's four spin images taught
    on ``SPOT`` facing east, north, west, south with their depth profiles."""
    tp = replace(TopometricParams(), **{"place_depth": True, **changes})  # type: ignore[arg-type]
    rt = runtime(topometric=tp)
    for j, image in enumerate(rt.spin_images[B]):
        rt.taught_depth[int(image)] = room_profile(*SPOT, j * math.pi / 2, walls=WALLS)
    return rt


def evidence(
    rt: TourRuntime,
    depth: np.ndarray | None,
    heading: float,
    masses: dict[int, float] | None = None,
) -> np.ndarray:
    """The place evidence with the belief's ``masses`` at places (0.9 at B unless given; the
    rest spread evenly) and the spin view of B facing ``heading`` ranked first by the engine."""
    g = rt.graph
    masses = {B: 0.9} if masses is None else masses
    belief = np.full(g.n_fine, (1.0 - sum(masses.values())) / (g.n_fine - len(masses)))
    for place, mass in masses.items():
        belief[place] = mass
    likelihood = np.ones((1, g.n_fine))
    similarity = np.zeros(g.n_images)
    spins = rt.spin_images[B]
    facing = round(heading / (math.pi / 2)) % 4
    similarity[spins[facing]] = 0.9
    return rt.place_evidence(belief, likelihood, depth, similarity)


@pytest.mark.parametrize("heading", [0.0, math.pi / 2, math.pi, -math.pi / 2])
@pytest.mark.parametrize("offset", [(0.0, 0.0), (0.3, -0.2), (-0.4, 0.3)])
def test_a_robot_at_the_place_keeps_its_weight(heading: float, offset: tuple[float, float]) -> None:
    rt = taught()
    x, y = SPOT[0] + offset[0], SPOT[1] + offset[1]
    out = evidence(rt, room_profile(x, y, heading + 0.05, walls=WALLS), heading)
    np.testing.assert_array_equal(out, np.ones(rt.graph.n_fine))


@pytest.mark.parametrize("heading", [0.0, math.pi / 2])
def test_a_robot_elsewhere_weighs_the_place_ratio_times_less_and_nothing_else(
    heading: float,
) -> None:
    rt = taught()
    out = evidence(rt, room_profile(0.0, 0.0, heading, walls=ELSEWHERE), heading)
    want = np.ones(rt.graph.n_fine)
    want[B] = 1.0 / rt.params.topometric.place_depth_ratio
    np.testing.assert_array_equal(out, want)


def test_only_the_places_about_to_be_favoured_are_asked() -> None:
    rt = taught(place_depth_places=1)
    elsewhere = room_profile(0.0, 0.0, 0.0, walls=ELSEWHERE)
    masses = {A: 0.5, B: 0.3, C: 0.1}
    # the belief most at A: B is not the one place asked about (A has no profiles: no word)
    np.testing.assert_array_equal(evidence(rt, elsewhere, 0.0, masses), np.ones(rt.graph.n_fine))
    # with two asked, B is the second most likely and refuted
    out = evidence(taught(place_depth_places=2), elsewhere, 0.0, masses)
    assert out[B] < 1.0 and np.all(np.delete(out, B) == 1.0)


def test_off_without_depth_or_with_a_ratio_of_one_it_has_no_word() -> None:
    elsewhere = room_profile(0.0, 0.0, 0.0, walls=ELSEWHERE)
    ones = np.ones(taught().graph.n_fine)
    np.testing.assert_array_equal(evidence(taught(place_depth=False), elsewhere, 0.0), ones)
    np.testing.assert_array_equal(evidence(taught(), None, 0.0), ones)
    np.testing.assert_array_equal(evidence(taught(place_depth_ratio=1.0), elsewhere, 0.0), ones)


def test_place_depth_defaults_are_documented_numbers() -> None:
    p = TopometricParams()
    assert not p.place_depth
    assert (p.place_depth_ratio, p.place_depth_places) == (4.0, 2)
