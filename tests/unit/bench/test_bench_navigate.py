"""The options of ``teachrepeat bench navigate`` (the benchmark itself runs as a command)."""

from __future__ import annotations

import argparse
import json

import pytest

from server.bench.navigate import _navigation_env, _setting, _trial_list


def test_set_takes_json_values_and_bare_words() -> None:
    assert _setting("dock_second_axis=false") == ("dock_second_axis", False)
    assert _setting("motion.unstick_s=6") == ("motion.unstick_s", 6)
    assert _setting("dock_zooms=[1.3, 1.69]") == ("dock_zooms", [1.3, 1.69])
    assert _setting("x=word") == ("x", "word")
    for bad in ("nonsense", "=3"):
        with pytest.raises(argparse.ArgumentTypeError, match="NAME=VALUE"):
            _setting(bad)


def test_settings_are_checked_before_the_server_starts() -> None:
    env = _navigation_env([("dock_second_axis", False), ("motion.unstick_s", 6)])
    assert json.loads(env["TEACHREPEAT_NAVIGATION"]) == {
        "dock_second_axis": False,
        "motion.unstick_s": 6,
    }
    assert _navigation_env([]) == {}
    with pytest.raises(ValueError, match="no setting 'dock_second_axes'"):
        _navigation_env([("dock_second_axes", False)])


def test_only_takes_trial_numbers() -> None:
    assert _trial_list("2,5,14") == frozenset({2, 5, 14})
    for bad in ("a,b", "", "-1"):
        with pytest.raises(argparse.ArgumentTypeError):
            _trial_list(bad)
