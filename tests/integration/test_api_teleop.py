"""POST /robots/{robot}/teleop and /halt over HTTP: status codes and messages, who may drive
which robot, and what the robot's frames are answered while it is driven."""

from __future__ import annotations

from typing import Any

import pytest
from conftest import Api, make_jpeg

JPEG = {"Content-Type": "image/jpeg"}
PASSWORD = "correct horse battery"


def stream(api: Api, robot: dict[str, str], t: float, name: str = "rover") -> Any:
    """One frame from the robot agent (``stream=true``); the answer's JSON."""
    r = api.client.post(
        f"/robots/{name}/frames",
        params={"timestamp": t, "stream": "true"},
        content=make_jpeg(int(t * 10)),
        headers={**robot, **JPEG},
    )
    assert r.status_code == 200, r.text
    return r.json()


def teleop(api: Api, headers: dict[str, str], body: Any, name: str = "rover") -> Any:
    return api.client.post(f"/robots/{name}/teleop", json=body, headers=headers)


def login(api: Api, household: int = 1, name: str = "default") -> dict[str, str]:
    c = api.client
    if household == 1:
        c.put("/households/1/password", json={"password": PASSWORD}, headers=api.admin)
    else:
        r = c.post("/households", json={"name": name, "password": PASSWORD}, headers=api.admin)
        assert r.status_code == 201, r.text
    r = c.post("/auth/login", json={"household": name, "password": PASSWORD})
    assert r.status_code == 200, r.text
    return {"Authorization": f"Bearer {r.json()['token']}"}


def test_a_robot_drives_itself_and_its_frames_carry_the_command(api: Api) -> None:
    robot = api.register()
    assert stream(api, robot, 0.1)["command"]["behaviour"] == "stand"
    r = teleop(api, robot, {"v": 0.2, "w": -0.5, "ttl_s": 1.0})
    assert r.status_code == 200, r.text
    assert r.json() == {
        "robot": "rover",
        "v": 0.2,
        "w": -0.5,
        "clamped": False,
        "max_v": 0.3,
        "max_w": 1.0,
        "ttl_s": 1.0,
        "mode": "idle",
    }
    answer = stream(api, robot, 0.2)
    assert answer["mode"] == "idle"
    assert answer["command"]["behaviour"] == "teleop"
    assert (answer["command"]["v"], answer["command"]["w"]) == (0.2, -0.5)
    assert 0 < answer["command"]["ttl_s"] <= 0.3
    state = api.client.get("/robots/rover/state", headers=robot).json()
    assert state["control"]["connected"] and state["control"]["teleop"]["v"] == 0.2
    # zero stops at once
    assert teleop(api, robot, {"v": 0, "w": 0}).status_code == 200
    assert stream(api, robot, 0.3)["command"]["behaviour"] == "stand"


def test_speeds_beyond_the_limit_are_clamped_beyond_physics_refused(api: Api) -> None:
    robot = api.register()
    stream(api, robot, 0.1)
    r = teleop(api, robot, {"v": 1.5, "w": 3.0})
    assert r.status_code == 200 and r.json()["clamped"] is True
    assert (r.json()["v"], r.json()["w"]) == (0.3, 1.0)
    for body, where in (
        ({"v": 6.0, "w": 0}, "v: Input should be less than or equal to 5"),
        ({"v": 0, "w": -25}, "w: Input should be greater than or equal to -20"),
        ({"v": 0.1, "w": 0, "ttl_s": 0}, "ttl_s: Input should be greater than 0"),
        ({"v": 0.1, "w": 0, "ttl_s": 5}, "ttl_s: Input should be less than or equal to 2"),
        ({"v": "fast", "w": 0}, "v: Input should be a valid number"),
        ({"v": 0.1}, "w: Field required"),
        ({"v": 0.1, "w": 0, "speed": 1}, "speed: Extra inputs are not permitted"),
    ):
        r = teleop(api, robot, body)
        assert r.status_code == 422, (body, r.text)
        assert r.json()["code"] == "invalid" and where in r.json()["detail"], r.text
    r = api.client.post(
        "/robots/rover/teleop",
        content=b'{"v": NaN, "w": 0}',
        headers={**robot, "Content-Type": "application/json"},
    )
    assert r.status_code == 422, r.text


def test_driving_a_robot_whose_agent_sends_nothing_is_409(api: Api) -> None:
    robot = api.register()
    r = teleop(api, robot, {"v": 0.2, "w": 0})
    assert r.status_code == 409 and r.json()["code"] == "conflict"
    assert r.json()["detail"] == (
        "robot 'rover' is not connected: it has never sent a frame. Start its agent "
        "(`teachrepeat robot run`) before driving it"
    )


def test_driving_a_navigating_robot_is_409_until_halted(api: Api) -> None:
    robot = api.register()
    tour = api.client.post("/tours", json={"name": "home"}, headers=robot).json()["id"]
    api.client.post("/robots/rover/teach/start", json={"tour": tour}, headers=robot)
    api.client.post("/robots/rover/teach/locations", json={"name": "hall"}, headers=robot)
    r = api.client.post(
        "/robots/rover/teach/spin",
        params={"timestamp": 0},
        content=make_jpeg(1, 160, 120),
        headers={**robot, **JPEG},
    )
    assert r.status_code == 200, r.text
    assert api.client.post("/robots/rover/teach/finish", headers=robot).status_code == 200
    assert api.client.post(
        "/robots/rover/goto", json={"location": "hall"}, headers=robot
    ).is_success
    stream(api, robot, 1.0)
    r = teleop(api, robot, {"v": 0.2, "w": 0})
    assert r.status_code == 409 and "is navigating; stop it first" in r.json()["detail"]
    r = api.client.post("/robots/rover/halt", headers=robot)
    assert r.status_code == 200, r.text
    assert r.json()["mode"] == "idle" and r.json()["navigation"]["task"]["state"] == "cancelled"
    assert teleop(api, robot, {"v": 0.2, "w": 0}).status_code == 200


def test_a_robot_token_drives_only_itself_a_login_only_its_households_robots(api: Api) -> None:
    rover = api.register("rover")
    scout = api.register("scout")
    stream(api, rover, 0.1)
    # another robot of the same household: refused, naming whose token it is
    r = teleop(api, scout, {"v": 0.2, "w": 0})
    assert r.status_code == 403
    assert (
        r.json()["detail"] == "this token belongs to robot 'scout'; it cannot read or drive 'rover'"
    )
    assert api.client.post("/robots/rover/halt", headers=scout).status_code == 403
    # the admin token administers, it does not drive
    r = teleop(api, api.admin, {"v": 0.2, "w": 0})
    assert r.status_code == 403 and "administration only" in r.json()["detail"]
    # another household's login: as if the robot did not exist
    other = login(api, 2, "bee")
    r = teleop(api, other, {"v": 0.2, "w": 0})
    assert r.status_code == 404
    assert r.json()["detail"] == "no robot named 'rover'; GET /robots lists your household's robots"
    # no token at all
    r = api.client.post("/robots/rover/teleop", json={"v": 0.2, "w": 0})
    assert r.status_code == 401 and "missing bearer token" in r.json()["detail"]
    assert api.client.get("/robots/rover/state", headers=rover).json()["control"]["teleop"] is None
    # its own household's login drives it (a frame just before: the logins' password hashing
    # took the robot's last frame past connected_s on a loaded machine)
    own = login(api)
    stream(api, rover, 0.15)
    r = teleop(api, own, {"v": 0.2, "w": 0})
    assert r.status_code == 200, r.text
    assert stream(api, rover, 0.2)["command"]["reason"] == "driven by hand (household:default)"


@pytest.mark.parametrize("who", ["robot", "login"])
def test_the_start_of_a_drive_is_audited_with_who_not_every_repeat(api: Api, who: str) -> None:
    robot = api.register()
    headers = robot if who == "robot" else login(api)
    stream(api, robot, 0.1)
    # repeats within the command's time-to-live (the longest allowed: on a loaded machine
    # four calls took longer than the default 0.5 s, and the drive had ended in between)
    for _ in range(4):
        assert teleop(api, headers, {"v": 0.2, "w": 0, "ttl_s": 2.0}).status_code == 200
    rows = api.client.get("/audit", params={"limit": 50}, headers=api.admin).json()
    drives = [row for row in rows if "teleop" in row["action"]]
    actor = "robot:rover" if who == "robot" else "household:default"
    assert [(row["actor"], row["action"], row["target"]) for row in drives] == [
        (actor, "teleop start", "/robots/rover/teleop")
    ]


def test_halt_with_nothing_to_stop_answers_the_state(api: Api) -> None:
    robot = api.register()
    before = api.dump()
    r = api.client.post("/robots/rover/halt", headers=robot)
    assert r.status_code == 200 and r.json()["mode"] == "idle", r.text
    assert api.dump() == before
