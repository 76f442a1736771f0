"""Learning from a repeat run through the API (docs/learning.md), on the real corridor frames:
learn (transitions), list, bad input changes nothing, undo restores the taught behaviour
exactly."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from conftest import ADMIN_TOKEN, Api
from fastapi.testclient import TestClient
from pydantic import SecretStr
from test_api_navigation import post_frame, teach_corridor

from server.imaging import decode_jpeg
from server.services.container import Services
from server.vision import extract


@pytest.fixture()
def api(tmp_path: Path) -> Iterator[Api]:
    from server.app import create_app
    from server.config import Settings

    db_path = tmp_path / "api.sqlite"
    settings = Settings(
        db=db_path,
        admin_token=SecretStr(ADMIN_TOKEN),
        dashboard_port=None,
        navigation={"learning.collect": True},
    )
    with TestClient(create_app(settings)) as client:
        yield Api(client, db_path, {"Authorization": f"Bearer {ADMIN_TOKEN}"})


def test_learn_list_refuse_and_undo(api: Api, shared_data: Path) -> None:
    c = api.client
    services: Services = c.app.state.services  # type: ignore[attr-defined]
    robot = api.register()
    tour = teach_corridor(api, robot, shared_data / "corridor" / "ref")
    queries = sorted((shared_data / "corridor" / "query").glob("*.jpg"))
    probe = extract(decode_jpeg(queries[50].read_bytes(), services.limits)[0])
    taught = services.navigation.runtime(tour).observe(probe)[1]

    # nothing to learn before a task arrived
    r = c.post("/robots/rover/learn", headers=robot)
    assert r.status_code == 409 and "arrived" in r.json()["detail"], r.text

    r = c.post("/robots/rover/goto", json={"location": "kitchen"}, headers=robot)
    assert r.status_code == 200, r.text
    for k, path in enumerate(queries):
        body = post_frame(api, robot, path, 100 + k / 10).json()
    # the query traversal ends where the reference one did: the path tracker, locked on the
    # corridor, puts the replayed frames at its end and the task arrives
    assert body["task"]["state"] == "arrived", body["task"]

    r = c.post("/robots/rover/learn", headers=robot)
    assert r.status_code == 200, r.text
    made = r.json()
    assert [m["kind"] for m in made] == ["transitions"]
    assert all(m["tour"] == tour and "rover" in m["source"] for m in made)
    (transitions,) = made
    listed = c.get(f"/tours/{tour}/learned", headers=robot).json()
    assert [m["id"] for m in listed] == [m["id"] for m in made]
    rt = services.navigation.runtime(tour)
    assert rt.model.advance_scale is not None
    # the same run cannot be learned twice
    assert c.post("/robots/rover/learn", headers=robot).status_code == 409

    # bad input: an unknown change, another household's tour -> 404 and nothing changes
    password = "correct horse battery"
    c.post("/households", json={"name": "bee", "password": password}, headers=api.admin)
    token = c.post("/auth/login", json={"household": "bee", "password": password}).json()
    bee = {"Authorization": f"Bearer {token['token']}"}
    before = api.dump()
    r = c.delete(f"/tours/{tour}/learned/9999", headers=robot)
    assert r.status_code == 404 and "no learned change 9999" in r.json()["detail"], r.text
    assert c.get(f"/tours/{tour}/learned", headers=bee).status_code == 404
    r = c.delete(f"/tours/{tour}/learned/{transitions['id']}", headers=bee)
    assert r.status_code == 404 and "rover" not in r.text
    assert api.dump() == before

    # undo: remove every change, the tour answers exactly as taught
    for m in made:
        assert c.delete(f"/tours/{tour}/learned/{m['id']}", headers=robot).status_code == 204
    assert c.get(f"/tours/{tour}/learned", headers=robot).json() == []
    rt = services.navigation.runtime(tour)
    assert rt.model.advance_scale is None
    assert np.array_equal(rt.observe(probe)[1], taught)
