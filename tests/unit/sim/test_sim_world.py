"""The simulated home as the camera and the depth sensor see it."""

from __future__ import annotations

import math
from collections.abc import Iterator

import cv2
import numpy as np
import pytest

from robot_client.sim.floorplan import FloorPlan, load_plan
from robot_client.sim.textures import TEXTURES, TextureError, load_texture
from robot_client.sim.world import CameraParams, Pose, SimWorld


@pytest.fixture(scope="module")
def plan() -> FloorPlan:
    return load_plan()


@pytest.fixture(scope="module")
def world(plan: FloorPlan) -> Iterator[SimWorld]:
    with SimWorld(plan) as w:
        yield w


def _at(plan: FloorPlan, name: str, turn: float = 0.0) -> Pose:
    p = plan.place(name)
    return Pose(p.x, p.y, p.yaw + turn)


def _mad(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a.astype(np.float32) - b.astype(np.float32)).mean())


def test_frames_are_bgr_uint8_and_full_of_features(world: SimWorld, plan: FloorPlan) -> None:
    for p in plan.places:
        frame = world.render(Pose(p.x, p.y, p.yaw))
        assert frame.shape == (240, 320, 3) and frame.dtype == np.uint8
        assert frame.std() > 15, p.name
        grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        corners = cv2.goodFeaturesToTrack(grey, 200, 0.01, 5)
        assert corners is not None and len(corners) >= 50, p.name


def test_rendering_is_deterministic(world: SimWorld, plan: FloorPlan) -> None:
    pose = _at(plan, "living room", 0.7)
    first = world.render(pose)
    world.render(_at(plan, "kitchen"))
    assert np.array_equal(first, world.render(pose))
    with SimWorld(plan) as other:
        assert np.array_equal(first, other.render(pose))


def test_frames_are_bgr_not_rgb(world: SimWorld, plan: FloorPlan) -> None:
    # the living-room sofa is red leather: red channel (index 2 in BGR) dominates its pixels
    frame = world.render(Pose(5.3, 2.6, -math.pi / 2)).astype(np.float32)
    lower = frame[150:200, 60:260]
    assert lower[..., 2].mean() > lower[..., 0].mean()


def test_lighting_condition_is_darker_and_warmer(plan: FloorPlan, world: SimWorld) -> None:
    with SimWorld(plan, condition="lighting") as dim:
        for name in ("living room", "kitchen", "office"):
            a = world.render(_at(plan, name)).astype(np.float64)
            b = dim.render(_at(plan, name)).astype(np.float64)
            assert b.mean() < 0.85 * a.mean(), name
            ratio_a = a[..., 2].mean() / a[..., 0].mean()  # red / blue
            ratio_b = b[..., 2].mean() / b[..., 0].mean()
            assert ratio_b > 1.15 * ratio_a, name


def test_moved_condition_displaces_furniture(plan: FloorPlan, world: SimWorld) -> None:
    with SimWorld(plan, condition="moved") as moved:
        table = next(f for f in moved.furniture if f.name == "living/coffee table")
        original = next(f for f in plan.furniture if f.name == "living/coffee table")
        assert (table.x, table.y) != (original.x, original.y)
        assert moved.collides(table.x + 0.3, table.y, 0.05)
        pose = _at(plan, "living room")
        before, after = world.render(pose), moved.render(pose)
        changed = np.abs(before.astype(np.int16) - after.astype(np.int16)).max(axis=2) > 20
        assert changed.mean() > 0.03  # a visible part of the frame changed
        # the walls did not move: a view without movable furniture is unchanged
        hall = _at(plan, "hall")
        assert _mad(world.render(hall), moved.render(hall)) < 0.5


def test_look_alike_rooms_render_alike(world: SimWorld, plan: FloorPlan) -> None:
    for turn in (0.0, -1.2, 2.0):
        a = world.render(_at(plan, "bedroom", turn))
        b = world.render(_at(plan, "guest room", turn))
        alike = _mad(a, b)
        others = [
            _mad(a, world.render(_at(plan, n, turn)))
            for n in ("entry", "living room", "kitchen", "bathroom", "office", "hall")
        ]
        assert alike < 0.25 * min(others), (turn, alike, others)


def test_depth_profile_sees_the_wall_at_its_distance(world: SimWorld) -> None:
    # entry, facing south: the outer wall's inner surface is at y = 0.06
    profile = world.depth_profile(Pose(1.5, 1.2, -math.pi / 2))
    cam = world.camera
    assert profile.shape == (cam.n_depth_rays,) and profile.dtype == np.float32
    centre = cam.n_depth_rays // 2
    assert profile[centre] == pytest.approx(1.14, abs=1e-3)
    half = math.radians(cam.depth_fov_deg) / 2
    # off-centre rays hit the same wall further away: 1.14 / cos(angle)
    angle = half * 4 / (cam.n_depth_rays // 2)
    assert profile[centre - 4] == pytest.approx(1.14 / math.cos(angle), abs=1e-3)
    # down the corridor nothing is within range
    far = world.depth_profile(Pose(2.0, 4.75, 0.0))
    assert math.isinf(far[centre])


def test_depth_profile_runs_left_to_right(world: SimWorld) -> None:
    # in the corridor facing east, the left (north) wall is closer than the far end
    profile = world.depth_profile(Pose(2.0, 4.75, 0.0))
    assert profile[0] < 1.5 and profile[-1] < 1.5
    pose = Pose(2.0, 4.4, 0.0)  # nearer the south wall: the rightmost ray is shorter
    profile = world.depth_profile(pose)
    assert profile[-1] < profile[0]


def test_collides_with_walls_furniture_and_outside(world: SimWorld, plan: FloorPlan) -> None:
    for f in world.furniture:
        if f.solid:
            assert world.collides(f.x, f.y, 0.01), f.name
    rug = next(f for f in world.furniture if f.kind == "rug")
    assert not world.collides(rug.x + 0.6, rug.y, 0.05) or world.clearance(rug.x, rug.y) > 0
    assert world.collides(3.0, 1.0, 0.1)  # inside the wall between entry and living room
    assert not world.collides(3.0, 2.0, 0.18)  # but the doorway is open
    assert world.collides(-1.0, 2.0, 0.1)
    for p in plan.places:
        assert not world.collides(p.x, p.y, 0.25), p.name


def test_free_random_poses_are_free_and_seeded(world: SimWorld) -> None:
    poses = [world.free_random_pose(np.random.default_rng(7)) for _ in range(2)]
    assert poses[0] == poses[1]
    rng = np.random.default_rng(3)
    for _ in range(50):
        p = world.free_random_pose(rng)
        assert not world.collides(p.x, p.y, 0.3)


def test_close_is_idempotent_and_render_after_close_fails(plan: FloorPlan) -> None:
    w = SimWorld(plan, camera=CameraParams(width=160, height=120))
    assert w.render(_at(plan, "entry")).shape == (120, 160, 3)
    w.close()
    w.close()
    with pytest.raises(RuntimeError, match="closed"):
        w.render(_at(plan, "entry"))


def test_textures_are_photographs_from_installed_packages() -> None:
    for name in TEXTURES:
        image = load_texture(name)
        assert image.ndim == 3 and image.shape[2] == 3 and image.dtype == np.uint8
        assert image.std() > 3, name
    with pytest.raises(TextureError, match="unknown texture 'plaid'"):
        load_texture("plaid")
