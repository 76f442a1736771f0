"""The dashboard's controls, driven without a browser against real services on a temp SQLite.

Assigning ``True`` to a viser button's value runs its click callbacks (with no client), exactly
as a click in the browser does; snapshots are published by hand for deterministic checks.
"""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from conftest import make_jpeg
from pydantic import SecretStr

from server import schemas
from server.services.container import Services
from server.storage.repo import FrameRow
from web.dashboard import Dashboard
from web.imagery import BEHAVIOUR_COLOURS
from web.panels import NONE
from web.publisher import Publisher


@pytest.fixture()
def services(tmp_path: Path) -> Iterator[Services]:
    from server.app import create_app
    from server.config import Settings

    settings = Settings(
        db=tmp_path / "dash.sqlite", admin_token=SecretStr("dash-admin"), dashboard_port=None
    )
    services: Services = create_app(settings).state.services
    yield services
    services.close()


@pytest.fixture()
def dash(services: Services) -> Iterator[Dashboard]:
    d = Dashboard(services, port=0)
    d.start()
    d.publisher.stop()  # the tests publish by hand: deterministic
    yield d
    d.stop()


def meta(t: float) -> schemas.FrameMeta:
    return schemas.FrameMeta(timestamp=t, v=0.3, w=0.0)


def teach(
    services: Services, robot: str = "rover", places: tuple[str, ...] = ("a", "b", "c")
) -> int:
    """Register ``robot`` and teach a line of places, 4 frames per path; returns the tour id."""
    services.robots.register(schemas.RobotCreate(name=robot), 1)
    tour = services.tours.create(schemas.TourCreate(name="home"), 1)
    services.teaching.start(robot, schemas.TeachStart(tour=tour.id))
    t, seed = 0.0, 0
    for k, name in enumerate(places):
        if k:
            for _ in range(4):
                t, seed = t + 0.1, seed + 1
                services.teaching.frame(robot, make_jpeg(seed), meta(t))
        services.teaching.mark(robot, schemas.LocationMark(name=name))
        t, seed = t + 0.1, seed + 1
        services.teaching.spin_image(robot, make_jpeg(seed), meta(t))
    services.teaching.finish(robot)
    return tour.id


def click(button: object) -> None:
    button.value = True  # type: ignore[attr-defined]


def test_shows_the_robots_the_tour_and_its_places(services: Services, dash: Dashboard) -> None:
    tour_id = teach(services)
    services.robots.register(schemas.RobotCreate(name="scout"), 1)
    snap = dash.refresh()
    c = dash.controls
    assert snap is not None and c is not None
    assert c.robot.options == ("rover", "scout") and c.robot.value == "rover"
    assert c.tour.value == f"home (#{tour_id})"
    assert c.goal.options == ("a", "b", "c")
    assert "**rover** is **idle**" in c.status.content
    assert snap.graph is not None and snap.graph.n_locations == 3
    assert dash._scene is not None and len(dash._scene.places) == 3
    assert [label.text for label in dash._scene.labels] == ["a", "b", "c"]


def test_go_streams_and_stop_through_the_navigation_service(
    services: Services, dash: Dashboard
) -> None:
    teach(services)
    dash.refresh()
    c = dash.controls
    assert c is not None
    c.goal.value = "c"
    click(c.go)
    assert "task 1 to **c** is underway" in c.message.content
    state = services.robot_state("rover")
    assert state.mode == "navigating" and state.navigation is not None
    assert state.navigation.task is not None and state.navigation.task.goal == "c"

    for k in range(3):  # the robot sends frames; the dashboard shows the last step
        services.frame("rover", make_jpeg(100 + k), meta(10.0 + 0.1 * k))
    before = c.images.image.copy()
    snap = dash.refresh()
    assert snap is not None and snap.step is not None and snap.task is not None
    assert snap.task.state == "underway" and snap.step.index == 3
    assert "Task 1 to **c**: **underway**" in c.status.content
    assert "**Action:" in c.action.content and "Entropy" in c.action.content
    assert f"({snap.step.behaviour})" in c.action.content  # what the motion layer is doing
    assert f"Why: {snap.step.reason}" in c.action.content and snap.step.reason
    # the task's behaviours over time: one segment so far, drawn in its colour
    assert [seg.behaviour for seg in snap.timeline] == [snap.step.behaviour]
    colour = BEHAVIOUR_COLOURS[snap.step.behaviour]
    assert (c.strip.image[5, 5] == colour).all() and (c.strip.image[5, -5] == colour).all()
    assert "Vote mass" in c.votes.content
    assert not np.array_equal(before, c.images.image)  # camera | best match were drawn
    assert len(c.over_time.data[0]) == 3
    assert np.isclose(snap.step.state_belief.sum(), 1.0)

    click(c.stop)
    assert "cancelled" in c.message.content
    assert services.robot_state("rover").mode == "idle"


def test_refused_actions_show_the_service_message(services: Services, dash: Dashboard) -> None:
    c = dash.controls
    assert c is not None
    click(c.go)  # nothing registered
    assert c.message.content.startswith("**Error:**") and "no robot selected" in c.message.content

    teach(services)
    dash.refresh()
    click(c.stop)
    assert c.message.content.startswith("**Error:**")
    assert "has no navigation underway; nothing to stop" in c.message.content

    c.place_name.value = "kitchen"
    click(c.mark)
    assert "is not teaching, so it cannot mark a place" in c.message.content

    services.teaching.start("rover", schemas.TeachStart(tour=1))
    c.place_name.value = "   "
    click(c.mark)
    assert "invalid input - name:" in c.message.content  # the pydantic check of the route

    click(c.go)  # the same check as POST /goto: not while teaching
    assert "is teaching; finish or abort teaching first" in c.message.content


def test_teaching_controls_mark_finish_and_abort(services: Services, dash: Dashboard) -> None:
    teach(services)
    c = dash.controls
    assert c is not None
    services.teaching.start("rover", schemas.TeachStart(tour=1))
    dash.refresh()
    assert "**rover** is **teaching**" in c.status.content
    c.place_name.value = "c"
    click(c.mark)
    assert "marked known place **c**" in c.message.content
    for k in range(3):
        services.teaching.frame("rover", make_jpeg(200 + k), meta(50.0 + 0.1 * k))
    dash.refresh()
    assert "at **c**; **3** images on the open path; 3 places and 2 paths" in c.teaching.content

    click(c.finish)  # the open path does not end at a place
    assert "the open path has 3 frames that do not end at a place" in c.message.content
    c.place_name.value = "d"
    click(c.mark)
    assert "marked new place **d**, closing a path of 3" in c.message.content
    snap = dash.refresh()
    assert snap is not None and snap.graph is not None and snap.graph.n_locations == 4
    assert c.goal.options == ("a", "b", "c", "d")
    services.teaching.frame("rover", make_jpeg(300), meta(60.0))
    click(c.abort)
    assert "teaching aborted; 1 images of the open path discarded" in c.message.content
    assert services.robot_state("rover").mode == "idle"
    assert "Not teaching" in (dash.refresh() and c.teaching.content)


def test_selecting_another_robot_shows_it(services: Services, dash: Dashboard) -> None:
    teach(services)
    services.robots.register(schemas.RobotCreate(name="scout"), 1)
    dash.refresh()
    c = dash.controls
    assert c is not None
    c.robot.value = "scout"
    dash.refresh()
    assert c.robot.value == "scout" and "**scout** is **idle**" in c.status.content
    c.goal.value = "b"
    click(c.go)
    assert services.robot_state("scout").mode == "navigating"
    assert services.robot_state("rover").mode == "idle"


def test_the_publisher_never_waits_for_a_session_lock(services: Services) -> None:
    teach(services)
    services.navigation.goto("rover", schemas.GotoRequest(location="b"))
    services.frame("rover", make_jpeg(7), meta(20.0))
    session = services.navigation.sessions()["rover"]
    publisher = Publisher(services, selection=lambda: ("rover", None))
    done = threading.Event()
    with session.lock:  # as if a step were running
        worker = threading.Thread(target=lambda: (publisher.publish_once(), done.set()))
        worker.start()
        assert done.wait(5.0), "the snapshot waited for the session lock"
    snap = publisher.latest
    assert snap is not None and snap.step is not None and snap.mode == "navigating"


def test_the_publisher_keeps_to_five_snapshots_a_second(services: Services) -> None:
    publisher = Publisher(services, selection=lambda: (None, None), hz=100.0)
    assert publisher.period_s == pytest.approx(0.2)
    publisher.start()
    try:
        for _ in range(20):
            publisher.poke()
            threading.Event().wait(0.05)
    finally:
        publisher.stop()
    assert 3 <= publisher.published <= 7  # ~1 s of pokes every 50 ms


def test_a_busy_port_is_detected_and_reported(services: Services) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        d = Dashboard(services, port=port)
        try:
            with pytest.warns(RuntimeWarning, match=f"dashboard port {port} is busy"):
                used = d.start()
            assert used != port and used == d.port
        finally:
            d.stop()


def test_an_empty_server_shows_placeholders(services: Services, dash: Dashboard) -> None:
    snap = dash.refresh()
    c = dash.controls
    assert snap is not None and c is not None
    assert snap.robot is None and snap.graph is None
    assert c.robot.value == NONE and c.goal.options == (NONE,)
    assert "No robot registered yet" in c.status.content


# --- the household's dashboard: its controls act only within it ------------------------------


def test_a_household_dashboard_shows_and_drives_only_that_household(
    services: Services,
) -> None:
    ids, tours = {}, {}
    for name in ("alpha", "beta"):
        ids[name] = services.households.create(schemas.HouseholdCreate(name=name)).id
        services.robots.register(schemas.RobotCreate(name=f"{name}-rover"), ids[name])
        tours[name] = services.tours.create(schemas.TourCreate(name=f"{name}-home"), ids[name]).id
    dash = Dashboard(services, household=ids["alpha"], port=0)
    dash.start()
    dash.publisher.stop()
    try:
        snap = dash.refresh()
        c = dash.controls
        assert c is not None and c.robot.options == ("alpha-rover",)
        assert snap is not None and snap.robots == ("alpha-rover",)
        assert [name for _, name in snap.tours] == ["alpha-home"]
        c.tour.value = f"beta-home (#{tours['beta']})"  # forged: not listed, so not shown
        snap = dash.refresh()
        assert snap is not None and snap.tour_name == "alpha-home"
        c.robot.value = "beta-rover"  # as a forged GUI message would set it
        c.place_name.value = "kitchen"
        click(c.mark)
        assert "no robot named 'beta-rover' in this household" in c.message.content
        click(c.stop)
        assert "no robot named 'beta-rover'" in c.message.content
        c.robot.value = "alpha-rover"
        click(c.stop)
        assert "has no navigation underway" in c.message.content  # reached the service
    finally:
        dash.stop()
    rows = [(a.actor, a.action, a.target, a.status) for a in services.repo.audit(limit=3)][::-1]
    assert rows == [
        ("household:alpha", "dashboard mark", "beta-rover", 404),
        ("household:alpha", "dashboard stop", "beta-rover", 404),
        ("household:alpha", "dashboard stop", "alpha-rover", 409),
    ]


def test_names_are_shown_as_text_never_as_html_or_links(
    services: Services, dash: Dashboard
) -> None:
    """viser renders raw HTML inside markdown unsanitised: a tour named like a style sheet or
    a link must show as those characters, not restyle the page or become a link."""
    services.robots.register(schemas.RobotCreate(name="rover"), 1)
    name = "<style>*{display:none}</style> [win](https://example.org) & co"
    services.tours.create(schemas.TourCreate(name=name), 1)
    dash.refresh()
    c = dash.controls
    assert c is not None
    assert "<style>" not in c.status.content and "[win](" not in c.status.content
    assert "&lt;style&gt;*{display:none}&lt;/style&gt; \\[win\\](https" in c.status.content
    assert "&amp; co" in c.status.content
    c.goal.value = "<b>nowhere</b>"  # a forged goal: quoted back in the refusal
    click(c.go)
    assert "<b>" not in c.message.content and "&lt;b&gt;nowhere" in c.message.content


# --- what a new user found weak, and the Timeline -------------------------------------------


def test_an_idle_robot_says_what_the_others_do_and_a_busy_one_is_shown_first(
    services: Services, dash: Dashboard
) -> None:
    teach(services)  # rover
    services.robots.register(schemas.RobotCreate(name="scout"), 1)
    services.navigation.goto("scout", schemas.GotoRequest(location="b"))
    snap = dash.refresh()
    c = dash.controls
    assert snap is not None and c is not None
    assert c.robot.value == "scout"  # nobody picked a robot: the one navigating is shown
    assert "**scout** is **navigating** - tour *home*" in c.status.content
    c.robot.value = "rover"  # a user picks the idle one
    dash.refresh()
    assert c.robot.value == "rover"
    assert "**rover** is **idle**" in c.status.content and "not bound" not in c.status.content
    assert "Also: **scout** is navigating to b (pick it above to watch)." in c.status.content


def test_the_teaching_controls_show_only_while_teaching(
    services: Services, dash: Dashboard
) -> None:
    teach(services)
    dash.refresh()
    c = dash.controls
    assert c is not None
    assert not any(h.visible for h in c.teach_inputs) and "Not teaching" in c.teaching.content
    services.teaching.start("rover", schemas.TeachStart(tour=1))
    dash.refresh()
    assert all(h.visible for h in c.teach_inputs)


def test_plots_wait_for_frames_and_the_map_shows_the_robot(
    services: Services, dash: Dashboard
) -> None:
    teach(services)
    dash.refresh()
    c = dash.controls
    assert c is not None
    assert not any(h.visible for h in c.plots) and "appear with the first frame" in (
        c.plots_note.content
    )
    empty_map = c.map.image.copy()
    services.navigation.goto("rover", schemas.GotoRequest(location="c"))
    for k in range(3):
        services.frame("rover", make_jpeg(100 + k), meta(10.0 + 0.1 * k))
    dash.refresh()
    assert c.over_time.visible and c.plots_note.content == ""
    red = (c.map.image == (220, 38, 38)).all(axis=2)
    assert red.any() and not (empty_map == (220, 38, 38)).all(axis=2).any()


def test_the_timeline_opens_the_current_task_and_a_recording(
    services: Services, dash: Dashboard
) -> None:
    from web.timeline import CURRENT

    teach(services)
    dash.refresh()
    services.navigation.goto("rover", schemas.GotoRequest(location="c", record=True))
    for k in range(4):
        services.frame("rover", make_jpeg(100 + k), meta(10.0 + 0.1 * k))
    tl = dash.timeline
    c = tl.controls
    assert c is not None
    c.source.value = CURRENT
    tl.open_selected()
    assert "rover's current task: the last 4 frames" in c.note.content
    assert c.frame.max == 3 and not c.frame.disabled
    c.frame.value = 2
    assert "**Belief**" in c.belief.content and "Vote mass" in c.text.content
    services.navigation.stop("rover")
    services.recordings.wait_idle()
    dash.refresh()  # lists the recording
    (name,) = [o for o in c.source.options if o != CURRENT]
    c.source.value = name
    tl.open_selected()
    assert "rover's task to c" in c.note.content and "4 frames" in c.note.content
    c.frame.value = 3
    assert tl.source is not None and len(tl.source.frames) == 4
    frame = tl.source.frames[3]
    assert frame.belief is not None
    assert f"entropy {frame.belief['entropy']:.2f} nats" in c.text.content
    c.source.value = "nothing.mcap"
    assert "no recording" in tl.open_selected()


def test_a_household_timeline_lists_its_own_recordings_only(services: Services) -> None:
    ids = {}
    for name in ("alpha", "beta"):
        ids[name] = services.households.create(schemas.HouseholdCreate(name=name)).id
        services.robots.register(schemas.RobotCreate(name=f"{name}-rover"), ids[name])
        services.recordings.store.new_path(ids[name], f"{name}-rover", 1, 1, 1_795_680_000.0)
    dash = Dashboard(services, household=ids["alpha"], port=0)
    dash.start()
    dash.publisher.stop()
    try:
        dash.refresh()
        c = dash.timeline.controls
        assert c is not None
        assert [o for o in c.source.options if "rover" in o] == [
            "alpha-rover.tour1.20261126-080000.task1.mcap"
        ]
    finally:
        dash.stop()


def test_the_robot_s_question_is_answered_with_yes_or_no(
    services: Services, dash: Dashboard
) -> None:
    """The Questions folder shows the selected robot's oldest open question; Yes and No answer
    it through the question service, as POST /robots/{robot}/questions/{id} does."""
    tour = teach(services)
    c = dash.controls
    assert c is not None
    dash.refresh()
    assert "No question" in c.question.content and not c.yes.visible
    repo = services.repo
    a, b = (repo.location_by_name(tour, n) for n in ("a", "b"))
    assert a is not None and b is not None
    now = services.questions.clock()
    frames = [FrameRow(float(k), 0.3, 0.0, 64, 48, make_jpeg(500 + k), None) for k in range(3)]
    for target in (b, a):  # two questions: the oldest is shown first
        repo.add_question(
            robot="rover",
            tour_id=tour,
            kind="new_path",
            text=f"Keep the way to <{target}>?",
            location_id=target,
            source_location_id=a if target == b else b,
            image_id=None,
            match_image_id=None,
            confidence=0.9,
            now=now,
            expires_at=now + 60.0,
            frames=frames,
        )
    dash.refresh()
    assert f"Keep the way to &lt;{b}&gt;?" in c.question.content and c.yes.visible
    assert "1 more waiting" in c.question.content
    click(c.yes)
    assert "answered yes" in c.message.content and "learned change #" in c.message.content
    assert [(e.source, e.target) for e in services.tours.graph(tour, 1).edges][-1] == (a, b)
    dash.refresh()
    assert f"&lt;{a}&gt;" in c.question.content and "more waiting" not in c.question.content
    click(c.no)
    assert "answered no" in c.message.content
    dash.refresh()
    assert "No question" in c.question.content and not c.no.visible
    assert services.questions.open_questions("rover") == []
