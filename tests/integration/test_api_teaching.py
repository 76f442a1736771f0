"""Every endpoint of the teaching API, and every bad input: status, message, database unchanged."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
from conftest import Api, make_jpeg
from fastapi.testclient import TestClient
from pydantic import SecretStr

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
        ("office", 1),  # no spin image there: the last frame of the path to it
    ]
    office_image = graph["locations"][1]["image_ids"][0]
    assert api.client.get(f"/images/{office_image}", headers=robot).content == make_jpeg(4)
    assert [(e["source_name"], e["target_name"], e["image_count"]) for e in graph["edges"]] == [
        ("kitchen", "office", 5),
        ("office", "kitchen", 3),
    ]
    listed = api.client.get("/tours", headers=robot).json()
    assert listed == [{"id": tour_id, "name": "home", "locations": 2, "edges": 2, "images": 10}]
    image_id = graph["edges"][0]["first_image_id"]
    image = api.client.get(f"/images/{image_id}", headers=robot)
    assert image.status_code == 200 and image.headers["content-type"] == "image/jpeg"
    assert image.content == make_jpeg(0)
    assert api.client.get("/robots/rover/state", headers=robot).json()["mode"] == "idle"


def test_taught_images_keep_the_poses_the_robot_sent(api: Api) -> None:
    """``pose=x&pose=y&pose=theta`` comes back in ``GET /tours/{id}``, per image in order; a
    place or edge with an image without a pose has none; a pose of two values is 422."""
    robot = api.register()
    tour_id = start_teaching(api, robot)
    mark(api, robot, "kitchen")
    send = dict(headers={**robot, **JPEG}, content=make_jpeg(0))
    params: dict[str, object] = {"timestamp": 0.0, "pose": [0.5, -1.0, 3.0]}
    assert api.client.post("/robots/rover/teach/spin", params=params, **send).status_code == 200
    for k in range(3):
        params = {"timestamp": 1.0 + k, "v": 0.3, "pose": [0.5 + 0.3 * k, -1.0, 0.0]}
        assert api.client.post("/robots/rover/frames", params=params, **send).status_code == 200
    mark(api, robot, "office")  # gets a copy of the last frame, pose and all
    frame(api, robot, 5.0)  # no pose
    frame(api, robot, 6.0)
    mark(api, robot, "kitchen")
    bad = api.client.post("/robots/rover/frames", params={"timestamp": 7, "pose": [1, 2]}, **send)
    assert_refused(api, bad, 422, "pose")
    assert api.client.post("/robots/rover/teach/finish", headers=robot).status_code == 200
    graph = api.client.get(f"/tours/{tour_id}", headers=robot).json()
    assert [loc["poses"] for loc in graph["locations"]] == [[[0.5, -1.0, 3.0]], [[1.1, -1.0, 0.0]]]
    assert graph["edges"][0]["poses"] == [[0.5, -1.0, 0.0], [0.8, -1.0, 0.0], [1.1, -1.0, 0.0]]
    assert graph["edges"][1]["poses"] is None
    assert all(e["entropy"] is None for e in graph["edges"])  # not computed yet


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
    assert api.client.get("/tours", headers=robot).json()[0]["images"] == 4  # 3 + b's image


def test_admin_registers_and_lists_robots(api: Api) -> None:
    api.register("rover")
    api.register("mop-2")
    r = api.client.get("/robots", headers=api.admin)
    assert [x["name"] for x in r.json()] == ["mop-2", "rover"]
    assert api.client.get("/whoami", headers=api.admin).json() == {
        "kind": "admin",
        "robot": None,
        "household": None,
    }


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


def test_docs_work_without_internet(api: Api) -> None:
    """/docs loads Swagger UI from files the server holds, never from a CDN."""
    import re

    r = api.client.get("/docs")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    assert not re.search(r"https?://", r.text), r.text
    assets = re.findall(r'(?:src|href)="([^"]+)"', r.text)
    assert {a.rsplit("/", 1)[-1] for a in assets} == {
        "swagger-ui-bundle.js",
        "swagger-ui.css",
        "favicon.png",
    }
    for url in assets:
        asset = api.client.get(url)
        assert asset.status_code == 200 and len(asset.content) > 1000, url
    # Swagger UI 5 renders OpenAPI 3.1 (the 4.x of swagger-ui-bundle refuses anything but 3.0)
    bundle = api.client.get(next(a for a in assets if a.endswith(".js"))).text
    assert "isOAS31" in bundle
    assert api.client.get("/openapi.json").json()["openapi"].startswith("3.1")


def test_the_root_points_to_the_docs_and_the_dashboard(api: Api, tmp_path: Path) -> None:
    r = api.client.get("/")
    assert r.status_code == 200
    assert r.json() == {
        "name": "teachrepeat",
        "version": "0.1.0",
        "docs": "/docs",
        "openapi": "/openapi.json",
        "dashboard": None,  # the fixture runs without a dashboard
    }
    from server.app import create_app
    from server.config import Settings

    settings = Settings(db=tmp_path / "d.sqlite", admin_token=SecretStr("x"), dashboard_port=8080)
    with TestClient(create_app(settings), base_url="http://robot-server.local:8000") as client:
        assert client.get("/").json()["dashboard"] == "http://robot-server.local:8080"


def place_images(api: Api, robot: dict[str, str], tour_id: int) -> dict[str, list[bytes]]:
    graph = api.client.get(f"/tours/{tour_id}", headers=robot).json()
    return {
        loc["name"]: [
            api.client.get(f"/images/{i}", headers=robot).content for i in loc["image_ids"]
        ]
        for loc in graph["locations"]
    }


def test_a_place_reached_by_a_path_gets_its_last_frame_until_spin_images_come(api: Api) -> None:
    robot = api.register()
    tour_id = start_teaching(api, robot)
    mark(api, robot, "hall")
    frame(api, robot, 0.0, seed=100, path="teach/spin")
    for k in range(3):
        frame(api, robot, 1.0 + k, seed=k)
    r = mark(api, robot, "kitchen")
    assert r.json()["location"]["image_count"] == 1 and r.json()["edge"]["image_count"] == 3
    assert place_images(api, robot, tour_id)["kitchen"] == [make_jpeg(2)]
    # the spin images replace it: a client that spins at every place gets only its spin images
    frame(api, robot, 4.0, seed=200, path="teach/spin")
    frame(api, robot, 4.5, seed=201, path="teach/spin")
    assert place_images(api, robot, tour_id)["kitchen"] == [make_jpeg(200), make_jpeg(201)]
    # a place that has images keeps just them when a path reaches it again
    for k in range(2):
        frame(api, robot, 5.0 + k, seed=10 + k)
    mark(api, robot, "hall")
    assert api.client.post("/robots/rover/teach/finish", headers=robot).status_code == 200
    images = place_images(api, robot, tour_id)
    assert images == {"hall": [make_jpeg(100)], "kitchen": [make_jpeg(200), make_jpeg(201)]}


def test_finish_refuses_a_place_without_an_image(api: Api) -> None:
    robot = api.register()
    tour_id = start_teaching(api, robot)
    mark(api, robot, "hall")  # the first place: no path leads there, and no spin image
    for k in range(2):
        frame(api, robot, k, seed=k)
    mark(api, robot, "kitchen")
    before = api.dump()
    r = api.client.post("/robots/rover/teach/finish", headers=robot)
    assert_refused(
        api, r, 409, "place 'hall' has no image", "/robots/rover/teach/spin", "at 'kitchen' now"
    )
    assert api.dump() == before
    # drive back and mark it again: the path's last frame becomes its image
    for k in range(2):
        frame(api, robot, 10 + k, seed=10 + k)
    mark(api, robot, "hall")
    assert api.client.post("/robots/rover/teach/finish", headers=robot).status_code == 200
    assert place_images(api, robot, tour_id)["hall"] == [make_jpeg(11)]


def test_a_spin_image_at_the_first_place_lets_teaching_finish(api: Api) -> None:
    robot = api.register()
    start_teaching(api, robot)
    mark(api, robot, "hall")
    r = api.client.post("/robots/rover/teach/finish", headers=robot)
    assert_refused(api, r, 409, "place 'hall' has no image", "spin image")
    assert frame(api, robot, 0.0, path="teach/spin").status_code == 200
    assert api.client.post("/robots/rover/teach/finish", headers=robot).status_code == 200


# --- bad input: clear 4xx, nothing changed ----------------------------------------------------


def test_unknown_things_are_404(api: Api) -> None:
    robot = api.register()
    before = api.dump()
    assert_refused(api, api.client.get("/tours/99", headers=robot), 404, "no tour", "99")
    assert_refused(api, api.client.get("/images/99", headers=robot), 404, "no image")
    r = api.client.post("/robots/rover/teach/start", json={"tour": 42}, headers=robot)
    assert_refused(api, r, 404, "no tour")
    r = api.client.get("/robots/ghost/state", headers=robot)
    assert_refused(api, r, 404, "no robot", "ghost")
    assert api.dump() == before


def test_marking_or_uploading_while_not_teaching_is_409(api: Api) -> None:
    robot = api.register()
    before = api.dump()
    assert_refused(api, mark(api, robot, "kitchen"), 409, "not teaching", "teach/start")
    # a frame is answered in every mode: an idle robot is told to stand, nothing is stored
    idle = frame(api, robot, 0.0)
    assert idle.status_code == 200, idle.text
    assert idle.json()["mode"] == "idle" and idle.json()["command"]["behaviour"] == "stand"
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


@pytest.mark.parametrize("name", ["", "   ", "x" * 65, " kitchen", "kitchen\n", "kitchen\u00a0"])
def test_empty_or_overlong_location_name_is_422(api: Api, name: str) -> None:
    robot = api.register()
    start_teaching(api, robot)
    before = api.dump()
    assert_refused(api, mark(api, robot, name), 422, "name")
    assert api.dump() == before


@pytest.mark.parametrize("tour", [True, "1", 1.5, 0])
def test_a_tour_id_that_is_not_a_positive_json_integer_is_422(api: Api, tour: object) -> None:
    """The schema says integer: neither true nor "1" is taken for 1 (lax pydantic would)."""
    robot = api.register()
    api.client.post("/tours", json={"name": "home"}, headers=robot)
    before = api.dump()
    r = api.client.post("/robots/rover/teach/start", json={"tour": tour}, headers=robot)
    assert_refused(api, r, 422, "tour")
    assert api.dump() == before


@pytest.mark.parametrize("name", ["   ", " home", "home ", "ho\x00me", "ho\tme", "home\x7f1"])
def test_a_tour_name_with_spaces_at_either_end_or_a_control_character_is_422(
    api: Api, name: str
) -> None:
    robot = api.register()
    before = api.dump()
    assert_refused(api, api.client.post("/tours", json={"name": name}, headers=robot), 422, "name")
    assert api.dump() == before


@pytest.mark.parametrize("n_frames", [0, 1])
def test_edge_with_fewer_than_two_images_is_409(api: Api, n_frames: int) -> None:
    """The mark is well formed (422 is for those that are not); the open path is too short."""
    robot = api.register()
    start_teaching(api, robot)
    mark(api, robot, "kitchen")
    for k in range(n_frames):
        frame(api, robot, k)
    before = api.dump()
    assert_refused(api, mark(api, robot, "office"), 409, "at least 2 images", str(n_frames))
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


@pytest.mark.parametrize(
    ("params", "words"),
    [
        ({"timestamp": 1.0, "v": 1e300}, ("query.v", "less than or equal to 5")),
        ({"timestamp": 1.0, "v": -5.5}, ("query.v", "greater than or equal to -5")),
        ({"timestamp": 1.0, "w": 21.0}, ("query.w", "less than or equal to 20")),
        ({"timestamp": 1.0, "w": "-inf"}, ("query.w", "finite")),
        ({"timestamp": 1.0, "v": "nan"}, ("query.v", "finite")),
        ({"timestamp": -1.0}, ("query.timestamp", "greater than or equal to 0")),
        ({"timestamp": 2e10}, ("query.timestamp", "less than or equal to 10000000000")),
        ({"timestamp": "inf"}, ("query.timestamp", "finite")),
        ({"timestamp": 1.0, "depth": [1.0, -0.1]}, ("query.depth.1", "greater than or equal")),
        ({"timestamp": 1.0, "depth": [1001.0]}, ("query.depth.0", "less than or equal to 1000")),
        ({"timestamp": 1.0, "depth": ["inf"]}, ("query.depth.0", "finite")),
        ({"timestamp": 1.0, "depth": [1.0] * 257}, ("query.depth", "at most 256")),
    ],
)
def test_physically_impossible_frame_values_are_422(
    api: Api, params: dict[str, Any], words: tuple[str, ...]
) -> None:
    """Bounds from the schema (and the OpenAPI document): the answer names the parameter and
    the limit; nothing is stored."""
    robot = api.register()
    start_teaching(api, robot)
    mark(api, robot, "kitchen")
    before = api.dump()
    for path in ("frames", "teach/spin"):
        r = api.client.post(
            f"/robots/rover/{path}", params=params, content=make_jpeg(), headers={**robot, **JPEG}
        )
        assert_refused(api, r, 422, *words)
    assert api.dump() == before


def test_a_wild_speed_while_teaching_leaves_the_odometry_intact(api: Api) -> None:
    robot = api.register()
    tour_id = start_teaching(api, robot)
    mark(api, robot, "kitchen")
    for k in range(3):
        assert frame(api, robot, float(k), seed=k).status_code == 200  # 0.3 m/s, 1 s apart
    before = api.dump()
    r = api.client.post(
        "/robots/rover/frames",
        params={"timestamp": 3.0, "v": 1e300},
        content=make_jpeg(3),
        headers={**robot, **JPEG},
    )
    assert_refused(api, r, 422, "query.v", "5")
    assert api.dump() == before
    assert frame(api, robot, 3.0, seed=3).status_code == 200
    edge = mark(api, robot, "office").json()["edge"]
    assert edge["image_count"] == 4
    assert edge["length_m"] == pytest.approx(0.9)  # 3 intervals of 1 s at 0.3 m/s
    graph = api.client.get(f"/tours/{tour_id}", headers=robot).json()
    assert graph["edges"][0]["length_m"] == pytest.approx(0.9)


def test_the_robot_client_sends_rays_that_saw_nothing_within_the_bounds(api: Api) -> None:
    """The simulated depth sensor reports inf beyond its range: the client sends the maximum."""
    import httpx

    from robot_client.client import TeachRepeatClient

    robot = api.register()
    start_teaching(api, robot)
    mark(api, robot, "kitchen")
    sent: list[httpx.Request] = []

    def forward(request: httpx.Request) -> httpx.Response:
        sent.append(request)
        r = api.client.request(
            request.method, str(request.url), content=request.content, headers=request.headers
        )
        return httpx.Response(r.status_code, content=r.content, headers=r.headers)

    token = robot["Authorization"].split()[1]
    with TeachRepeatClient("http://testserver", token, transport=httpx.MockTransport(forward)) as c:
        c.upload_frame("rover", make_jpeg(), timestamp=1.0, depth=[math.inf, math.nan, 2.0, 5e3])
    assert sent[0].url.params.get_list("depth") == ["1000.0", "1000.0", "2.0", "1000.0"]


def test_the_openapi_document_declares_the_physical_bounds(api: Api) -> None:
    spec = api.client.get("/openapi.json").json()
    operation = spec["paths"]["/robots/{robot}/frames"]["post"]
    params = {p["name"]: p["schema"] for p in operation["parameters"]}
    assert (params["timestamp"]["minimum"], params["timestamp"]["maximum"]) == (0, 1e10)
    assert (params["v"]["minimum"], params["v"]["maximum"]) == (-5, 5)
    assert (params["w"]["minimum"], params["w"]["maximum"]) == (-20, 20)
    depth = next(s for s in params["depth"]["anyOf"] if s["type"] == "array")
    assert (depth["items"]["minimum"], depth["items"]["maximum"]) == (0, 1000)


@pytest.mark.parametrize(
    ("text", "where"),
    [
        ('{"name": "a" "b"}', "line 1, column 14: Expecting ',' delimiter"),
        ('{\n  "name": "a"\n  "x": 1}', "line 3, column 3: Expecting ',' delimiter"),
        ('{"name": }', "line 1, column 10: Expecting value"),
    ],
)
def test_malformed_json_says_where(api: Api, text: str, where: str) -> None:
    robot = api.register()
    before = api.dump()
    r = api.client.post(
        "/tours", content=text, headers={**robot, "Content-Type": "application/json"}
    )
    assert_refused(api, r, 422, f"invalid request - body: JSON decode error at {where}")
    assert api.dump() == before


def test_an_undeclared_method_is_405_with_allow(api: Api) -> None:
    for method, url, allowed in (
        ("DELETE", "/tours", "GET, POST"),
        ("TRACE", "/health", "GET"),
        ("PUT", "/robots/rover/frames", "POST"),
    ):
        r = api.client.request(method, url, headers=api.admin)
        assert_refused(api, r, 405, "method not allowed")
        assert r.headers["allow"] == allowed, (url, r.headers)


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
    assert_refused(api, r, 403, "robot token", "household login")
    assert_refused(api, api.client.get("/robots", headers=robot), 403, "household login")
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
    ]
    for method, path, kwargs in calls:
        r = api.client.request(method, path, headers=mine, **kwargs)
        assert_refused(api, r, 403, "belongs to robot 'rover'")
    r = api.client.get("/robots/nobody/state", headers=mine)
    assert_refused(api, r, 404, "no robot named 'nobody'")
    assert api.dump() == before


def test_the_admin_token_is_for_administration_only(api: Api) -> None:
    robot = api.register("rover")
    api.client.post("/tours", json={"name": "home"}, headers=robot)
    for method, path in (
        ("GET", "/robots/rover/state"),
        ("POST", "/robots/rover/stop"),
        ("GET", "/tours"),
        ("GET", "/tours/1"),
        ("GET", "/images/1"),
    ):
        r = api.client.request(method, path, headers=api.admin)
        assert_refused(api, r, 403, "administration only")


def test_bad_robot_name_is_422(api: Api) -> None:
    before = api.dump()
    r = api.client.post("/robots", json={"name": "Has Spaces"}, headers=api.admin)
    assert_refused(api, r, 422, "name")
    assert api.dump() == before
