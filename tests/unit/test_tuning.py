"""Overriding parameter dataclasses by name (server.tuning)."""

from __future__ import annotations

import pytest

from server.navigation import NavigationParams
from server.tuning import tuned


def test_overrides_reach_nested_settings_and_leave_the_rest_at_their_defaults() -> None:
    base = NavigationParams()
    p = tuned(
        base,
        {
            "dock_second_axis": False,
            "stall_s": 30,
            "motion.unstick_s": 6,
            "policy.explore_entropy": 0.9,
            "dock_zooms": [1.5],
            "signature_weights": [0.2, 0.2, 0.2, 0.2, 0.2],
        },
    )
    assert p.dock_second_axis is False and p.stall_s == 30.0 and isinstance(p.stall_s, float)
    assert p.motion.unstick_s == 6.0 and p.motion.spin_w == base.motion.spin_w
    assert p.policy.explore_entropy == 0.9 and p.policy.round_trip_m == base.policy.round_trip_m
    assert p.dock_zooms == (1.5,) and p.signature_weights == (0.2,) * 5
    assert tuned(base, {}) == base
    # the original is untouched (frozen dataclasses are copied)
    assert base.dock_second_axis is True


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"dock_second_axes": False}, "has no setting 'dock_second_axes'"),
        ({"motion.spin": 1.0}, "MotionParams has no setting 'spin'"),
        ({"stall_s.x": 1.0}, "is a value, not a group"),
        ({"motion": 1.0}, "is a group of settings"),
        ({"dock": "yes"}, "NavigationParams.dock takes bool, not 'yes'"),
        ({"arrive_steps": 2.5}, "arrive_steps takes int"),
        ({"stall_s": True}, "stall_s takes float"),
        ({"dock_zooms": ["x"]}, "dock_zooms takes a list of numbers"),
        ({"features.thumb_size": [8.5, 6]}, "thumb_size takes a list of numbers"),
    ],
)
def test_unknown_names_and_wrong_types_are_refused(overrides: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        tuned(NavigationParams(), overrides)


def test_the_dataclass_checks_still_run() -> None:
    with pytest.raises(ValueError, match="dock_zooms"):
        tuned(NavigationParams(), {"dock_zooms": [0.5]})
    with pytest.raises(ValueError, match="avoid_full_m"):
        tuned(NavigationParams(), {"motion.avoid_full_m": 0.9})


def test_a_setting_typed_as_optional_takes_null_and_a_number() -> None:
    """``TrackerParams.changed_likelihood_power: float | None``: null turns it off, a number
    sets it; a plain float setting still refuses null; changed() round-trips both."""
    from server.tuning import changed

    base = NavigationParams()
    off = tuned(base, {"tracker.changed_likelihood_power": None})
    assert off.tracker.changed_likelihood_power is None
    assert (
        tuned(base, {"tracker.changed_likelihood_power": 1}).tracker.changed_likelihood_power == 1.0
    )
    assert tuned(base, changed(off, base)) == off
    with pytest.raises(ValueError, match="likelihood_power takes float, not None"):
        tuned(base, {"tracker.likelihood_power": None})
