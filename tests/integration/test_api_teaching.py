"""Every endpoint of the teaching API, and every bad input: status, message, database unchanged."""

from __future__ import annotations

from typing import Any

import pytest
from conftest import Api, make_jpeg

JPEG = {"Content-Type": "image/jpeg"}


def start_teaching(api: Api, robot: dict[str, str], tour: str = "home") -> int:
    tour_id = api.client.post("/tours", json={"name": tour}, headers=robot).json()["id"]
    r = api.client.post("/robots/rover/teach/start", json={"tour": tour_id}, headers=robot)
    assert r.status_code == 200, r.text
    return int(tour_id)


def frame(api: Api, robot: dict[str, str], t: float, seed: int = 0, path: str = "frames"):
    return api.client.post(
        f"/robots/rover/{path}",
        params={"timestamp": t, "v": 0.3, "w": 0.0},
        content=make_jpeg(seed),
        headers={**robot, **JPEG},
    )


def mark(api: Api, robot: dict[str, str], name: str):
    return api.client.post("/robots/rover/teach/locations", json={"name": name}, headers=robot)


def assert_refused(api: Api, response, status: int, *words: str) -> None:
    assert response.status_code == status, response.text
    body = response.json()
    assert set(body) == {"detail", "code"}
    for word in words:
        assert word.lower() in body["detail"].lower(), body["detail"]


# --- the happy path -------------------------------------------------------------------------


def test_teach_a_small_tour(api: Api) -> None:
    robot = api.register()
    tour_id = start_teaching(api, robot)
    r = mark(api, robot, "kitchen")
    assert r.status_code == 200 and r.json()["created"] and r.json()["edge"] is None
    spin = frame(api, robot, 0.0, path="teach/spin")
    assert spin.status_code == 200 and spin.json()["width"] == 64
    for k in range(5):
        r = frame(api, robot, 1.0 + k, seed=k)
        assert r.status_code == 200 and r.json()["open_path_images"] == k + 1
    r = mark(api, robot, "office")
    assert r.status_code == 200, r.text
    edge = r.json()["edge"]
    assert (edge["source_name"], edge["target_name"], edge["image_count"]) == (
        "kitchen",
        "office",
        5,
    )
    assert edge["duration_s"] == pytest.approx(4.0)
    # back to the kitchen: closes a path into the existing place
    for k in range(3):
        frame(api, robot, 10.0 + k, seed=10 + k)
    r = mark(api, robot, "kitchen")
    assert r.json()["created"] is False and r.json()["edge"]["target_name"] == "kitchen"
    state = api.client.get("/robots/rover/state", headers=robot).json()
    assert state["mode"] == "teaching" and state["teaching"]["current_location"] == "kitchen"
    done = api.client.post("/robots/rover/teach/finish", headers=robot)
    assert done.status_code == 200 and done.json()["discarded_images"] == 0
    graph = api.client.get(f"/tours/{tour_id}", headers=robot).json()
    assert [(loc["name"], loc["image_count"]) for loc in graph["locations"]] == [
        ("kitchen", 1),
        ("office", 0),
    ]
    assert [(e["source_name"], e["target_name"], e["image_count"]) for e in graph["edges"]] == [
        ("kitchen", "office", 5),
        ("office", "kitchen", 3),
    ]
    listed = api.client.get("/tours", headers=robot).json()
    assert listed == [{"id": tour_id, "name": "home", "locations": 2, "edges": 2, "images": 9}]
    image_id = graph["edges"][0]["first_image_id"]
    image = api.client.get(f"/images/{image_id}", headers=robot)
    assert image.status_code == 200 and image.headers["content-type"] == "image/jpeg"
    assert image.content == make_jpeg(0)
    assert api.client.get("/robots/rover/state", headers=robot).json()["mode"] == "idle"


def test_abort_discards_only_the_open_path(api: Api) -> None:
    robot = api.register()
    tour_id = start_teaching(api, robot)
    mark(api, robot, "a")
    for k in range(3):
        frame(api, robot, k, seed=k)
    mark(api, robot, "b")
    for k in range(4):
        frame(api, robot, 10 + k, seed=k)
    r = api.client.post("/robots/rover/teach/abort", headers=robot)
    assert r.status_code == 200 and r.json()["discarded_images"] == 4
    graph = api.client.get(f"/tours/{tour_id}", headers=robot).json()
    assert len(graph["locations"]) == 2 and len(graph["edges"]) == 1
    assert api.client.get("/tours", headers=robot).json()[0]["images"] == 3


def test_admin_registers_and_lists_robots(api: Api) -> None:
    api.register("rover")
    api.register("mop-2")
    r = api.client.get("/robots", headers=api.admin)
    assert [x["name"] for x in r.json()] == ["mop-2", "rover"]
    assert api.client.get("/whoami", headers=api.admin).json() == {"kind": "admin", "robot": None}


def test_openapi_documents_every_route(api: Api) -> None:
    spec = api.client.get("/openapi.json").json()
    for path in (
        "/tours",
        "/tours/{tour_id}",
        "/robots",
        "/robots/{robot}/frames",
        "/robots/{robot}/teach/start",
        "/robots/{robot}/teach/locations",
        "/robots/{robot}/teach/spin",
        "/robots/{robot}/teach/finish",
        "/robots/{robot}/teach/abort",
        "/images/{image_id}",
        "/robots/{robot}/state",
    ):
        assert path in spec["paths"], path
    assert api.client.get("/docs").status_code == 200


# --- bad input: clear 4xx, nothing changed ----------------------------------------------------


def test_unknown_things_are_404(api: Api) -> None:
    robot = api.register()
    before = api.dump()
    assert_refused(api, api.client.get("/tours/99", headers=robot), 404, "no tour", "99")
    assert_refused(api, api.client.get("/images/99", headers=robot), 404, "no image")
    r = api.client.post("/robots/rover/teach/start", json={"tour": 42}, headers=robot)
    assert_refused(api, r, 404, "no tour")
    r = api.client.get("/robots/ghost/state", headers=api.admin)
    assert_refused(api, r, 404, "no robot", "ghost")
    assert api.dump() == before


def test_marking_or_uploading_while_not_teaching_is_409(api: Api) -> None:
    robot = api.register()
    before = api.dump()
    assert_refused(api, mark(api, robot, "kitchen"), 409, "not teaching", "teach/start")
    assert_refused(api, frame(api, robot, 0.0), 409, "not teaching")
    assert_refused(api, frame(api, robot, 0.0, path="teach/spin"), 409, "not teaching")
    assert_refused(api, api.client.post("/robots/rover/teach/finish", headers=robot), 409)
    assert_refused(api, api.client.post("/robots/rover/teach/abort", headers=robot), 409)
    assert api.dump() == before


def test_frames_before_the_first_place_are_409(api: Api) -> None:
    robot = api.register()
    start_teaching(api, robot)
    before = api.dump()
    assert_refused(api, frame(api, robot, 0.0), 409, "starting place")
    assert api.dump() == before


def test_start_twice_is_409(api: Api) -> None:
    robot = api.register()
    tour_id = start_teaching(api, robot)
    before = api.dump()
    r = api.client.post("/robots/rover/teach/start", json={"tour": tour_id}, headers=robot)
    assert_refused(api, r, 409, "already teaching")
    assert api.dump() == before


def test_duplicate_tour_name_is_409(api: Api) -> None:
    robot = api.register()
    api.client.post("/tours", json={"name": "home"}, headers=robot)
    before = api.dump()
    r = api.client.post("/tours", json={"name": "home"}, headers=robot)
    assert_refused(api, r, 409, "exists already")
    assert api.dump() == before


def test_duplicate_robot_is_409(api: Api) -> None:
    api.register("rover")
    before = api.dump()
    r = api.client.post("/robots", json={"name": "rover"}, headers=api.admin)
    assert_refused(api, r, 409, "registered already")
    assert api.dump() == before


@pytest.mark.parametrize("name", ["", "   ", "x" * 65])
def test_empty_or_overlong_location_name_is_422(api: Api, name: str) -> None:
    robot = api.register()
    start_teaching(api, robot)
    before = api.dump()
    assert_refused(api, mark(api, robot, name), 422, "name")
    assert api.dump() == before


@pytest.mark.parametrize("n_frames", [0, 1])
def test_edge_with_fewer_than_two_images_is_422(api: Api, n_frames: int) -> None:
    robot = api.register()
    start_teaching(api, robot)
    mark(api, robot, "kitchen")
    for k in range(n_frames):
        frame(api, robot, k)
    before = api.dump()
    assert_refused(api, mark(api, robot, "office"), 422, "at least 2 images", str(n_frames))
    assert api.dump() == before


def test_finish_with_an_open_path_is_409(api: Api) -> None:
    robot = api.register()
    start_teaching(api, robot)
    mark(api, robot, "kitchen")
    frame(api, robot, 0.0)
    before = api.dump()
    r = api.client.post("/robots/rover/teach/finish", headers=robot)
    assert_refused(api, r, 409, "open path", "abort")
    assert api.dump() == before


def test_timestamps_going_backwards_are_422(api: Api) -> None:
    robot = api.register()
    start_teaching(api, robot)
    mark(api, robot, "kitchen")
    frame(api, robot, 5.0)
    before = api.dump()
    assert_refused(api, frame(api, robot, 4.0), 422, "backwards", "5.0")
    assert_refused(api, frame(api, robot, 4.0, path="teach/spin"), 422, "backwards")
    assert api.dump() == before


@pytest.mark.parametrize(
    ("body", "status", "word"),
    [
        (b"", 422, "empty"),
        (b"this is not an image at all", 415, "not a jpeg"),
        (b"\x89PNG\r\n\x1a\n" + b"\x00" * 100, 415, "not a jpeg"),
        (make_jpeg(3)[:200], 422, "truncated"),
        (make_jpeg(3)[:-2], 422, "truncated"),
    ],
)
def test_bodies_that_are_not_decodable_images(
    api: Api, body: bytes, status: int, word: str
) -> None:
    robot = api.register()
    start_teaching(api, robot)
    mark(api, robot, "kitchen")
    before = api.dump()
    r = api.client.post(
        "/robots/rover/frames", params={"timestamp": 1.0}, content=body, headers={**robot, **JPEG}
    )
    assert_refused(api, r, status, word)
    assert api.dump() == before


def test_wrong_content_type_is_415(api: Api) -> None:
    robot = api.register()
    start_teaching(api, robot)
    mark(api, robot, "kitchen")
    before = api.dump()
    r = api.client.post(
        "/robots/rover/frames",
        params={"timestamp": 1.0},
        content=make_jpeg(),
        headers={**robot, "Content-Type": "image/png"},
    )
    assert_refused(api, r, 415, "image/jpeg")
    assert api.dump() == before


def claimed_size_jpeg(width: int, height: int) -> bytes:
    """A JPEG whose header claims ``width`` x ``height`` (the rest is a small real image)."""
    data = bytearray(make_jpeg(1))
    pos = 2
    while data[pos + 1] not in (0xC0, 0xC2):
        pos += 2 + int.from_bytes(data[pos + 2 : pos + 4], "big")
    data[pos + 5 : pos + 7] = height.to_bytes(2, "big")
    data[pos + 7 : pos + 9] = width.to_bytes(2, "big")
    return bytes(data)


@pytest.mark.parametrize(("body_kind"), ["bytes", "pixels", "side"])
def test_images_over_the_limits_are_413(api: Api, body_kind: str) -> None:
    robot = api.register()
    start_teaching(api, robot)
    mark(api, robot, "kitchen")
    body = {
        "bytes": b"\xff\xd8" + b"\x00" * (4 * 1024 * 1024 + 10),
        "pixels": claimed_size_jpeg(20000, 20000),
        "side": claimed_size_jpeg(9000, 10),
    }[body_kind]
    before = api.dump()
    r = api.client.post(
        "/robots/rover/frames", params={"timestamp": 1.0}, content=body, headers={**robot, **JPEG}
    )
    assert_refused(api, r, 413, "limit")
    assert api.dump() == before


@pytest.mark.parametrize("params", [{}, {"timestamp": "soon"}, {"timestamp": "nan"}])
def test_missing_or_bad_timestamp_is_422(api: Api, params: dict[str, str]) -> None:
    robot = api.register()
    start_teaching(api, robot)
    mark(api, robot, "kitchen")
    before = api.dump()
    r = api.client.post(
        "/robots/rover/frames", params=params, content=make_jpeg(), headers={**robot, **JPEG}
    )
    assert_refused(api, r, 422, "timestamp")
    assert api.dump() == before


# --- authentication -------------------------------------------------------------------------


def test_missing_or_wrong_token_is_401(api: Api) -> None:
    api.register()
    before = api.dump()
    assert_refused(api, api.client.get("/tours"), 401, "bearer")
    r = api.client.get("/tours", headers={"Authorization": "Bearer nope"})
    assert_refused(api, r, 401, "not valid")
    assert r.headers["www-authenticate"] == "Bearer"
    r = api.client.post("/robots", json={"name": "x"}, headers={"Authorization": "Basic abc"})
    assert_refused(api, r, 401)
    assert api.dump() == before


def test_robot_token_cannot_do_admin_work(api: Api) -> None:
    robot = api.register()
    before = api.dump()
    r = api.client.post("/robots", json={"name": "evil"}, headers=robot)
    assert_refused(api, r, 403, "admin")
    assert_refused(api, api.client.get("/robots", headers=robot), 403, "admin")
    assert api.dump() == before


def test_robot_token_cannot_touch_another_robot(api: Api) -> None:
    mine = api.register("rover")
    api.register("other")
    tour_id = api.client.post("/tours", json={"name": "home"}, headers=mine).json()["id"]
    before = api.dump()
    calls: list[tuple[str, str, dict[str, Any]]] = [
        ("GET", "/robots/other/state", {}),
        ("POST", "/robots/other/teach/start", {"json": {"tour": tour_id}}),
        ("POST", "/robots/other/teach/locations", {"json": {"name": "x"}}),
        ("POST", "/robots/other/teach/finish", {}),
        ("POST", "/robots/other/teach/abort", {}),
        ("POST", "/robots/other/frames", {"params": {"timestamp": 1}, "content": make_jpeg()}),
        ("POST", "/robots/other/teach/spin", {"params": {"timestamp": 1}, "content": make_jpeg()}),
        ("GET", "/robots/nobody/state", {}),
    ]
    for method, path, kwargs in calls:
        r = api.client.request(method, path, headers=mine, **kwargs)
        assert_refused(api, r, 403, "belongs to robot 'rover'")
    assert api.dump() == before


def test_admin_may_act_for_a_robot(api: Api) -> None:
    api.register("rover")
    r = api.client.get("/robots/rover/state", headers=api.admin)
    assert r.status_code == 200 and r.json()["mode"] == "idle"


def test_bad_robot_name_is_422(api: Api) -> None:
    before = api.dump()
    r = api.client.post("/robots", json={"name": "Has Spaces"}, headers=api.admin)
    assert_refused(api, r, 422, "name")
    assert api.dump() == before
