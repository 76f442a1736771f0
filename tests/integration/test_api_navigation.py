"""Navigation endpoints on a tour taught from the real corridor frames."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import Api, make_jpeg

from server.navigation import BEHAVIOURS

JPEG = {"Content-Type": "image/jpeg"}
MARKS = {0: "entry", 36: "hall", 73: "office", 110: "kitchen"}


def teach_corridor(api: Api, robot: dict[str, str], frames: Path) -> int:
    tour_id = api.client.post("/tours", json={"name": "corridor"}, headers=robot).json()["id"]
    api.client.post("/robots/rover/teach/start", json={"tour": tour_id}, headers=robot)
    for k, path in enumerate(sorted(frames.glob("*.jpg"))):
        params = {"timestamp": k / 10, "v": 0.3}
        if k in MARKS:
            r = api.client.post(
                "/robots/rover/teach/locations", json={"name": MARKS[k]}, headers=robot
            )
            assert r.status_code == 200, r.text
            url = "/robots/rover/teach/spin"
        else:
            url = "/robots/rover/frames"
        r = api.client.post(
            url, params=params, content=path.read_bytes(), headers={**robot, **JPEG}
        )
        assert r.status_code == 200, r.text
    assert api.client.post("/robots/rover/teach/finish", headers=robot).status_code == 200
    return int(tour_id)


@pytest.fixture()
def taught(api: Api, shared_data: Path) -> tuple[Api, dict[str, str], int]:
    robot = api.register()
    tour_id = teach_corridor(api, robot, shared_data / "corridor" / "ref")
    return api, robot, tour_id


def post_frame(api: Api, robot: dict[str, str], path: Path, t: float, **extra: object):
    return api.client.post(
        "/robots/rover/frames",
        params={"timestamp": t, "v": 0.3, **extra},
        content=path.read_bytes(),
        headers={**robot, **JPEG},
    )


def test_goto_then_frames_are_answered_with_commands(
    taught: tuple[Api, dict[str, str], int], shared_data: Path
) -> None:
    api, robot, tour_id = taught
    r = api.client.post("/robots/rover/goto", json={"location": "kitchen"}, headers=robot)
    assert r.status_code == 200, r.text
    task = r.json()
    assert (task["goal"], task["state"], task["tour"]) == ("kitchen", "underway", tour_id)
    state = api.client.get("/robots/rover/state", headers=robot).json()
    assert state["mode"] == "navigating"
    queries = sorted((shared_data / "corridor" / "query").glob("*.jpg"))
    for k, path in enumerate(queries[:20]):
        r = post_frame(api, robot, path, 100 + k / 10, depth=[2.0, 1.5, 3.0])
        assert r.status_code == 200, r.text
        body = r.json()
        assert body["mode"] == "navigating"
        command = body["command"]
        assert command["ttl_s"] > 0
        assert command["action"] in {"rotate_and_find_edge", "navigate", "explore", "do_nothing"}
        assert command["behaviour"] in BEHAVIOURS
        assert command["reason"]  # why the behaviour that won this frame chose the command
        assert abs(sum(body["votes"].values()) - 1.0) < 1e-6
        top = body["belief"]["top"]
        assert top and abs(top[0]["probability"]) <= 1.0
    # after 20 frames from the start of the corridor the belief is on its first part
    assert top[0]["name"] in {"entry", "entry -> hall"}, top
    r = api.client.post("/robots/rover/stop", headers=robot)
    assert r.status_code == 200 and r.json()["state"] == "cancelled"
    state = api.client.get("/robots/rover/state", headers=robot).json()
    assert state["mode"] == "idle" and state["navigation"]["task"]["state"] == "cancelled"
    # frames after the task ended keep the belief up to date and say: stand still
    r = post_frame(api, robot, queries[21], 103.0)
    assert r.json()["command"]["v"] == 0.0 and r.json()["command"]["w"] == 0.0


def test_goto_unknown_place_is_404(taught: tuple[Api, dict[str, str], int]) -> None:
    api, robot, _ = taught
    before = api.dump()
    r = api.client.post("/robots/rover/goto", json={"location": "attic"}, headers=robot)
    assert r.status_code == 404 and "attic" in r.json()["detail"]
    assert "kitchen" in r.json()["detail"]  # says which places exist
    assert api.dump() == before


def test_goto_a_place_without_an_image_is_409_and_says_how_to_give_it_one(
    taught: tuple[Api, dict[str, str], int], shared_data: Path
) -> None:
    api, robot, tour_id = taught
    teach = "/robots/rover/teach"
    api.client.post(f"{teach}/start", json={"tour": tour_id}, headers=robot)
    api.client.post(f"{teach}/locations", json={"name": "attic"}, headers=robot)
    assert api.client.post(f"{teach}/abort", headers=robot).status_code == 200  # no image
    before = api.dump()
    r = api.client.post("/robots/rover/goto", json={"location": "attic"}, headers=robot)
    assert r.status_code == 409, r.text
    detail = r.json()["detail"]
    for words in ("'attic'", "no image", f"{teach}/start", f"{teach}/locations", f"{teach}/spin"):
        assert words in detail, detail
    assert api.dump() == before
    # what the message says works
    api.client.post(f"{teach}/start", json={"tour": tour_id}, headers=robot)
    api.client.post(f"{teach}/locations", json={"name": "attic"}, headers=robot)
    image = (shared_data / "corridor" / "query" / "0000000.jpg").read_bytes()
    r = api.client.post(
        f"{teach}/spin", params={"timestamp": 1e3}, content=image, headers={**robot, **JPEG}
    )
    assert r.status_code == 200, r.text
    assert api.client.post(f"{teach}/finish", headers=robot).status_code == 200
    r = api.client.post("/robots/rover/goto", json={"location": "attic"}, headers=robot)
    assert r.status_code == 200, r.text


def test_goto_without_a_tour_when_the_robot_has_none_is_409(api: Api) -> None:
    """Well-formed (the schema makes ``tour`` optional), but the robot has no tour of its own
    and there is more than one: a conflict with the state, not invalid input."""
    robot = api.register()
    for name in ("home", "office"):
        api.client.post("/tours", json={"name": name}, headers=robot)
    before = api.dump()
    r = api.client.post("/robots/rover/goto", json={"location": "kitchen"}, headers=robot)
    assert r.status_code == 409 and "pass 'tour'" in r.json()["detail"], r.text
    assert api.dump() == before


def test_goto_unknown_tour_is_404(taught: tuple[Api, dict[str, str], int]) -> None:
    api, robot, _ = taught
    r = api.client.post(
        "/robots/rover/goto", json={"location": "kitchen", "tour": 99}, headers=robot
    )
    assert r.status_code == 404 and "no tour" in r.json()["detail"]


def test_goto_while_teaching_is_409(taught: tuple[Api, dict[str, str], int]) -> None:
    api, robot, tour_id = taught
    api.client.post("/robots/rover/teach/start", json={"tour": tour_id}, headers=robot)
    before = api.dump()
    r = api.client.post("/robots/rover/goto", json={"location": "kitchen"}, headers=robot)
    assert r.status_code == 409 and "teaching" in r.json()["detail"]
    assert api.dump() == before


def test_teach_while_navigating_is_409(taught: tuple[Api, dict[str, str], int]) -> None:
    api, robot, tour_id = taught
    api.client.post("/robots/rover/goto", json={"location": "kitchen"}, headers=robot)
    r = api.client.post("/robots/rover/teach/start", json={"tour": tour_id}, headers=robot)
    assert r.status_code == 409 and "navigating" in r.json()["detail"]


def test_stop_with_nothing_running_is_409(taught: tuple[Api, dict[str, str], int]) -> None:
    api, robot, _ = taught
    before = api.dump()
    r = api.client.post("/robots/rover/stop", headers=robot)
    assert r.status_code == 409 and "nothing to stop" in r.json()["detail"]
    assert api.dump() == before


def test_frames_with_bad_depth_are_422(taught: tuple[Api, dict[str, str], int]) -> None:
    api, robot, _ = taught
    api.client.post("/robots/rover/goto", json={"location": "kitchen"}, headers=robot)
    r = api.client.post(
        "/robots/rover/frames",
        params={"timestamp": 1.0, "depth": [1.0, -2.0]},
        content=make_jpeg(),
        headers={**robot, **JPEG},
    )
    assert r.status_code == 422 and "depth" in r.json()["detail"]


def test_navigation_frames_going_backwards_are_422(
    taught: tuple[Api, dict[str, str], int], shared_data: Path
) -> None:
    api, robot, _ = taught
    api.client.post("/robots/rover/goto", json={"location": "kitchen"}, headers=robot)
    frame = shared_data / "corridor" / "query" / "0000000.jpg"
    assert post_frame(api, robot, frame, 5.0).status_code == 200
    r = post_frame(api, robot, frame, 4.0)
    assert r.status_code == 422 and "backwards" in r.json()["detail"]


def test_another_robot_cannot_drive_this_one(taught: tuple[Api, dict[str, str], int]) -> None:
    api, _, _ = taught
    other = api.register("other")
    for method, path, kwargs in [
        ("POST", "/robots/rover/goto", {"json": {"location": "kitchen"}}),
        ("POST", "/robots/rover/stop", {}),
    ]:
        r = api.client.request(method, path, headers=other, **kwargs)
        assert r.status_code == 403 and "belongs to robot 'other'" in r.json()["detail"]


def test_the_tour_is_rebuilt_after_more_teaching(
    taught: tuple[Api, dict[str, str], int], shared_data: Path
) -> None:
    api, robot, tour_id = taught
    api.client.post("/robots/rover/goto", json={"location": "kitchen"}, headers=robot)
    api.client.post("/robots/rover/stop", headers=robot)
    # teach one more place after the kitchen
    api.client.post("/robots/rover/teach/start", json={"tour": tour_id}, headers=robot)
    api.client.post("/robots/rover/teach/locations", json={"name": "kitchen"}, headers=robot)
    queries = sorted((shared_data / "corridor" / "query").glob("*.jpg"))
    for k, path in enumerate(queries[:5]):
        assert post_frame(api, robot, path, 200 + k).status_code == 200
    api.client.post("/robots/rover/teach/locations", json={"name": "garden"}, headers=robot)
    api.client.post("/robots/rover/teach/finish", headers=robot)
    r = api.client.post("/robots/rover/goto", json={"location": "garden"}, headers=robot)
    assert r.status_code == 200, r.text


@pytest.mark.parametrize("at_once", [1, 3])
def test_steps_of_many_robots_run_at_most_concurrent_steps_at_once(
    taught: tuple[Api, dict[str, str], int],
    shared_data: Path,
    monkeypatch: pytest.MonkeyPatch,
    at_once: int,
) -> None:
    import threading
    import time

    from server.session import RobotSession

    api, _, tour_id = taught
    navigation = api.client.app.state.services.navigation  # type: ignore[attr-defined]
    # the app was built with the default (settings.concurrent_steps = 1); try another count
    navigation._steps = threading.BoundedSemaphore(at_once)
    running, most, guard = [0], [0], threading.Lock()
    real_step = RobotSession.step

    def counted_step(self: RobotSession, *args: object, **kwargs: object):  # type: ignore[no-untyped-def]
        with guard:
            running[0] += 1
            most[0] = max(most[0], running[0])
        try:
            time.sleep(0.02)  # long enough for the other robots' frames to arrive
            return real_step(self, *args, **kwargs)  # type: ignore[arg-type]
        finally:
            with guard:
                running[0] -= 1

    monkeypatch.setattr(RobotSession, "step", counted_step)
    names = [f"bot{i}" for i in range(4)]
    tokens = {name: api.register(name) for name in names}
    for name in names:
        r = api.client.post(
            f"/robots/{name}/goto",
            json={"location": "kitchen", "tour": tour_id},
            headers=tokens[name],
        )
        assert r.status_code == 200, r.text
    frames = sorted((shared_data / "corridor" / "query").glob("*.jpg"))[:5]
    codes: list[int] = []

    def drive(name: str) -> None:
        for k, path in enumerate(frames):
            r = api.client.post(
                f"/robots/{name}/frames",
                params={"timestamp": k / 10, "v": 0.3},
                content=path.read_bytes(),
                headers={**tokens[name], **JPEG},
            )
            codes.append(r.status_code)

    threads = [threading.Thread(target=drive, args=(name,)) for name in names]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert codes == [200] * (len(names) * len(frames))
    assert most[0] == at_once


def test_a_tour_s_runtime_reads_its_taught_images_from_the_store(
    taught: tuple[Api, dict[str, str], int],
) -> None:
    """For docking's zooms on the taught images (``dock_taught_zooms``): the runtime's reader
    gives the stored frame of every canonical image, as the frame route decoded it."""
    import numpy as np

    from server.imaging import decode_jpeg

    api, _, tour_id = taught
    services = api.client.app.state.services  # type: ignore[attr-defined]
    rt = services.navigation.runtime(tour_id)
    assert rt.taught_pixels is not None
    for k in (0, 5, rt.graph.n_images - 1):
        stored = services.repo.image_jpeg(int(rt.graph.image_ids[k]))
        pixels = rt.taught_pixels(k)
        assert pixels is not None
        assert np.array_equal(pixels, decode_jpeg(stored, services.limits)[0])


def test_a_restarted_service_resumes_the_whole_filter_not_only_the_belief(
    taught: tuple[Api, dict[str, str], int], shared_data: Path
) -> None:
    """The persisted snapshot carries the tracker's memory (migration 8): a service started
    afresh on the same store (a restarted server) resumes the robot's belief and also its
    belief over the appearance models, the running familiarity of the change gate and the
    evidence averages, as they were after the frame that saved them."""

    import numpy as np

    from server.services.navigation import BELIEF_SNAPSHOT_S, NavigationService

    api, robot, _ = taught
    services = api.client.app.state.services  # type: ignore[attr-defined]
    assert api.client.post("/robots/rover/goto", json={"location": "kitchen"}, headers=robot)
    queries = sorted((shared_data / "corridor" / "query").glob("*.jpg"))
    for k, path in enumerate(queries[:30]):
        assert post_frame(api, robot, path, 100 + k / 10).status_code == 200
    # snapshots are a second of robot time apart (100.0, 101.0, 102.0): this frame is saved
    assert post_frame(api, robot, queries[30], 102.0 + BELIEF_SNAPSHOT_S).status_code == 200
    live = services.navigation.session("rover")
    assert live is not None
    saved = live.tracker.memory()
    assert len(saved.appearance) == 2 and np.isfinite(saved.familiar)  # two models, default
    restarted = NavigationService(services.repo, services.limits, services.navigation.params)
    try:
        resumed = restarted.session("rover")
        assert resumed is not None and resumed is not live
        assert resumed.tracker.memory() == saved
        np.testing.assert_allclose(resumed.tracker.belief, live.tracker.belief, atol=1e-6)
    finally:
        restarted.close()
