"""Junctions from shared path prefixes through the API (docs/learning.md, "Junctions"), on real
frames: two paths leave 'entry' down the same corridor (the corridor's two traversals, ref and
query) and part; the search finds one junction, a dry run changes nothing, bad input is refused
with the database unchanged, and undoing the junction restores the graph and the likelihoods
bit for bit.

The corridor's two traversals differ more than two simulated runs do (the default
``max_error`` is chosen in the simulator): the server runs with the deployment setting
``learning.junctions.max_error=0.665``, which separates this corridor from elsewhere."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from conftest import ADMIN_TOKEN, Api
from fastapi.testclient import TestClient
from pydantic import SecretStr
from test_api_navigation import JPEG

from server.belief.junctions import Junction
from server.imaging import decode_jpeg
from server.services.container import Services
from server.vision import extract

SHARED = 45  # images of the corridor both paths drive before they part


@pytest.fixture()
def api(tmp_path: Path) -> Iterator[Api]:
    from server.app import create_app
    from server.config import Settings

    db_path = tmp_path / "api.sqlite"
    settings = Settings(
        db=db_path,
        admin_token=SecretStr(ADMIN_TOKEN),
        dashboard_port=None,
        navigation={"learning.junctions.max_error": 0.665},
    )
    with TestClient(create_app(settings)) as client:
        yield Api(client, db_path, {"Authorization": f"Bearer {ADMIN_TOKEN}"})


def teach_fork(api: Api, robot: dict[str, str], data: Path) -> int:
    """entry -> office down the corridor (ref 1..79), back to entry (ref 79..1), then
    entry -> garden: the corridor's other traversal (query 1..SHARED), then other images."""
    c = api.client
    ref = sorted((data / "corridor" / "ref").glob("*.jpg"))
    query = sorted((data / "corridor" / "query").glob("*.jpg"))
    other = sorted((data / "triplets").rglob("*.jpg"))[:24]
    tour = c.post("/tours", json={"name": "fork"}, headers=robot).json()["id"]
    assert c.post("/robots/rover/teach/start", json={"tour": tour}, headers=robot).is_success
    t = [0.0]

    def send(url: str, path: Path) -> None:
        t[0] += 0.1
        r = c.post(
            url,
            params={"timestamp": t[0], "v": 0.3},
            content=path.read_bytes(),
            headers={**robot, **JPEG},
        )
        assert r.status_code == 200, r.text

    def place(name: str, spin: Path | None) -> None:
        r = c.post("/robots/rover/teach/locations", json={"name": name}, headers=robot)
        assert r.status_code == 200, r.text
        if spin is not None:
            send("/robots/rover/teach/spin", spin)

    place("entry", ref[0])
    for p in ref[1:80]:
        send("/robots/rover/frames", p)
    place("office", ref[80])
    for p in ref[79:0:-1]:
        send("/robots/rover/frames", p)
    place("entry", None)
    for p in [*query[1 : 1 + SHARED], *other]:
        send("/robots/rover/frames", p)
    place("garden", sorted((data / "ukbench").glob("*.jpg"))[0])
    assert c.post("/robots/rover/teach/finish", headers=robot).status_code == 200
    return int(tour)


def test_find_apply_refuse_and_undo(api: Api, shared_data: Path) -> None:
    c = api.client
    services: Services = c.app.state.services  # type: ignore[attr-defined]
    robot = api.register()
    tour = teach_fork(api, robot, shared_data)
    before_rt = services.navigation.runtime(tour)
    taught = before_rt.graph
    assert [loc.name for loc in taught.locations] == ["entry", "office", "garden"]
    probes = [
        extract(decode_jpeg(p.read_bytes(), services.limits)[0])
        for p in sorted((shared_data / "corridor" / "query").glob("*.jpg"))[10:90:20]
    ]
    before = [before_rt.observe(f)[1] for f in probes]

    # a dry run lists the junction and changes nothing
    dump = api.dump()
    r = c.post(f"/tours/{tour}/junctions", json={"dry_run": True}, headers=robot)
    assert r.status_code == 200, r.text
    (found,) = r.json()["junctions"]
    assert r.json()["changes"] == [] and found["change"] is None
    assert (found["source"], found["kept_target"], found["other_target"]) == (
        "entry",
        "office",
        "garden",
    )
    # the junction goes 0.5 m (17 images at 0.03 m each) before the paths part
    back = 17
    assert abs(found["kept_shared"] - (SHARED - back)) <= 6, found
    assert abs(found["other_shared"] - (SHARED - back)) <= 6, found
    assert api.dump() == dump

    # bad input: a clear 4xx, nothing changed
    for method, url, body in [
        ("POST", f"/tours/{tour}/junctions", {"dry_run": "maybe"}),
        ("POST", f"/tours/{tour}/junctions", {"dryrun": True}),
        ("POST", "/tours/999/junctions", {}),
        ("DELETE", f"/tours/{tour}/learned/12345", None),
    ]:
        r = c.request(method, url, json=body, headers=robot)
        assert r.status_code in (404, 422), (url, r.text)
        assert r.json()["detail"], r.text
        assert api.dump() == dump, url

    # apply: one learned change; the runtime's graph has the junction
    r = c.post(f"/tours/{tour}/junctions", json={}, headers=robot)
    assert r.status_code == 200, r.text
    (change,) = r.json()["changes"]
    assert change["kind"] == "junction" and r.json()["junctions"][0]["change"] == change["id"]
    listed = c.get(f"/tours/{tour}/learned", headers=robot).json()
    assert [x["id"] for x in listed] == [change["id"]] and listed[0]["kind"] == "junction"
    refined = services.navigation.runtime(tour)
    g = refined.graph
    assert g.n_locations == 4 and g.locations[3].junction and len(g.locations[3].image_ids) == 1
    assert g.n_edges == taught.n_edges + 1
    assert g.n_images == taught.n_images - found["other_shared"]
    assert refined.index.n_images == taught.n_images  # the mapped images stay, as appearances
    assert [(e.source, e.target) for e in g.edges] == [(0, 3), (3, 1), (1, 0), (3, 2)]
    # found again: nothing more (and nothing stored)
    dump = api.dump()
    r = c.post(f"/tours/{tour}/junctions", json={}, headers=robot)
    assert r.status_code == 200 and r.json()["junctions"] == [], r.text
    assert api.dump() == dump

    # undo: the taught graph and its likelihoods, bit for bit
    r = c.delete(f"/tours/{tour}/learned/{change['id']}", headers=robot)
    assert r.status_code == 204, r.text
    assert c.get(f"/tours/{tour}/learned", headers=robot).json() == []
    after_rt = services.navigation.runtime(tour)
    assert after_rt is not before_rt
    after = after_rt.graph
    assert after.locations == taught.locations
    assert [(e.source, e.target, e.image_ids, e.id) for e in after.edges] == [
        (e.source, e.target, e.image_ids, e.id) for e in taught.edges
    ]
    for a, b in zip(after.edges, taught.edges, strict=True):
        np.testing.assert_array_equal(a.timestamps, b.timestamps)
    np.testing.assert_array_equal(after.image_entropy, taught.image_entropy)
    np.testing.assert_array_equal(after_rt.index.weights, before_rt.index.weights)
    for f, lik in zip(probes, before, strict=True):
        np.testing.assert_array_equal(after_rt.observe(f)[1], lik)


def blocks(seed: int) -> bytes:
    """A 64x48 JPEG of 8x6 random colour blocks: one seed, one look."""
    from server.imaging import encode_jpeg

    rng = np.random.default_rng(seed)
    grid = rng.integers(0, 255, (6, 8, 3), dtype=np.uint8)
    return encode_jpeg(np.kron(grid, np.ones((8, 8, 1), dtype=np.uint8)))


def test_two_junctions_in_a_row(api: Api) -> None:
    """S -> A and S -> B share 20 images, S -> C the first 10 of them: two junctions in a row,
    each removable on its own; one stored on the first one's remainders makes removing the
    first a 409 that changes nothing."""
    c = api.client
    robot = api.register()
    tour = c.post("/tours", json={"name": "three"}, headers=robot).json()["id"]
    assert c.post("/robots/rover/teach/start", json={"tour": tour}, headers=robot).is_success
    t = [0.0]

    def send(url: str, seed: int) -> None:
        t[0] += 0.1
        r = c.post(
            url,
            params={"timestamp": t[0], "v": 1.5},  # 0.15 m per image
            content=blocks(seed),
            headers={**robot, **JPEG},
        )
        assert r.status_code == 200, r.text

    def place(name: str, spin: int | None) -> None:
        r = c.post("/robots/rover/teach/locations", json={"name": name}, headers=robot)
        assert r.status_code == 200, r.text
        if spin is not None:
            send("/robots/rover/teach/spin", spin)

    place("S", 1)
    for target, shared, own in (("A", 20, 100), ("B", 20, 200), ("C", 10, 300)):
        for k in range(shared):
            send("/robots/rover/frames", 1000 + k)
        for k in range(10):
            send("/robots/rover/frames", own + k)
        place(target, own + 50)
        for k in range(5):
            send("/robots/rover/frames", own + 60 + k)
        place("S", None)
    assert c.post("/robots/rover/teach/finish", headers=robot).status_code == 200

    r = c.post(f"/tours/{tour}/junctions", json={}, headers=robot)
    assert r.status_code == 200, r.text
    first, second = r.json()["junctions"]
    assert (first["kept_target"], first["other_target"]) == ("A", "B")
    assert (second["kept_target"], second["other_target"]) == ("(junction 1)", "C")
    one, two = (x["change"] for x in (first, second))
    services: Services = c.app.state.services  # type: ignore[attr-defined]
    assert sum(loc.junction for loc in services.navigation.runtime(tour).graph.locations) == 2
    # a junction stored on the first one's remainders depends on it: the first cannot go
    g = services.navigation.runtime(tour).graph
    j1 = next(k for k, loc in enumerate(g.locations) if loc.name == "(junction 1)")
    rest_a, rest_b = (e for e in g.edges if e.source == j1)
    later = services.repo.add_junction_change(
        tour,
        Junction(rest_a.image_ids[0], rest_b.image_ids[0], 3, 3, (0, 1, 2)),
        source="test",
        summary="on the remainders of junction 1",
        now=0.0,
    )
    services.navigation.tour_changed(tour)
    dump = api.dump()
    r = c.delete(f"/tours/{tour}/learned/{one}", headers=robot)
    assert r.status_code == 409 and str(later) in r.json()["detail"], r.text
    assert api.dump() == dump
    assert c.delete(f"/tours/{tour}/learned/{later}", headers=robot).status_code == 204
    # the second junction's edges start where the taught ones do: it still applies alone
    assert c.delete(f"/tours/{tour}/learned/{one}", headers=robot).status_code == 204
    assert [x["id"] for x in c.get(f"/tours/{tour}/learned", headers=robot).json()] == [two]
    alone = services.navigation.runtime(tour).graph
    assert [loc.name for loc in alone.locations if loc.junction] == ["(junction 1)"]
    assert c.delete(f"/tours/{tour}/learned/{two}", headers=robot).status_code == 204
    assert not any(loc.junction for loc in services.navigation.runtime(tour).graph.locations)
