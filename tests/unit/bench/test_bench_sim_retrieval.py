"""``teachrepeat bench sim-retrieval`` on a short route: it runs and reports every cell; the
pieces of ``--offsets`` (labels, poses beside the path, the server's image order)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from robot_client.sim.world import Pose
from server.bench.sim_retrieval import (
    CONDITIONS,
    OffsetView,
    canonical_order,
    offset_label,
    offset_summary,
    side_poses,
)
from server.cli import main


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
    def view(retrieved: bool, inliers: int) -> OffsetView:
        return OffsetView(0, 1.0, "same", Pose(0, 0, 0), 0, retrieved, inliers)

    views = [view(True, 30), view(True, 5), view(False, 40), view(True, 10)]
    cell = offset_summary(views, 2, min_inliers=10)
    assert cell["matched_fraction"] == 0.5
    assert cell["retrieved_fraction"] == 0.75
    assert cell["geometric_fraction"] == 0.75
    assert (cell["views"], cell["skipped"], cell["median_inliers"]) == (4, 2, 20.0)
    assert math.isnan(offset_summary([], 3, min_inliers=10)["matched_fraction"])


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
            "geometric_fraction",
            "views",
            "skipped",
            "median_inliers",
        } <= set(cell)
        assert cell["views"] + cell["skipped"] == 30
    near = result["offsets"]["0_25m"]
    assert near["skipped"] == 0
    assert near["matched_fraction"] >= 0.7
    assert near["matched_fraction"] >= result["offsets"]["1m"]["matched_fraction"]
