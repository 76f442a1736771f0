"""The whole step on a synthetic tour: properties that hold whatever the frames say."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "vision"))
from navigation_testkit import GRAPH, A, B, C, runtime
from vision_testkit import scene, zoomed

from server.navigation import Frame, Navigator, Task
from server.navigation.command import Command

IMAGES = [int(i) for i in GRAPH.image_ids]

frames = st.lists(
    st.tuples(
        st.integers(0, len(IMAGES) - 1),  # which taught view the camera sees
        st.sampled_from([1.0, 1 / 1.2, 1.2]),  # seen nearer or further than taught
        st.floats(0.0, 0.4),  # reported forward speed
        st.lists(st.floats(0.1, 5.0), min_size=31, max_size=31) | st.none(),  # depth
    ),
    min_size=5,
    max_size=40,
)


def drive(nav: Navigator, seq: list, t0: float = 0.0) -> list[Command]:
    out = []
    for k, (view, zoom, v, depth) in enumerate(seq):
        image = zoomed(scene(IMAGES[view]), zoom)
        ranges = None if depth is None else np.asarray(depth)
        step = nav.step(Frame(image, t0 + 0.1 * (k + 1), v, 0.0, ranges))
        out.append(step.command)
    return out


@settings(max_examples=25, deadline=None)
@given(seq=frames, goal=st.sampled_from([A, B, C]))
def test_commands_stay_in_the_robot_s_limits_and_never_drive_into_a_near_obstacle(
    seq: list, goal: int
) -> None:
    rt = runtime()
    mp = rt.params.motion
    nav = Navigator(rt)
    nav.start(Task(id=1, goal=goal, goal_name="g", started_at=0.0))
    for (_, _, _, depth), c in zip(seq, drive(nav, seq), strict=True):
        assert abs(c.v) <= mp.max_v + 1e-9 and abs(c.w) <= mp.max_w + 1e-9
        if depth is not None and min(depth) <= mp.avoid_full_m:
            assert c.v <= 0.0, c


@settings(max_examples=15, deadline=None)
@given(first=frames, second=frames)
def test_a_new_task_never_sees_an_earlier_task_s_behaviour_state(first: list, second: list) -> None:
    used = Navigator(runtime())
    used.start(Task(id=1, goal=C, goal_name="C", started_at=0.0))
    drive(used, first, t0=0.0)
    used.start(Task(id=2, goal=A, goal_name="A", started_at=0.0))
    fresh = Navigator(runtime())
    fresh.start(Task(id=2, goal=A, goal_name="A", started_at=0.0))
    assert drive(used, second, t0=100.0) == drive(fresh, second, t0=100.0)
