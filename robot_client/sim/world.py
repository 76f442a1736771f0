"""The simulated home as the robot's sensors see it: MuJoCo rendering plus 2D geometry.

:class:`SimWorld` turns a :class:`~robot_client.sim.floorplan.FloorPlan` into

* a MuJoCo model (walls, floors, ceiling, furniture, pictures, lights) rendered on the CPU through
  OSMesa into ``(240, 320, 3)`` BGR frames from a forward camera at the robot's pose;
* 2D obstacle geometry (wall panels and solid furniture as oriented rectangles) for
  :meth:`SimWorld.collides` and :meth:`SimWorld.depth_profile`.

This is the simulator's truth. The belief tracker never imports it: it only sees frames.

Conditions (how a repeat run differs from the teaching run): ``same``; ``lighting`` - dimmer, warmer
light; ``moved`` - the furniture pieces with a ``moved`` offset in the plan are displaced.
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING
from xml.sax.saxutils import quoteattr

import cv2
import numpy as np
import numpy.typing as npt

from robot_client.sim.floorplan import FloorPlan, Furniture, Wall, check_condition
from robot_client.sim.textures import TEXTURES, TextureError, load_texture, texture_size_m

if TYPE_CHECKING:  # mujoco is imported lazily so MUJOCO_GL can be set first
    import mujoco

BGRImage = npt.NDArray[np.uint8]
"""``(H, W, 3)`` uint8, BGR channel order (OpenCV's)."""


def _ensure_gl_backend() -> None:
    """Select CPU rendering (OSMesa) unless the caller chose a backend before importing MuJoCo."""
    os.environ.setdefault("MUJOCO_GL", "osmesa")
    if os.environ["MUJOCO_GL"] == "osmesa":
        os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")


@dataclass(frozen=True)
class Pose:
    """A planar pose: position ``(x, y)`` in metres, heading ``theta`` in radians (CCW from +x)."""

    x: float
    y: float
    theta: float


@dataclass(frozen=True)
class CameraParams:
    """The robot's forward camera and its depth sensor.

    Attributes:
        width, height: frame size in pixels.
        vfov_deg: vertical field of view, degrees.
        height_m: height of the camera above the floor, metres.
        pitch_deg: tilt of the camera, degrees (positive looks up).
        n_depth_rays: number of rays of the depth profile.
        depth_fov_deg: horizontal span of the depth rays, degrees.
        max_range_m: rays longer than this read ``inf``, metres.
    """

    width: int = 320
    height: int = 240
    vfov_deg: float = 60.0
    height_m: float = 0.45
    pitch_deg: float = 5.0
    n_depth_rays: int = 31
    depth_fov_deg: float = 90.0
    max_range_m: float = 4.0

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view of the camera, degrees."""
        half = math.radians(self.vfov_deg) / 2
        return math.degrees(2 * math.atan(math.tan(half) * self.width / self.height))


@dataclass(frozen=True)
class Lighting:
    """Scene lighting: RGB intensities in [0, 1]."""

    ambient: tuple[float, float, float]
    diffuse: tuple[float, float, float]
    """Diffuse colour of the main (overhead) light; side lights get fractions of it."""


LIGHTING: dict[str, Lighting] = {
    "same": Lighting(ambient=(0.38, 0.38, 0.38), diffuse=(0.62, 0.62, 0.62)),
    "lighting": Lighting(ambient=(0.27, 0.21, 0.14), diffuse=(0.42, 0.31, 0.18)),
    "moved": Lighting(ambient=(0.38, 0.38, 0.38), diffuse=(0.62, 0.62, 0.62)),
}
"""Lighting per condition: ``lighting`` is dimmer and warmer than when taught."""


@dataclass(frozen=True)
class Obstacle:
    """An oriented rectangle the robot cannot enter: centre, half sizes, yaw (metres, radians)."""

    x: float
    y: float
    hx: float
    hy: float
    yaw: float
    name: str


class SimWorld:
    """A floor plan made visible: renders camera frames, casts depth rays, tests collisions.

    Use as a context manager or call :meth:`close`, which releases the OpenGL context.

    Args:
        plan: the home.
        condition: ``same``, ``lighting`` or ``moved`` (see module docstring).
        seed: reserved for condition randomness; the conditions are deterministic data today.
        camera: the robot camera's parameters.
    """

    def __init__(
        self,
        plan: FloorPlan,
        *,
        condition: str = "same",
        seed: int = 0,
        camera: CameraParams = CameraParams(),
    ) -> None:
        check_condition(condition)
        self.plan = plan
        self.condition = condition
        self.seed = seed
        self.camera = camera
        self.geometry = PlanGeometry(plan, condition=condition)
        self.furniture: tuple[Furniture, ...] = self.geometry.furniture
        self.obstacles: tuple[Obstacle, ...] = self.geometry.obstacles
        self._renderer: mujoco.Renderer | None = None
        _ensure_gl_backend()
        import mujoco

        self._mujoco = mujoco
        with tempfile.TemporaryDirectory(prefix="teachrepeat-sim-") as tmp:
            xml = build_mjcf(plan, self.furniture, LIGHTING[condition], camera, Path(tmp))
            self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        mujoco.mj_forward(self.model, self.data)
        self._renderer = mujoco.Renderer(self.model, height=camera.height, width=camera.width)
        self._cam_id = 0

    # -- lifecycle ---------------------------------------------------------------------------------

    def close(self) -> None:
        """Release the renderer (and its OpenGL context). Safe to call twice."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __enter__(self) -> SimWorld:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):  # interpreter shutdown
            self.close()

    # -- sensors ---------------------------------------------------------------------------------

    def render(self, pose: Pose) -> BGRImage:
        """The forward camera's frame at ``pose``.

        Returns:
            ``(height, width, 3)`` uint8 BGR (OpenCV order), a new array.
        """
        if self._renderer is None:
            raise RuntimeError("SimWorld is closed; create a new one to render")
        self.data.cam_xpos[self._cam_id] = (pose.x, pose.y, self.camera.height_m)
        self.data.cam_xmat[self._cam_id] = _camera_matrix(
            pose.theta, math.radians(self.camera.pitch_deg)
        )
        self._renderer.update_scene(self.data, camera=self._cam_id)
        rgb = self._renderer.render()
        return np.ascontiguousarray(rgb[:, :, ::-1])

    def render_view(self, x: float, y: float, z: float, yaw: float, pitch: float) -> BGRImage:
        """A frame from any camera position (metres) and yaw/pitch (radians), for figures."""
        if self._renderer is None:
            raise RuntimeError("SimWorld is closed; create a new one to render")
        self.data.cam_xpos[self._cam_id] = (x, y, z)
        self.data.cam_xmat[self._cam_id] = _camera_matrix(yaw, pitch)
        self._renderer.update_scene(self.data, camera=self._cam_id)
        return np.ascontiguousarray(self._renderer.render()[:, :, ::-1])

    def depth_profile(self, pose: Pose) -> npt.NDArray[np.float32]:
        """Ranges to walls and solid furniture along a fan of horizontal rays from the robot centre.

        Returns:
            ``(n_depth_rays,)`` float32 metres, leftmost ray first; ``inf`` beyond ``max_range_m``.
        """
        cam = self.camera
        half = math.radians(cam.depth_fov_deg) / 2
        angles = pose.theta + np.linspace(half, -half, cam.n_depth_rays)
        return self.cast_rays(pose.x, pose.y, angles, max_range=cam.max_range_m)

    def cast_rays(
        self, x: float, y: float, angles: npt.ArrayLike, *, max_range: float = math.inf
    ) -> npt.NDArray[np.float32]:
        """See :meth:`PlanGeometry.cast_rays`."""
        return self.geometry.cast_rays(x, y, angles, max_range=max_range)

    def collides(self, x: float, y: float, radius: float) -> bool:
        """Whether a disk of ``radius`` metres at ``(x, y)`` overlaps a wall or solid furniture,
        or leaves the home."""
        return self.geometry.collides(x, y, radius)

    def clearance(self, x: float, y: float) -> float:
        """Distance in metres from ``(x, y)`` to the nearest obstacle (0 inside one)."""
        return self.geometry.clearance(x, y)

    def free_random_pose(self, rng: np.random.Generator, *, clearance: float = 0.35) -> Pose:
        """A uniformly random pose inside the home at least ``clearance`` metres from obstacles."""
        return self.geometry.free_random_pose(rng, clearance=clearance)


# -- 2D geometry ---------------------------------------------------------------------------------


class PlanGeometry:
    """The home as 2D obstacles (wall panels and solid furniture as oriented rectangles).

    Cheap to build (no rendering): collision tests, clearance maps, ray casting, path planning.

    Args:
        plan: the home. condition: ``moved`` displaces furniture; the others do not change geometry.
    """

    def __init__(self, plan: FloorPlan, *, condition: str = "same") -> None:
        check_condition(condition)
        self.plan = plan
        self.condition = condition
        self.furniture: tuple[Furniture, ...] = plan.furniture_for(condition)
        self.obstacles: tuple[Obstacle, ...] = _obstacles(plan.walls(), self.furniture)
        self._rects = np.array(
            [(o.x, o.y, o.hx, o.hy, math.cos(o.yaw), math.sin(o.yaw)) for o in self.obstacles],
            dtype=np.float64,
        )
        self._segments = _rect_edges(self._rects)
        self.cache: dict[object, object] = {}
        """Derived data keyed by its users (e.g. path planning grids)."""

    def cast_rays(
        self, x: float, y: float, angles: npt.ArrayLike, *, max_range: float = math.inf
    ) -> npt.NDArray[np.float32]:
        """Distance from ``(x, y)`` to the first obstacle along each heading in ``angles``.

        Args:
            angles: ``(n,)`` world headings, radians.
        Returns:
            ``(n,)`` float32 metres; ``inf`` where nothing is hit within ``max_range``.
        """
        a = np.asarray(angles, dtype=np.float64).reshape(-1)
        d = np.stack([np.cos(a), np.sin(a)], axis=1)  # (n, 2)
        p, e = self._segments[:, :2], self._segments[:, 2:] - self._segments[:, :2]  # (m, 2)
        w = p - np.array([x, y])  # (m, 2)
        denom = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]  # (n, m)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (w[None, :, 0] * e[None, :, 1] - w[None, :, 1] * e[None, :, 0]) / denom
            u = (w[None, :, 0] * d[:, None, 1] - w[None, :, 1] * d[:, None, 0]) / denom
        valid = (np.abs(denom) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
        dist = np.where(valid, t, np.inf).min(axis=1)
        dist[dist > max_range] = np.inf
        return dist.astype(np.float32)

    # -- geometry ----------------------------------------------------------------------------------

    def collides(self, x: float, y: float, radius: float) -> bool:
        """Whether a disk of ``radius`` metres at ``(x, y)`` overlaps a wall or solid furniture,
        or leaves the home."""
        x0, y0, x1, y1 = self.plan.bounds
        if not (x0 + radius <= x <= x1 - radius and y0 + radius <= y <= y1 - radius):
            return True
        return bool(self.clearance(x, y) < radius)

    def clearance(self, x: float, y: float) -> float:
        """Distance in metres from ``(x, y)`` to the nearest obstacle (0 inside one)."""
        r = self._rects
        dx, dy = x - r[:, 0], y - r[:, 1]
        lx = r[:, 4] * dx + r[:, 5] * dy
        ly = -r[:, 5] * dx + r[:, 4] * dy
        ox = np.maximum(np.abs(lx) - r[:, 2], 0.0)
        oy = np.maximum(np.abs(ly) - r[:, 3], 0.0)
        return float(np.sqrt(ox * ox + oy * oy).min())

    def free_random_pose(self, rng: np.random.Generator, *, clearance: float = 0.35) -> Pose:
        """A uniformly random pose inside the home at least ``clearance`` metres from obstacles."""
        x0, y0, x1, y1 = self.plan.bounds
        for _ in range(10_000):
            x, y = rng.uniform(x0, x1), rng.uniform(y0, y1)
            if self.plan.room_at(x, y) is not None and not self.collides(x, y, clearance):
                return Pose(float(x), float(y), float(rng.uniform(-math.pi, math.pi)))
        raise RuntimeError("no free pose found; is the floor plan full of furniture?")

    def clearance_map(self, xs: npt.ArrayLike, ys: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Clearance (metres to the nearest obstacle, 0 inside) at many points.

        Args:
            xs, ys: arrays of the same shape, metres.
        Returns:
            array of that shape, float64 metres.
        """
        x = np.asarray(xs, dtype=np.float64)
        y = np.asarray(ys, dtype=np.float64)
        flat_x, flat_y = x.reshape(-1), y.reshape(-1)
        out = np.empty(flat_x.size, dtype=np.float64)
        every = range(len(self.obstacles))
        step = 4096
        for i in range(0, flat_x.size, step):
            part = self.distance_map(flat_x[i : i + step], flat_y[i : i + step], every)
            out[i : i + step] = part.min(axis=0)
        return out.reshape(x.shape)

    def distance_map(
        self, xs: npt.ArrayLike, ys: npt.ArrayLike, obstacles: Sequence[int]
    ) -> npt.NDArray[np.float64]:
        """Distance from many points to each of the chosen obstacles.

        Args:
            xs, ys: arrays of the same shape, metres.
            obstacles: indices into :attr:`obstacles`.
        Returns:
            ``(len(obstacles), *shape)`` float64 metres (0 inside an obstacle).
        """
        x = np.asarray(xs, dtype=np.float64)
        y = np.asarray(ys, dtype=np.float64)
        flat_x, flat_y = x.reshape(-1), y.reshape(-1)
        r = self._rects[np.asarray(list(obstacles), dtype=np.int64)]
        out = np.empty((len(r), flat_x.size), dtype=np.float64)
        step = max(1, 2**19 // max(1, len(r)))
        for i in range(0, flat_x.size, step):
            dx = flat_x[None, i : i + step] - r[:, 0, None]
            dy = flat_y[None, i : i + step] - r[:, 1, None]
            lx = r[:, 4, None] * dx + r[:, 5, None] * dy
            ly = -r[:, 5, None] * dx + r[:, 4, None] * dy
            ox = np.maximum(np.abs(lx) - r[:, 2, None], 0.0)
            oy = np.maximum(np.abs(ly) - r[:, 3, None], 0.0)
            out[:, i : i + step] = np.sqrt(ox * ox + oy * oy)
        return out.reshape((len(r), *x.shape))


def _obstacles(walls: tuple[Wall, ...], furniture: tuple[Furniture, ...]) -> tuple[Obstacle, ...]:
    out = []
    for i, w in enumerate(walls):
        length = w.length
        yaw = math.atan2(w.y1 - w.y0, w.x1 - w.x0)
        out.append(
            Obstacle(
                (w.x0 + w.x1) / 2, (w.y0 + w.y1) / 2, length / 2, w.thickness / 2, yaw, f"wall {i}"
            )
        )
    for f in furniture:
        if f.solid:
            out.append(Obstacle(f.x, f.y, f.sx / 2, f.sy / 2, f.yaw, f.name))
    return tuple(out)


def _rect_edges(rects: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """``(4 m, 4)`` segments ``(x0, y0, x1, y1)`` of the rectangles' edges."""
    edges = []
    for cx, cy, hx, hy, c, s in rects:
        corners = [
            (cx + c * px - s * py, cy + s * px + c * py)
            for px, py in ((-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy))
        ]
        for k in range(4):
            edges.append((*corners[k], *corners[(k + 1) % 4]))
    return np.array(edges, dtype=np.float64)


def _camera_matrix(yaw: float, pitch: float) -> npt.NDArray[np.float64]:
    """Row-major 3x3 orientation of a MuJoCo camera (looks along -z, y up) facing ``yaw``."""
    forward = np.array(
        [math.cos(yaw) * math.cos(pitch), math.sin(yaw) * math.cos(pitch), math.sin(pitch)]
    )
    right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
    up = np.cross(right, forward)
    return np.stack([right, up, -forward], axis=1).reshape(-1)


# -- MJCF -----------------------------------------------------------------------------------------


def _fmt(*values: float) -> str:
    return " ".join(f"{v:.4f}" for v in values)


def _texture_files(names: set[str], folder: Path, objects: set[str]) -> list[str]:
    """Write each texture as a PNG and return the MJCF asset lines (textures + materials).

    Every texture gets a 2D version (walls, floors, pictures); those in ``objects`` also get a
    cube version (one square image repeated on all six faces of a piece of furniture).
    """
    lines = []
    for name in sorted(names):
        try:
            rgb = load_texture(name)
        except TextureError as exc:
            raise TextureError(f"floor plan uses texture {name!r}: {exc}") from None
        png = folder / f"{name}.png"  # MuJoCo shows row 0 at the top of a +z box face: no flip
        cv2.imwrite(str(png), cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR))
        rep = 1.0 / texture_size_m(name)
        lines.append(f'<texture name="t_{name}" type="2d" file={quoteattr(str(png))}/>')
        if name in objects:
            cube = folder / f"{name}_cube.png"
            square = cv2.resize(rgb, (256, 256), interpolation=cv2.INTER_AREA)
            cv2.imwrite(str(cube), cv2.cvtColor(square, cv2.COLOR_RGB2BGR))
            lines.append(f'<texture name="c_{name}" type="cube" file={quoteattr(str(cube))}/>')
            lines.append(
                f'<material name="obj_{name}" texture="c_{name}" specular="0.15" shininess="0.2"/>'
            )
        lines.append(
            f'<material name="uni_{name}" texture="t_{name}" texuniform="true" '
            f'texrepeat="{_fmt(rep, rep)}" specular="0.1" shininess="0.1"/>'
        )
        lines.append(
            f'<material name="pic_{name}" texture="t_{name}" texuniform="false" '
            f'texrepeat="1 1" specular="0.2" shininess="0.3"/>'
        )
    return lines


def _wall_geom(w: Wall, material: str) -> str:
    """A box whose local z is the wall's normal, so the 2D texture lands on both big faces."""
    ux, uy = (w.x1 - w.x0) / max(w.length, 1e-9), (w.y1 - w.y0) / max(w.length, 1e-9)
    pos = ((w.x0 + w.x1) / 2, (w.y0 + w.y1) / 2, w.z0 + w.height / 2)
    size = (w.length / 2, w.height / 2, w.thickness / 2)
    return (
        f'<geom type="box" pos="{_fmt(*pos)}" size="{_fmt(*size)}" '
        f'xyaxes="{_fmt(ux, uy, 0, 0, 0, 1)}" material="{material}"/>'
    )


def _box(
    x: float,
    y: float,
    z: float,
    hx: float,
    hy: float,
    hz: float,
    yaw: float,
    material: str,
    *,
    kind: str = "box",
) -> str:
    c, s = math.cos(yaw), math.sin(yaw)
    return (
        f'<geom type="{kind}" pos="{_fmt(x, y, z)}" size="{_fmt(hx, hy, hz)}" '
        f'xyaxes="{_fmt(c, s, 0, -s, c, 0)}" material="{material}"/>'
    )


def _furniture_geoms(f: Furniture) -> list[str]:
    """Geoms of one piece; the kind sets its shape (backrests sit on the local -y side)."""
    m = f"obj_{f.texture}"
    c, s = math.cos(f.yaw), math.sin(f.yaw)

    def at(px: float, py: float) -> tuple[float, float]:
        return f.x + c * px - s * py, f.y + s * px + c * py

    hx, hy, z0, h = f.sx / 2, f.sy / 2, f.z, f.h
    out = []
    if f.kind in ("table", "desk"):
        top = 0.04
        out.append(_box(f.x, f.y, z0 + h - top / 2, hx, hy, top / 2, f.yaw, m))
        leg = 0.03
        for sx_, sy_ in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            lx, ly = at(sx_ * (hx - leg), sy_ * (hy - leg))
            out.append(_box(lx, ly, z0 + (h - top) / 2, leg, leg, (h - top) / 2, f.yaw, m))
    elif f.kind in ("chair", "sofa"):
        seat = min(0.45, h * 0.55)
        back = min(0.2, f.sy * 0.25)
        out.append(_box(f.x, f.y, z0 + seat / 2, hx, hy, seat / 2, f.yaw, m))
        bx, by = at(0.0, -hy + back / 2)
        out.append(_box(bx, by, z0 + (seat + h) / 2, hx, back / 2, (h - seat) / 2, f.yaw, m))
        if f.kind == "sofa":
            for side in (-1, 1):
                ax, ay = at(side * (hx - 0.1), 0.0)
                out.append(_box(ax, ay, z0 + seat + 0.1, 0.1, hy, 0.1, f.yaw, m))
    elif f.kind == "plant":
        pot_h = min(0.35, h * 0.4)
        r = min(hx, hy)
        out.append(
            f'<geom type="cylinder" pos="{_fmt(f.x, f.y, z0 + pot_h / 2)}" '
            f'size="{_fmt(r * 0.75, pot_h / 2)}" material="obj_terracotta"/>'
        )
        out.append(
            _box(
                f.x,
                f.y,
                z0 + pot_h + (h - pot_h) / 2,
                hx,
                hy,
                (h - pot_h) / 2,
                f.yaw,
                m,
                kind="ellipsoid",
            )
        )
    elif f.kind == "bed":
        out.append(_box(f.x, f.y, z0 + h / 2, hx, hy, h / 2, f.yaw, m))
        px, py = at(0.0, hy - 0.25)
        out.append(_box(px, py, z0 + h + 0.06, hx * 0.8, 0.18, 0.06, f.yaw, "obj_ceiling"))
        hbx, hby = at(0.0, hy - 0.03)
        out.append(_box(hbx, hby, z0 + 0.5, hx, 0.03, 0.5, f.yaw, "obj_walnut"))
    elif f.kind == "rug":
        out.append(_box(f.x, f.y, 0.004, hx, hy, 0.004, f.yaw, f"uni_{f.texture}"))
    else:
        out.append(_box(f.x, f.y, z0 + h / 2, hx, hy, h / 2, f.yaw, m))
    return out


def build_mjcf(
    plan: FloorPlan,
    furniture: tuple[Furniture, ...],
    lighting: Lighting,
    camera: CameraParams,
    folder: Path,
) -> str:
    """The MJCF XML of the home; texture PNGs are written into ``folder`` (must outlive compiling).

    Args:
        plan: the home. furniture: the pieces as they stand (see ``FloorPlan.furniture_for``).
        lighting: light colours. camera: sets the camera's vertical field of view.
    """
    pictures = {p.texture for p in plan.pictures}
    used = (
        {r.floor for r in plan.rooms}
        | {r.wall for r in plan.rooms}
        | {w.texture for w in plan.extra_walls}
        | {f.texture for f in furniture}
        | pictures
        | {"ceiling", "terracotta", "walnut"}
    )
    unknown = sorted(used - set(TEXTURES))
    if unknown:
        raise TextureError(f"floor plan uses unknown textures {unknown}; known: {sorted(TEXTURES)}")
    objects = {f.texture for f in furniture} | {"ceiling", "terracotta", "walnut"}
    assets = _texture_files(used, folder, objects)
    geoms: list[str] = []
    for r in plan.rooms:
        geoms.append(
            f'<geom type="box" pos="{_fmt((r.x0 + r.x1) / 2, (r.y0 + r.y1) / 2, -0.01)}" '
            f'size="{_fmt((r.x1 - r.x0) / 2, (r.y1 - r.y0) / 2, 0.01)}" '
            f'material="uni_{r.floor}"/>'
        )
    x0, y0, x1, y1 = plan.bounds
    ceiling_pos = _fmt((x0 + x1) / 2, (y0 + y1) / 2, plan.wall_height + 0.01)
    geoms.append(
        f'<geom type="box" pos="{ceiling_pos}" '
        f'size="{_fmt((x1 - x0) / 2 + 0.1, (y1 - y0) / 2 + 0.1, 0.01)}" '
        'material="uni_ceiling"/>'
    )
    for w in (*plan.walls(), *plan.lintels()):
        geoms.append(_wall_geom(w, f"uni_{w.texture}"))
    for f in furniture:
        geoms.extend(_furniture_geoms(f))
    for p in plan.pictures:
        nx, ny = math.cos(p.yaw), math.sin(p.yaw)
        depth = 0.008
        cx, cy = p.x + nx * (depth + 0.002), p.y + ny * (depth + 0.002)
        geoms.append(
            f'<geom type="box" pos="{_fmt(cx, cy, p.z)}" '
            f'size="{_fmt(p.width / 2, p.height / 2, depth)}" '
            f'xyaxes="{_fmt(-ny, nx, 0, 0, 0, 1)}" material="pic_{p.texture}"/>'
        )
    amb, dif = lighting.ambient, lighting.diffuse
    cx_, cy_ = (x0 + x1) / 2, (y0 + y1) / 2
    lights = [
        (dif, (0.25, 0.35, -1.0)),
        (tuple(0.35 * v for v in dif), (1.0, 0.3, -0.4)),
        (tuple(0.2 * v for v in dif), (-0.4, -1.0, -0.3)),
    ]
    light_xml = "\n".join(
        f'<light type="directional" pos="{_fmt(cx_, cy_, plan.wall_height - 0.05)}" '
        f'dir="{_fmt(*d)}" diffuse="{_fmt(*c)}" specular="0.05 0.05 0.05" castshadow="false"/>'
        for c, d in lights
    )
    return f"""<mujoco model={quoteattr(plan.name)}>
  <compiler angle="radian"/>
  <visual>
    <headlight ambient="{_fmt(*amb)}" diffuse="0 0 0" specular="0 0 0"/>
    <quality shadowsize="0" offsamples="0"/>
    <global fovy="{camera.vfov_deg:.3f}" offwidth="{max(640, camera.width)}"
            offheight="{max(480, camera.height)}"/>
    <map znear="0.01" zfar="50"/>
  </visual>
  <asset>
    {chr(10).join(assets)}
  </asset>
  <worldbody>
    {light_xml}
    <camera name="robot" pos="0 0 {camera.height_m:.3f}" fovy="{camera.vfov_deg:.3f}"/>
    {chr(10).join(geoms)}
  </worldbody>
</mujoco>
"""


# -- figures -------------------------------------------------------------------------------------


def draw_map(
    world: SimWorld | PlanGeometry,
    *,
    px_per_m: int = 60,
    path: list[tuple[float, float]] | None = None,
    poses: list[Pose] | None = None,
    legs: Sequence[Sequence[tuple[float, float]]] = (),
) -> BGRImage:
    """A top-down map of the home: rooms, walls, doorways, furniture, named places (BGR, y up).

    Args:
        path: optional waypoints (metres) drawn as a line.
        poses: optional robot poses drawn as arrows.
        legs: optional polylines (metres), e.g. the legs of a teaching route, drawn thin with
            an arrow head at their end.
    """
    plan = world.plan
    x0, y0, x1, y1 = plan.bounds
    margin = 0.3
    w = int((x1 - x0 + 2 * margin) * px_per_m)
    h = int((y1 - y0 + 2 * margin) * px_per_m)
    img = np.full((h, w, 3), 255, np.uint8)

    def px(x: float, y: float) -> tuple[int, int]:
        return (round((x - x0 + margin) * px_per_m), round((y1 + margin - y) * px_per_m))

    for r in plan.rooms:
        colour = tuple(int(v) for v in load_texture(r.floor).reshape(-1, 3).mean(0)[::-1])
        colour = tuple(int(0.45 * c + 0.55 * 255) for c in colour)
        cv2.rectangle(img, px(r.x0, r.y1), px(r.x1, r.y0), colour, -1)
        cv2.putText(
            img,
            r.name,
            px(r.x0 + 0.12, r.y1 - 0.3),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.45,
            (90, 90, 90),
            1,
            cv2.LINE_AA,
        )
    for f in world.furniture:
        pts = np.array([px(cx, cy) for cx, cy in f.corners()], np.int32)
        colour = tuple(int(v) for v in load_texture(f.texture).reshape(-1, 3).mean(0)[::-1])
        if f.solid:
            cv2.fillPoly(img, [pts], colour)
            cv2.polylines(img, [pts], True, (60, 60, 60), 1, cv2.LINE_AA)
        else:
            cv2.polylines(img, [pts], True, colour, 2, cv2.LINE_AA)
    for o in world.obstacles:
        if o.name.startswith("wall"):
            c, s = math.cos(o.yaw), math.sin(o.yaw)
            corners = ((-o.hx, -o.hy), (o.hx, -o.hy), (o.hx, o.hy), (-o.hx, o.hy))
            pts = np.array(
                [px(o.x + c * a - s * b, o.y + s * a + c * b) for a, b in corners], np.int32
            )
            cv2.fillPoly(img, [pts], (40, 40, 40))
    for d in plan.doors:
        along_x = any(
            abs(d.y - r.y0) <= plan.wall_thickness or abs(d.y - r.y1) <= plan.wall_thickness
            for r in (plan.rooms[i] for i in plan.rooms_of_door(d))
        )
        half = d.width / 2
        a, b = (
            ((d.x - half, d.y), (d.x + half, d.y))
            if along_x
            else ((d.x, d.y - half), (d.x, d.y + half))
        )
        cv2.line(img, px(*a), px(*b), (60, 170, 60), 3, cv2.LINE_AA)
    for leg in legs:
        pts = np.array([px(x, y) for x, y in leg], np.int32)
        cv2.polylines(img, [pts], False, (200, 90, 20), 1, cv2.LINE_AA)
        if len(pts) >= 2:
            tip, back = pts[-1], pts[-2]
            heading = (tip - back).astype(np.float64)
            norm = float(np.hypot(heading[0], heading[1]))
            if norm > 0:
                tail = tip - (heading / norm * min(norm, 18.0)).astype(np.int32)
                cv2.arrowedLine(
                    img,
                    (int(tail[0]), int(tail[1])),
                    (int(tip[0]), int(tip[1])),
                    (200, 90, 20),
                    1,
                    cv2.LINE_AA,
                    tipLength=0.5,
                )
    for pic in plan.pictures:
        nx, ny = math.cos(pic.yaw), math.sin(pic.yaw)
        a = px(pic.x - ny * pic.width / 2, pic.y + nx * pic.width / 2)
        b = px(pic.x + ny * pic.width / 2, pic.y - nx * pic.width / 2)
        cv2.line(img, a, b, (0, 140, 255), 3)
    if path:
        pts = np.array([px(x, y) for x, y in path], np.int32)
        cv2.polylines(img, [pts], False, (200, 60, 0), 2, cv2.LINE_AA)
    for pose in poses or []:
        tail = px(pose.x, pose.y)
        head = px(pose.x + 0.3 * math.cos(pose.theta), pose.y + 0.3 * math.sin(pose.theta))
        cv2.arrowedLine(img, tail, head, (200, 0, 200), 2, cv2.LINE_AA, tipLength=0.4)
    for p in plan.places:
        spot = px(p.x, p.y)
        cv2.circle(img, spot, 7, (0, 0, 220), -1, cv2.LINE_AA)
        tip = px(p.x + 0.45 * math.cos(p.yaw), p.y + 0.45 * math.sin(p.yaw))
        cv2.arrowedLine(img, spot, tip, (0, 0, 220), 2, cv2.LINE_AA, tipLength=0.35)
        (tw, th), _ = cv2.getTextSize(p.name, cv2.FONT_HERSHEY_SIMPLEX, 0.55, 2)
        org = (spot[0] - tw // 2, spot[1] + 24)
        cv2.rectangle(
            img, (org[0] - 2, org[1] - th - 3), (org[0] + tw + 2, org[1] + 4), (255, 255, 255), -1
        )
        cv2.putText(img, p.name, org, cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 160), 2, cv2.LINE_AA)
    return img
