"""Questions through the API (issue 25 parts 1 and 5, docs/learning.md), on small synthetic
tours (deterministic scenes): "are we at A?" while teaching (yes closes the loop, no marks
look-alikes), "keep this new path?" while navigating (yes adds an edge the planner uses),
undo restores the graph and the likelihoods exactly, and bad answers change nothing."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from conftest import ADMIN_TOKEN, Api
from fastapi.testclient import TestClient
from pydantic import SecretStr

from server.imaging import decode_jpeg, encode_jpeg
from server.policy.costs import edge_costs
from server.services.container import Services
from server.vision import extract

JPEG = {"Content-Type": "image/jpeg"}


def scene(k: int) -> bytes:
    """A deterministic synthetic view: smooth colours and a dozen rectangles (corners)."""
    rng = np.random.default_rng(k)
    small = rng.integers(0, 255, (6, 8, 3), dtype=np.uint8)
    img = cv2.resize(small, (320, 240), interpolation=cv2.INTER_CUBIC)
    for _ in range(12):
        x, y = (int(z) for z in rng.integers(0, 300, 2))
        w, h = (int(z) for z in rng.integers(8, 40, 2))
        colour = tuple(int(c) for c in rng.integers(0, 255, 3))
        cv2.rectangle(img, (x, y), (x + w, y + h), colour, -1)
    return encode_jpeg(img)


@dataclass
class Home:
    api: Api
    robot: dict[str, str]
    tour: int
    now: list[float]
    t: list[float]

    @property
    def c(self) -> TestClient:
        return self.api.client

    @property
    def services(self) -> Services:
        return self.c.app.state.services  # type: ignore[attr-defined,no-any-return]

    def post(self, url: str, data: bytes, v: float = 0.3, dt: float = 0.5) -> dict[str, Any]:
        self.t[0] += dt
        r = self.c.post(
            f"/robots/rover/{url}",
            params={"timestamp": self.t[0], "v": v},
            content=data,
            headers={**self.robot, **JPEG},
        )
        assert r.status_code == 200, r.text
        return dict(r.json())

    def mark(self, name: str) -> None:
        r = self.c.post("/robots/rover/teach/locations", json={"name": name}, headers=self.robot)
        assert r.status_code == 200, r.text

    def questions(self) -> list[dict[str, Any]]:
        r = self.c.get("/robots/rover/questions", headers=self.robot)
        assert r.status_code == 200, r.text
        return list(r.json())

    def answer(self, question: int, answer: str, headers: dict[str, str] | None = None) -> Any:
        return self.c.post(
            f"/robots/rover/questions/{question}",
            json={"answer": answer},
            headers=self.robot if headers is None else headers,
        )

    def graph(self) -> dict[str, Any]:
        return dict(self.c.get(f"/tours/{self.tour}", headers=self.robot).json())


def teach_abc(home: Home) -> None:
    """Places A, B, C (one spin image each: scenes 10, 11, 12) joined A -> B -> C by five
    frames each; teaching goes on from C."""
    r = home.c.post("/robots/rover/teach/start", json={"tour": home.tour}, headers=home.robot)
    assert r.status_code == 200, r.text
    for i, name in enumerate("ABC"):
        if i:
            for k in range(5):
                home.post("frames", scene(100 * i + k))
        home.mark(name)
        home.post("teach/spin", scene(10 + i), v=0.0)


@pytest.fixture()
def home(tmp_path: Path) -> Iterator[Home]:
    from server.app import create_app
    from server.config import Settings

    db_path = tmp_path / "api.sqlite"
    settings = Settings(
        db=db_path,
        admin_token=SecretStr(ADMIN_TOKEN),
        dashboard_port=None,
        navigation={"questions.teaching": True, "questions.exploration": True},
    )
    now = [1_000_000.0]
    with TestClient(create_app(settings, wall_clock=lambda: now[0])) as client:
        api = Api(client, db_path, {"Authorization": f"Bearer {ADMIN_TOKEN}"})
        robot = api.register()
        tour = client.post("/tours", json={"name": "flat"}, headers=robot).json()["id"]
        yield Home(api, robot, tour, now, [0.0])


def back_at_a(home: Home, frames: int = 8) -> list[dict[str, Any]]:
    """From C, three new views, then A's view until the robot asks (at most ``frames``).
    The tour's runtime is brought up to date first (as the background rebuild does a second
    after teaching changed it), so the test does not depend on that thread's timing."""
    home.services.navigation.runtime(home.tour)
    for k in range(3):
        home.post("frames", scene(900 + k))
    for _ in range(frames):
        home.post("frames", scene(10), v=0.0)
        asked = home.questions()
        if asked:
            return asked
    return []


def probe_likelihood(home: Home) -> np.ndarray:
    services = home.services
    probe = extract(decode_jpeg(scene(10), services.limits)[0])
    return services.navigation.runtime(home.tour).observe(probe)[1]


def test_yes_closes_the_loop_and_undo_restores_graph_and_likelihoods(home: Home) -> None:
    teach_abc(home)
    before_lik = probe_likelihood(home)  # builds the runtime: the images' entropies are stored
    before_graph = home.graph()
    (q,) = back_at_a(home)
    assert q["kind"] == "same_place" and q["location"] == "A" and q["source_location"] == "C"
    assert q["text"] == "Are we at 'A'?" and q["state"] == "open" and q["confidence"] >= 0.9
    assert q["expires_at"] == home.now[0] + 120.0
    # the same question is not asked twice while it is open
    home.post("frames", scene(10), v=0.0)
    assert [x["id"] for x in home.questions()] == [q["id"]]

    r = home.answer(q["id"], "yes")
    assert r.status_code == 200, r.text
    assert r.json()["state"] == "yes" and r.json()["change"] is not None
    assert home.questions() == []
    state = home.c.get("/robots/rover/state", headers=home.robot).json()
    assert state["teaching"]["current_location"] == "A"  # teaching goes on from A
    graph = home.graph()
    closing = [e for e in graph["edges"] if (e["source_name"], e["target_name"]) == ("C", "A")]
    assert len(closing) == 1 and len(graph["locations"]) == 3  # joined, no new place
    (change,) = home.c.get(f"/tours/{home.tour}/learned", headers=home.robot).json()
    assert change["kind"] == "loop_closure" and change["edge"] == closing[0]["id"]
    assert change["images"] == closing[0]["image_count"] and "question" in change["source"]
    assert not np.array_equal(probe_likelihood(home), before_lik)  # the map changed

    r = home.c.delete(f"/tours/{home.tour}/learned/{change['id']}", headers=home.robot)
    assert r.status_code == 204, r.text
    # the graph as it was before the answer, with the images' entropies (a derived cache,
    # refreshed when the runtime is rebuilt) computed over the same images again
    assert np.array_equal(probe_likelihood(home), before_lik)
    assert home.graph() == before_graph


def test_no_marks_look_alikes_and_is_not_asked_again_until_undone(home: Home) -> None:
    teach_abc(home)
    (q,) = back_at_a(home)
    before_graph = home.graph()
    r = home.answer(q["id"], "no")
    assert r.status_code == 200 and r.json()["state"] == "no", r.text
    for _ in range(4):  # still looking at A: not asked again on this path
        home.post("frames", scene(10), v=0.0)
    assert home.questions() == []
    assert home.graph() == before_graph  # they stay apart
    (change,) = home.c.get(f"/tours/{home.tour}/learned", headers=home.robot).json()
    assert change["kind"] == "look_alike" and change["edge"] is None
    pair = home.services.repo.look_alike_images(home.services.repo.location_by_name(home.tour, "A"))  # type: ignore[arg-type]
    assert pair == {q["match_image_id"]}
    r = home.c.delete(f"/tours/{home.tour}/learned/{change['id']}", headers=home.robot)
    assert r.status_code == 204
    for _ in range(8):  # undone: the robot asks again (a fresh tracker on the rebuilt tour)
        home.post("frames", scene(10), v=0.0)
        if home.questions():
            break
    assert [x["location"] for x in home.questions()] == ["A"]


def test_a_mark_withdraws_the_question_and_bad_answers_change_nothing(home: Home) -> None:
    teach_abc(home)
    (q,) = back_at_a(home)
    c = home.c
    # another household: its login and its robot see no such robot or question
    admin = home.api.admin
    c.post("/households", json={"name": "bee", "password": "correct horse battery"}, headers=admin)
    login = c.post("/auth/login", json={"household": "bee", "password": "correct horse battery"})
    bee = {"Authorization": f"Bearer {login.json()['token']}"}
    bob = c.post("/robots", json={"name": "bob"}, headers=bee).json()["token"]
    before = home.api.dump()
    r = home.answer(q["id"], "yes", headers=bee)
    assert r.status_code == 404 and "Are we" not in r.text, r.text
    r = c.post(
        f"/robots/bob/questions/{q['id']}",
        json={"answer": "yes"},
        headers={"Authorization": f"Bearer {bob}"},
    )
    assert r.status_code == 404 and "no question" in r.json()["detail"], r.text
    assert c.get("/robots/bob/questions", headers=bee).json() == []
    r = home.answer(9999, "yes")
    assert r.status_code == 404 and "no question 9999" in r.json()["detail"], r.text
    r = home.answer(q["id"], "maybe")
    assert r.status_code == 422 and "answer" in r.json()["detail"], r.text
    home.now[0] += 121.0  # expired
    r = home.answer(q["id"], "yes")
    assert r.status_code == 410 and "expired" in r.json()["detail"], r.text
    assert home.questions() == []
    assert home.api.dump() == before

    # a fresh question, then the person marks the place: the question is withdrawn (409)
    home.now[0] += 1.0
    home.post("frames", scene(10), v=0.0)
    (q2,) = home.questions()
    assert q2["id"] != q["id"]
    home.mark("A")
    assert home.questions() == []
    before = home.api.dump()
    r = home.answer(q2["id"], "yes")
    assert r.status_code == 409 and "withdrawn" in r.json()["detail"], r.text
    assert home.api.dump() == before


def test_a_new_path_found_while_navigating_is_added_on_yes_and_used_by_the_planner(
    home: Home,
) -> None:
    teach_abc(home)
    c = home.c
    assert c.post("/robots/rover/teach/finish", headers=home.robot).status_code == 200
    before_lik = probe_likelihood(home)
    before_graph = home.graph()
    rt = home.services.navigation.runtime(home.tour)
    a, cc = rt.graph.location_index("A"), rt.graph.location_index("C")
    before_cost = float(rt.costs(cc)[a])
    r = c.post("/robots/rover/goto", json={"location": "B"}, headers=home.robot)
    assert r.status_code == 200, r.text
    # at A, then twelve views no edge explains, then C, driving 1 m/s (faster than taught)
    for img in [scene(10)] * 5 + [scene(900 + k) for k in range(12)] + [scene(12)] * 6:
        home.post("frames", img, v=1.0, dt=0.1)
    (q,) = home.questions()
    assert q["kind"] == "new_path" and (q["source_location"], q["location"]) == ("A", "C")
    assert q["frames"] >= 12 and "Keep it?" in q["text"]

    r = home.answer(q["id"], "yes")
    assert r.status_code == 200 and r.json()["state"] == "yes", r.text
    (change,) = c.get(f"/tours/{home.tour}/learned", headers=home.robot).json()
    assert change["kind"] == "new_path" and change["images"] == q["frames"]
    graph = home.graph()
    new = [e for e in graph["edges"] if e["id"] == change["edge"]]
    assert len(new) == 1 and (new[0]["source_name"], new[0]["target_name"]) == ("A", "C")
    # the planner uses it: from A, C is now as far as the new edge alone
    rt = home.services.navigation.runtime(home.tour)
    edge = next(j for j, e in enumerate(rt.graph.edges) if e.id == change["edge"])
    assert float(rt.costs(cc)[a]) < before_cost
    alone = float(edge_costs(rt.graph, rt.params.costs)[edge])
    assert float(rt.costs(cc)[a]) == pytest.approx(alone)

    # a second answer is refused and changes nothing; so are an unknown change and another
    # household's look at the tour; undo restores the taught tour
    password = "correct horse battery"
    c.post("/households", json={"name": "bee", "password": password}, headers=home.api.admin)
    login = c.post("/auth/login", json={"household": "bee", "password": password})
    bee = {"Authorization": f"Bearer {login.json()['token']}"}
    before = home.api.dump()
    r = home.answer(q["id"], "no")
    assert r.status_code == 409 and "already answered 'yes'" in r.json()["detail"], r.text
    r = c.delete(f"/tours/{home.tour}/learned/9999", headers=home.robot)
    assert r.status_code == 404 and "no learned change 9999" in r.json()["detail"], r.text
    assert c.get(f"/tours/{home.tour}/learned", headers=bee).status_code == 404
    r = c.delete(f"/tours/{home.tour}/learned/{change['id']}", headers=bee)
    assert r.status_code == 404 and "rover" not in r.text
    assert home.api.dump() == before
    r = c.delete(f"/tours/{home.tour}/learned/{change['id']}", headers=home.robot)
    assert r.status_code == 204
    assert np.array_equal(probe_likelihood(home), before_lik)  # (refreshes the entropies)
    assert home.graph() == before_graph


def test_no_to_a_new_path_discards_its_frames(home: Home) -> None:
    teach_abc(home)
    assert home.c.post("/robots/rover/teach/finish", headers=home.robot).status_code == 200
    probe_likelihood(home)  # builds the runtime (stores the images' entropies)
    before_graph = home.graph()
    home.c.post("/robots/rover/goto", json={"location": "B"}, headers=home.robot)
    for img in [scene(10)] * 5 + [scene(900 + k) for k in range(12)] + [scene(12)] * 6:
        home.post("frames", img)
    (q,) = home.questions()
    r = home.answer(q["id"], "no")
    assert r.status_code == 200 and r.json()["state"] == "no" and r.json()["frames"] == 0
    assert home.graph() == before_graph
    assert home.c.get(f"/tours/{home.tour}/learned", headers=home.robot).json() == []
