"""SpotFix: when the depth profiles' estimates of a place's spot count as found."""

from __future__ import annotations

import math

import numpy as np

from server.navigation.docking import SpotFix

DT = 0.1


def seen_from(heading: float, spot_world: np.ndarray) -> np.ndarray:
    """The spot in the frame of a robot standing at the origin facing ``heading``."""
    c, s = math.cos(heading), math.sin(heading)
    return np.array([c * spot_world[0] + s * spot_world[1], -s * spot_world[0] + c * spot_world[1]])


def turn_on_the_spot(fix: SpotFix, estimates: list[np.ndarray | None], w: float) -> list:
    return [fix.accept(e, 0.0, w, DT) for e in estimates]


def test_without_a_spread_two_frames_in_a_row_agreeing_find_it() -> None:
    spot = np.array([0.6, 0.2])
    fix = SpotFix()
    out = turn_on_the_spot(fix, [spot, spot], 0.0)
    assert out[0] is None and out[1] is not None
    np.testing.assert_allclose(out[1], spot)


def test_with_a_spread_the_fits_must_face_that_far_apart() -> None:
    """Standing still, agreeing estimates never find it; turning at 0.5 rad/s, the spot (a
    fixed point, seen turning in the robot's frame) is found once an estimate agrees with one
    made 0.8 rad of turn earlier, and not before."""
    world = np.array([0.5, 0.3])
    still = SpotFix(spread_rad=0.8)
    assert all(r is None for r in turn_on_the_spot(still, [world] * 30, 0.0))
    fix = SpotFix(spread_rad=0.8)
    w, found_at = 0.5, None
    for k in range(40):
        heading = k * w * DT
        out = fix.accept(seen_from(heading, world), 0.0, w if k else 0.0, DT)
        if out is not None and found_at is None:
            found_at = heading
            np.testing.assert_allclose(out, seen_from(heading, world), atol=1e-9)
            break
    assert found_at is not None and 0.8 <= found_at < 0.9
    # once found, it is confirmed frame to frame as without a spread
    assert fix.accept(seen_from(found_at + w * DT, world), 0.0, w, DT) is not None


def test_a_false_fit_that_the_walls_further_round_do_not_repeat_is_never_found() -> None:
    """Facing one way the profiles put the spot here, facing 1 rad further round there (a
    wall aligned wrongly, a different one each way): not found, though each is steady."""
    fix = SpotFix(spread_rad=0.8)
    first = [np.array([2.0, 0.0])] * 10  # standing, a steady (false) estimate
    assert all(r is None for r in turn_on_the_spot(fix, first, 0.0))
    heading = 0.0
    for _ in range(10):  # turn 1 rad without a fit
        heading += 0.1
        assert fix.accept(None, 0.0, 1.0, DT) is None
    elsewhere = np.array([0.4, -1.5])  # robot frame, far from where the first one was carried
    assert fix.accept(elsewhere, 0.0, 0.0, DT) is None
    assert fix.accept(elsewhere, 0.0, 0.0, DT) is None
