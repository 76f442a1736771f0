"""``teachrepeat bench sim-retrieval`` on a short route: it runs and reports every cell; the
pieces of ``--offsets`` (labels, poses beside the path, the server's image order)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "vision"))
from vision_testkit import index_of, scene, shifted

from robot_client.sim.world import Pose
from server.bench.sim_retrieval import (
    CONDITIONS,
    OffsetView,
    Shot,
    TaughtPoses,
    canonical_order,
    navigation_params,
    offset_label,
    offset_summary,
    pose_distance,
    reachable,
    side_poses,
)
from server.cli import main
from server.vision import extract


@pytest.mark.slow
def test_sim_retrieval_on_a_short_route(tmp_path: Path) -> None:
    out = tmp_path / "sim.json"
    code = main(
        [
            "bench",
            "sim-retrieval",
            "--route",
            "entry,living room",
            "--queries",
            "80",
            "--radius",
            "1.0",
            "--angle",
            "45",
            "--json",
            str(out),
        ]
    )
    assert code == 0
    result = json.loads(out.read_text())
    assert set(result["configs"]) == {
        "grey_world/learned",
        "grey_world/robust",
        "raw/learned",
        "raw/robust",
    }
    for cells in result["configs"].values():
        assert len(cells["weights"]) == 5
        for condition in CONDITIONS:
            cell = cells[condition]
            assert cell["queries"] > 0
            assert 0.0 <= cell["image_recall@1"] <= 1.0
            assert 0.0 <= cell["state_recall@1"] <= 1.0


# ------------------------------------------------------------------ --offsets


@pytest.mark.parametrize(
    ("metres", "label"),
    [(0.25, "0_25m"), (0.5, "0_5m"), (1.0, "1m"), (1.5, "1_5m"), (2, "2m"), (0, "0m"), (10, "10m")],
)
def test_offset_label(metres: float, label: str) -> None:
    assert offset_label(metres) == label


@pytest.mark.parametrize("bad", [-0.5, math.inf, math.nan])
def test_offset_label_rejects_what_is_no_distance(bad: float) -> None:
    with pytest.raises(ValueError, match="offset"):
        offset_label(bad)


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


SOURCES = [Pose(0.3 * i, 0.1 * i, -3.0 + 0.6 * i) for i in range(10)]


@pytest.mark.parametrize("offset", [0.25, 1.0, 1.5])
def test_side_poses_in_free_space(offset: float) -> None:
    poses = side_poses(SOURCES, offset, seed=3, is_free=lambda x, y: True, turn_deg=30.0)
    sides = []
    for src, pose in zip(SOURCES, poses, strict=True):
        assert pose is not None
        dx, dy = pose.x - src.x, pose.y - src.y
        assert math.hypot(dx, dy) == pytest.approx(offset)
        # sideways: perpendicular to the taught heading
        assert dx * math.cos(src.theta) + dy * math.sin(src.theta) == pytest.approx(0.0, abs=1e-9)
        assert abs(_wrap(pose.theta - src.theta)) <= math.radians(30.0) + 1e-12
        assert -math.pi <= pose.theta < math.pi
        sides.append(math.cos(src.theta) * dy - math.sin(src.theta) * dx > 0)  # left?
    assert sum(sides) == len(SOURCES) // 2  # half left, half right


def test_side_poses_same_side_and_turn_for_every_offset() -> None:
    near = side_poses(SOURCES, 0.25, seed=9, is_free=lambda x, y: True)
    far = side_poses(SOURCES, 1.5, seed=9, is_free=lambda x, y: True)
    other = side_poses(SOURCES, 0.25, seed=10, is_free=lambda x, y: True)
    for src, a, b in zip(SOURCES, near, far, strict=True):
        assert a is not None and b is not None
        assert a.theta == pytest.approx(b.theta)
        # b lies on the ray from the source through a
        assert (b.x - src.x, b.y - src.y) == pytest.approx((6 * (a.x - src.x), 6 * (a.y - src.y)))
    assert [p.theta for p in near if p] != [p.theta for p in other if p]


def test_side_poses_takes_the_other_side_or_skips() -> None:
    east = [Pose(0.0, 0.0, 0.0)] * 6  # facing +x: left is +y
    right_only = side_poses(east, 1.0, seed=1, is_free=lambda x, y: y <= 1e-9)
    assert all(p is not None and p.y == pytest.approx(-1.0) for p in right_only)
    # a wall at 0.3 < y < 0.4 with free space beyond it: the camera does not pass through
    wall = side_poses(east, 1.0, seed=1, is_free=lambda x, y: not 0.3 < y < 0.4)
    assert all(p is not None and p.y == pytest.approx(-1.0) for p in wall)
    corridor = side_poses(east, 1.0, seed=1, is_free=lambda x, y: abs(y) < 0.5)
    assert corridor == [None] * 6
    assert all(p is not None for p in side_poses(east, 0.0, seed=1, is_free=lambda x, y: x == 0))


def test_side_poses_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError, match="offset_m"):
        side_poses(SOURCES, -1.0, seed=0, is_free=lambda x, y: True)
    with pytest.raises(ValueError, match="turn_deg"):
        side_poses(SOURCES, 1.0, seed=0, is_free=lambda x, y: True, turn_deg=-30.0)


def test_offsets_refuses_a_bad_turn(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "sim-retrieval", "--offsets", "1", "--turn-deg", "400"]) == 2
    assert "--turn-deg must lie in [0, 180]" in capsys.readouterr().out


def test_canonical_order_places_first_then_each_traversal() -> None:
    keys = ["a", "a", "a->b", "a->b", "b", "b", "b->a", "b->a", "a->b"]
    order, states = canonical_order(keys)
    assert order.tolist() == [0, 1, 4, 5, 2, 3, 6, 7, 8]
    assert states.tolist() == [0, 0, 1, 1, 2, 2, 3, 3, 4]


def test_offset_summary_counts_retrieved_and_geometric() -> None:
    def view(retrieved: bool, inliers: int, from_source: bool) -> OffsetView:
        return OffsetView(0, 1.0, "same", Pose(0, 0, 0), 0, retrieved, inliers, 0, from_source)

    views = [
        view(True, 30, True),
        view(True, 5, False),
        view(False, 40, True),
        view(True, 10, False),
    ]
    cell = offset_summary(views, 2, min_inliers=10)
    assert cell["matched_fraction"] == 0.5
    assert cell["retrieved_fraction"] == 0.75
    assert cell["source_matched_fraction"] == 0.5  # views 0 and 2
    assert cell["source_retrieved_fraction"] == 0.5
    assert cell["geometric_fraction"] == 0.75
    assert (cell["views"], cell["skipped"], cell["median_inliers"]) == (4, 2, 20.0)
    assert cell["matched_ci95"][0] < 0.5 < cell["matched_ci95"][1]
    assert math.isnan(offset_summary([], 3, min_inliers=10)["matched_fraction"])


def test_pose_distance_adds_the_heading_difference_in_metres() -> None:
    pose = Pose(1.0, 2.0, 3.0)
    xs, ys = [1.0, 4.0, 1.0, 1.0], [2.0, 6.0, 2.0, 2.0]
    thetas = [3.0, 3.0, 3.0 + 0.5, -3.0]  # -3.0 is 2 pi - 6 = 0.283 rad from 3.0
    d = pose_distance(pose, xs, ys, thetas, metres_per_radian=2.0)
    np.testing.assert_allclose(d, [0.0, 5.0, 1.0, 2.0 * (2 * math.pi - 6.0)])
    np.testing.assert_allclose(pose_distance(pose, xs, ys, thetas, metres_per_radian=0.0)[1:2], 5.0)
    with pytest.raises(ValueError, match="metres_per_radian"):
        pose_distance(pose, xs, ys, thetas, metres_per_radian=-1.0)


def _shot(x: float, y: float, theta: float) -> Shot:
    return Shot(np.zeros((1, 1, 3), np.uint8), x, y, theta)


def test_the_nearest_taught_image_is_judged_by_position_and_heading() -> None:
    """A source frame on one path, another traversal 1.2 m to its left: a camera moved 1 m to
    the left and turned is nearest to the other traversal's frame that faces its way, and an
    image on the spot facing away is far."""
    tour = [
        _shot(0.0, 0.0, 0.0),  # 0: the source, facing +x
        _shot(0.1, 0.0, 0.0),  # 1: its neighbour on the same path
        _shot(0.0, 1.2, 0.4),  # 2: another traversal, 1.2 m left, facing 23 degrees left
        _shot(0.0, 1.0, math.pi),  # 3: on the camera's spot, facing back
        _shot(0.4, 1.2, 0.4),  # 4: next frame of that traversal, 0.4 m on
    ]
    taught = TaughtPoses.of(tour, 0.5, 30.0)
    camera = Pose(0.0, 1.0, 0.35)
    assert taught.nearest(camera) == 2
    assert taught.near(2).tolist() == [False, False, True, False, True]
    assert taught.near(0).tolist() == [True, True, False, False, False]
    # on the path, facing as taught, the source itself is nearest
    assert taught.nearest(Pose(0.01, 0.0, 0.0)) == 0


def test_navigation_params_for_the_bench() -> None:
    nav = navigation_params("teblid", [("engine.geometric", True)])
    assert nav.features.descriptor == nav.engine.features.descriptor == "teblid"
    assert nav.engine.geometric
    with pytest.raises(ValueError, match=r"engine\.features"):
        navigation_params(None, [("features.n_features", 200)])
    with pytest.raises(ValueError, match="no setting"):
        navigation_params(None, [("engine.geometrik", True)])


def test_descriptor_without_offsets_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "sim-retrieval", "--descriptor", "teblid"]) == 2
    assert "go with --offsets" in capsys.readouterr().out


@pytest.mark.slow
def test_sim_retrieval_offsets_on_a_short_route(tmp_path: Path) -> None:
    out = tmp_path / "offsets.json"
    code = main(
        [
            "bench",
            "sim-retrieval",
            "--route",
            "entry,living room",
            "--queries",
            "30",
            "--offsets",
            "0.25",
            "1.0",
            "--condition",
            "same",
            "lighting",
            "--json",
            str(out),
        ]
    )
    assert code == 0
    result = json.loads(out.read_text())
    assert result["plan"] == "apartment.json" and len(result["weights"]) == 5
    assert set(result["offsets"]) == {"0_25m", "1m"}
    assert set(result["conditions"]) == {"same", "lighting"}
    assert result["conditions"]["same"]["offsets"] == result["offsets"]
    for cell in result["offsets"].values():
        assert {
            "matched_fraction",
            "retrieved_fraction",
            "source_matched_fraction",
            "source_retrieved_fraction",
            "nearest_is_source_fraction",
            "reachable_fraction",
            "faces_wall_fraction",
            "geometric_fraction",
            "views",
            "skipped",
            "median_inliers",
        } <= set(cell)
        assert cell["views"] + cell["skipped"] == 30
        assert cell["matched_fraction"] <= cell["reachable_fraction"]
        assert cell["matched_fraction"] <= cell["retrieved_fraction"]
    near = result["offsets"]["0_25m"]
    assert near["skipped"] == 0
    assert near["matched_fraction"] >= 0.7
    assert near["matched_fraction"] >= result["offsets"]["1m"]["matched_fraction"]


def test_reachable_when_an_image_near_the_nearest_one_has_the_inliers() -> None:
    """Taught images 0-2 of scenes 0-2 side by side (image k taken at x = k metres); a query
    showing scene 1 shifted is reachable from image 1's neighbourhood, not from image 2's."""
    idx, _ = index_of([scene(s) for s in range(3)], [0, 1, 2])
    taught = TaughtPoses.of([_shot(float(k), 0.0, 0.0) for k in range(3)], 0.5, 30.0)
    query = extract(shifted(scene(1), 6))
    position = np.array([0, 1, 2])
    camera = Pose(1.0, 0.2, 0.0)
    assert taught.nearest(camera) == 1
    assert reachable(idx, query, position, taught, camera, 1, 10)
    assert not reachable(idx, query, position, taught, Pose(2.0, 0.0, 0.0), 2, 10)
    assert not reachable(idx, query, position, taught, camera, 1, 1000)
