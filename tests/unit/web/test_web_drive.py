"""Driving from the dashboard without a browser: the arrows' hold and release callbacks, a
browser that goes away, Start teaching and Stop, against real services on a temp SQLite.

(In the browser, keys and arrows: tests/e2e/test_e2e_teach_by_driving.py.)"""

from __future__ import annotations

import html.parser
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from conftest import make_jpeg
from pydantic import SecretStr

from server import schemas
from server.services.container import Services
from web.dashboard import Dashboard
from web.drive import DIRECTIONS, HOLD_TTL_S, drive_command, keyboard_bridge


@pytest.fixture()
def services(tmp_path: Path) -> Iterator[Services]:
    from server.app import create_app
    from server.config import Settings

    settings = Settings(
        db=tmp_path / "drive.sqlite", admin_token=SecretStr("drive-admin"), dashboard_port=None
    )
    services: Services = create_app(settings).state.services
    services.robots.register(schemas.RobotCreate(name="rover"), 1)
    yield services
    services.close()


@pytest.fixture()
def dash(services: Services) -> Iterator[Dashboard]:
    d = Dashboard(services, port=0)
    d.start()
    d.publisher.stop()  # the tests publish by hand: deterministic
    yield d
    d.stop()


class Event:
    """What viser passes a callback: the browser that sent it."""

    def __init__(self, client_id: int = 7) -> None:
        self.client_id = client_id
        self.client = None


def frame(services: Services, t: float) -> schemas.AnyFrameResult:
    meta = schemas.FrameMeta(timestamp=t, stream=True)
    return services.frame("rover", make_jpeg(int(t * 10), 64, 48), meta)


def click(button: object) -> None:
    button.value = True  # type: ignore[attr-defined]


def test_arrows_combine_into_one_command() -> None:
    assert drive_command(set(), speed=0.2, turn=0.5) == (0.0, 0.0)
    assert drive_command({"forward"}, speed=0.2, turn=0.5) == (0.2, 0.0)
    assert drive_command({"forward", "left"}, speed=0.2, turn=0.5) == (0.2, 0.5)
    assert drive_command({"back", "right"}, speed=0.2, turn=0.5) == (-0.2, -0.5)
    assert drive_command({"forward", "back"}, speed=0.2, turn=0.5) == (0.0, 0.0)


def test_the_keyboard_bridge_is_one_inert_image_with_the_arrow_labels() -> None:
    bridge = keyboard_bridge()
    tags: list[tuple[str, dict[str, str | None]]] = []

    class Parser(html.parser.HTMLParser):
        def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
            tags.append((tag, dict(attrs)))

    Parser().feed(bridge)
    assert [t for t, _ in tags] == ["img"]
    script = tags[0][1]["onerror"] or ""
    for d in DIRECTIONS:
        assert f"'{d.label}'" in script and all(f"{k}:" in script for k in d.keys)
    for event in ("keydown", "keyup", "blur", "visibilitychange", "pagehide"):
        assert f"'{event}'" in script


def test_holding_an_arrow_drives_and_releasing_it_stops_at_once(
    services: Services, dash: Dashboard
) -> None:
    frame(services, 0.1)
    dash.refresh()
    c = dash.controls
    assert c is not None and all(a.visible for a in c.arrows.values())
    assert "Hold an arrow" in c.drive_note.content
    dash._on_hold(Event(), "forward")  # type: ignore[arg-type]
    dash._on_hold(Event(), "left")  # type: ignore[arg-type]
    told = frame(services, 0.2).command
    assert told is not None and told.behaviour == "teleop"
    assert (told.v, told.w) == (c.speed.value, c.turn.value) == (0.25, 0.6)
    state = services.control.public("rover")
    assert state is not None and state.teleop is not None and state.teleop.ttl_s == HOLD_TTL_S
    dash._on_release(Event(), "left")  # type: ignore[arg-type]
    told = frame(services, 0.3).command
    assert told is not None and (told.v, told.w) == (0.25, 0.0)
    dash._on_release(Event(), "forward")  # type: ignore[arg-type]
    told = frame(services, 0.4).command
    assert told is not None and told.behaviour == "stand"
    rows = [(a.actor, a.action) for a in services.repo.audit(limit=5)]
    assert rows == [("dashboard", "teleop start")]


def test_a_browser_that_goes_away_stops_the_robot_it_was_driving(
    services: Services, dash: Dashboard
) -> None:
    frame(services, 0.1)
    dash.refresh()
    dash._on_hold(Event(client_id=3), "back")  # type: ignore[arg-type]
    assert frame(services, 0.2).command.v == -0.25  # type: ignore[union-attr]
    dash._client_gone(4)  # another browser: nothing changes
    assert frame(services, 0.3).command.v == -0.25  # type: ignore[union-attr]
    dash._client_gone(3)
    assert frame(services, 0.4).command.behaviour == "stand"  # type: ignore[union-attr]


def test_a_refused_drive_is_said_once_and_the_arrows_hide_while_navigating(
    services: Services, dash: Dashboard
) -> None:
    said: list[str] = []
    dash._say = lambda event, text, error: said.append(text)  # type: ignore[method-assign]
    for _ in range(3):
        dash._on_hold(Event(), "forward")  # type: ignore[arg-type]
    assert said == [
        "Drive refused: robot 'rover' is not connected: it has never sent a frame. Start "
        "its agent (`teachrepeat robot run`) before driving it"
    ]
    dash.refresh()
    c = dash.controls
    assert c is not None and not any(a.visible for a in c.arrows.values())
    assert "sends no frames" in c.drive_note.content


def test_start_teaching_creates_the_tour_named_and_stop_halts_the_spin(
    services: Services, dash: Dashboard
) -> None:
    frame(services, 0.1)
    dash.refresh()
    c = dash.controls
    assert c is not None and c.teach_start.visible and not c.mark.visible
    c.teach_tour.value = "flat"
    click(c.teach_start)
    assert "rover: teaching *flat*" in c.message.content
    teaching = services.teaching.state("rover")
    assert teaching is not None and teaching.tour_name == "flat"
    dash.refresh()
    assert c.mark.visible and not c.teach_start.visible
    assert "Name the place where the robot stands to begin" in c.teaching.content
    c.place_name.value = "hall"
    click(c.mark)
    frame(services, 0.2)
    dash.refresh()
    assert "Turning at **hall**" in c.teaching.content
    assert not any(a.visible for a in c.arrows.values())  # the arrows wait for the spin
    # the camera shows the robot's frame and the command it was given
    assert "**Command: spin**" in c.action.content
    click(c.stop)
    assert "rover: stopped the spin at hall" in c.message.content
    dash.refresh()
    assert "spin stopped at hall" in c.teaching.content


def test_start_teaching_an_existing_tour_by_name_or_as_chosen_above(
    services: Services, dash: Dashboard
) -> None:
    tour = services.tours.create(schemas.TourCreate(name="flat"), 1)
    dash.refresh()
    c = dash.controls
    assert c is not None
    c.teach_tour.value = ""
    click(c.teach_start)  # the tour chosen in "Go to a place"
    assert services.teaching.state("rover").tour == tour.id  # type: ignore[union-attr]
    services.teaching.abort("rover")
    c.teach_tour.value = "flat"
    click(c.teach_start)
    assert services.teaching.state("rover").tour == tour.id  # type: ignore[union-attr]
    assert [t.name for t in services.tours.list(1)] == ["flat"]
    click(c.teach_start)
    assert "is already teaching tour" in c.message.content


def test_stop_with_nothing_to_stop_is_refused_as_before(
    services: Services, dash: Dashboard
) -> None:
    dash.refresh()
    c: Any = dash.controls
    click(c.stop)
    assert "has no navigation underway; nothing to stop" in c.message.content
