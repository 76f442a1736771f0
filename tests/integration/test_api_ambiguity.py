"""Distinctiveness and taught poses in GET /tours/{id}, and the answers to frames while
navigating, on a tour taught from the real corridor frames with poses."""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import ADMIN_TOKEN, Api
from fastapi.testclient import TestClient
from pydantic import SecretStr

JPEG = {"Content-Type": "image/jpeg"}
MARKS = {0: "entry", 36: "hall", 73: "office", 110: "kitchen"}
STEP_M = 0.1
"""The corridor frames are taught as if 0.1 m apart along the x axis (1 m/s, 10 frames/s)."""


@pytest.fixture()
def api_with(tmp_path: Path) -> Iterator[Api]:
    from server.app import create_app
    from server.config import Settings

    settings = Settings(
        db=tmp_path / "api.sqlite",
        admin_token=SecretStr(ADMIN_TOKEN),
        dashboard_port=None,
    )
    with TestClient(create_app(settings)) as client:
        yield Api(client, tmp_path / "api.sqlite", {"Authorization": f"Bearer {ADMIN_TOKEN}"})


def test_entropies_poses_and_navigating_answers(api_with: Api, shared_data: Path) -> None:
    api = api_with
    robot = api.register()
    tour = api.client.post("/tours", json={"name": "corridor"}, headers=robot).json()["id"]
    api.client.post("/robots/rover/teach/start", json={"tour": tour}, headers=robot)
    frames = sorted((shared_data / "corridor" / "ref").glob("*.jpg"))
    for k, path in enumerate(frames):
        params = {"timestamp": k / 10, "v": 1.0, "pose": [k * STEP_M, 0.0, 0.0]}
        url = "/robots/rover/frames"
        if k in MARKS:
            api.client.post("/robots/rover/teach/locations", json={"name": MARKS[k]}, headers=robot)
            url = "/robots/rover/teach/spin"
        r = api.client.post(
            url, params=params, content=path.read_bytes(), headers={**robot, **JPEG}
        )
        assert r.status_code == 200, r.text
    assert api.client.post("/robots/rover/teach/finish", headers=robot).status_code == 200
    r = api.client.post("/robots/rover/goto", json={"location": "kitchen"}, headers=robot)
    assert r.status_code == 200, r.text  # the runtime is built: entropies computed and stored
    graph = api.client.get(f"/tours/{tour}", headers=robot).json()
    for part in graph["locations"] + graph["edges"]:
        assert part["poses"] is not None and len(part["entropy"]) == len(part["poses"])
        assert all(0 <= h <= math.log(2 * len(graph["locations"]) + 2) for h in part["entropy"])
    for edge in graph["edges"]:  # kept as sent: along the x axis, STEP_M apart
        xs = [p[0] for p in edge["poses"]]
        assert all(p[1:] == [0.0, 0.0] for p in edge["poses"])
        assert all(b - a == pytest.approx(STEP_M) for a, b in itertools.pairwise(xs))
    queries = sorted((shared_data / "corridor" / "query").glob("*.jpg"))
    for k, path in enumerate(queries[:40]):
        r = api.client.post(
            "/robots/rover/frames",
            params={"timestamp": 100 + k / 10, "v": 1.0},
            content=path.read_bytes(),
            headers={**robot, **JPEG},
        )
        assert r.status_code == 200, r.text
        body = r.json()
        assert body["mode"] == "navigating"
        assert "disambiguation" not in body  # active disambiguation was removed
