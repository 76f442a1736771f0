"""The dashboard's 3D scene: the tour graph, coloured by the belief, and the robot on it.

Places are spheres named just below themselves, taught paths are lines with one point per
taught image (coloured by the belief along the path), the robot's most likely position is a
wire ring and the image it homes on a green ball. The scene is rebuilt when the graph changes
and recoloured from each snapshot. The view is fitted to each browser's own 3D canvas (its
width and height as the browser reports them), so the whole tour shows however narrow the
canvas between the panels is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
import viser

from server.layout import GraphLayout, fine_position, graph_layout, image_position
from web.ambiguity import edge_entropy_colors
from web.imagery import belief_colors

if TYPE_CHECKING:
    from server.domain import TourGraph
    from web.publisher import Snapshot

FloatArray = npt.NDArray[np.float64]

TILT = 0.25
"""How far behind the graph the camera stands, per unit of height (a view from nearly above)."""
MARGIN = 1.35
"""Room around the graph in the fitted view (labels stand out of it)."""


@dataclass(frozen=True)
class View:
    """A camera over the graph: ``eye`` and ``look`` (layout units), the world directions of
    the screen's right and down (labels go below their places)."""

    eye: tuple[float, float, float]
    look: tuple[float, float, float]
    right: FloatArray
    down: FloatArray


def fit_view(layout: GraphLayout, *, aspect: float = 0.6, fov: float = math.radians(75)) -> View:
    """The view from above (slightly behind) that shows the whole graph on a canvas of
    ``aspect`` (width / height) and vertical field of view ``fov`` (rad): the graph's long
    axis (its principal axis, or the nearer of x and y when within :data:`SNAP_DEG` of it)
    runs up the screen, and the camera stands as far as the tighter of the two directions
    needs, with :data:`MARGIN`."""
    c = np.asarray(layout.center, dtype=np.float64)
    xy = np.concatenate([layout.places[:, :2], *[p[:, :2] for p in layout.edge_points]])
    major = _long_axis(xy - c[:2]) if len(xy) > 1 else np.array([1.0, 0.0])
    minor = np.array([-major[1], major[0]])
    rel = xy - c[:2] if len(xy) else np.zeros((1, 2))
    tall = float(np.ptp(rel @ major)) if len(xy) else 1.0
    wide = float(np.ptp(rel @ minor)) if len(xy) else 1.0
    half_v = math.tan(fov / 2)
    half_h = half_v * max(aspect, 0.05)
    height = MARGIN * max(0.5 * tall / half_v, 0.5 * wide / half_h, 0.5)
    back = TILT * height
    eye = (float(c[0] - back * major[0]), float(c[1] - back * major[1]), float(height))
    right = np.array([major[1], -major[0], 0.0])  # looking along +major, +z up
    down = np.array([-major[0], -major[1], 0.0])
    return View(eye, (float(c[0]), float(c[1]), 0.0), right, down)


SNAP_DEG = 20.0
"""A long axis this close to x or y is taken as that axis (floor plans run along them)."""


def _long_axis(points: FloatArray) -> FloatArray:
    """Unit ``(2,)`` direction of the largest spread of ``points`` (``(n, 2)``, centred),
    snapped to the nearest of +-x and +-y within :data:`SNAP_DEG`; it points to +x or +y."""
    values, vectors = np.linalg.eigh(points.T @ points)
    axis = vectors[:, int(np.argmax(values))]
    if abs(axis[0]) >= abs(axis[1]):
        axis = axis if axis[0] >= 0 else -axis
    else:
        axis = axis if axis[1] >= 0 else -axis
    for snapped in (np.array([1.0, 0.0]), np.array([0.0, 1.0])):
        if abs(float(axis @ snapped)) >= math.cos(math.radians(SNAP_DEG)):
            return snapped
    return axis / float(np.linalg.norm(axis))


@dataclass
class GraphScene:
    """Scene handles of the graph on screen (rebuilt when ``key`` changes)."""

    key: tuple[object, ...]
    graph: TourGraph | None = None
    layout: GraphLayout | None = None
    places: list[viser.IcosphereHandle] = field(default_factory=list)
    labels: list[viser.LabelHandle] = field(default_factory=list)
    edges: viser.LineSegmentsHandle | None = None
    points: viser.PointCloudHandle | None = None
    distinct: viser.PointCloudHandle | None = None  # each edge image by its distinctiveness
    robot: viser.IcosphereHandle | None = None
    target: viser.IcosphereHandle | None = None
    radius: float = 0.1
    sent: dict[str, object] = field(default_factory=dict)
    fitted: dict[int, tuple[int, int]] = field(default_factory=dict)  # client -> canvas size

    @classmethod
    def build(
        cls, server: viser.ViserServer, graph: TourGraph | None, key: tuple[object, ...]
    ) -> GraphScene:
        """Draw ``graph`` (nothing for ``None``) and point every browser's camera at it."""
        if graph is None:
            return cls(key)
        layout = graph_layout(graph)
        sc = server.scene
        radius = float(np.clip(0.035 * layout.extent, 0.05, 1.0))
        view = fit_view(layout)
        scene = cls(key, graph, layout, radius=radius)
        for k, loc in enumerate(graph.locations):
            pos = layout.places[k]
            scene.places.append(
                sc.add_icosphere(
                    f"/graph/place/{k}",
                    radius=radius,
                    color=(96, 108, 128),
                    position=pos,
                    subdivisions=2,
                )
            )
            scene.labels.append(
                sc.add_label(
                    f"/graph/label/{k}",
                    loc.name,
                    position=pos + 1.3 * radius * view.down,
                    anchor="top-center",
                    font_screen_scale=1.0,
                )
            )
        if len(layout.segments):
            scene.edges = sc.add_line_segments(
                "/graph/edges",
                points=layout.segments,
                colors=np.full((*layout.segments.shape[:2], 3), 150, dtype=np.uint8),
                thickness=3.0,
                thickness_units="screen",
            )
        all_points = [p for p in layout.edge_points if len(p)]
        if all_points:
            pts = np.concatenate(all_points, axis=0) + np.array([0, 0, 0.2 * radius])
            scene.points = sc.add_point_cloud(
                "/graph/belief",
                points=pts.astype(np.float32),
                colors=np.full((len(pts), 3), 150, dtype=np.uint8),
                point_size=0.5 * radius,
                point_shape="circle",
                precision="float32",
            )
            if graph.has_entropy:  # a band beside the belief, green to red (web.ambiguity)
                colours = np.concatenate(edge_entropy_colors(graph), axis=0)
                scene.distinct = sc.add_point_cloud(
                    "/graph/distinctiveness",
                    points=(pts - np.array([0, 0.9 * radius, 0.4 * radius])).astype(np.float32),
                    colors=colours,
                    point_size=0.35 * radius,
                    point_shape="circle",
                    precision="float32",
                )
        scene.robot = sc.add_icosphere(
            "/graph/robot",
            radius=1.9 * radius,
            color=(20, 20, 20),
            wireframe=True,
            subdivisions=1,
            visible=False,
        )
        scene.target = sc.add_icosphere(
            "/graph/target",
            radius=0.7 * radius,
            color=(22, 163, 74),
            visible=False,
            subdivisions=1,
        )
        server.initial_camera.position = view.eye
        server.initial_camera.look_at = view.look
        scene.fit(server)
        return scene

    def fit(self, server: viser.ViserServer) -> None:
        """Point each browser's camera so the whole graph shows on its canvas (once per canvas
        size: a browser the user has turned since keeps its view until its canvas changes)."""
        if self.layout is None:
            return
        for client in server.get_clients().values():
            camera = client.camera
            try:
                size = (int(camera.image_width), int(camera.image_height))
                fov = float(camera.fov)
            except AssertionError:  # the browser has not reported its camera yet
                continue
            if size[1] <= 0 or self.fitted.get(client.client_id) == size:
                continue
            self.fitted[client.client_id] = size
            view = fit_view(self.layout, aspect=size[0] / size[1], fov=fov)
            camera.position = view.eye
            camera.look_at = view.look

    def remove(self) -> None:
        handles: list[Any] = [*self.places, *self.labels]
        handles += [self.edges, self.points, self.distinct, self.robot, self.target]
        for h in handles:
            if h is not None:
                h.remove()

    def _put(self, key: str, handle: Any, attr: str, value: object) -> None:
        if self.sent.get(key) == value:
            return
        setattr(handle, attr, value)
        self.sent[key] = value

    def show(self, server: viser.ViserServer, snap: Snapshot) -> None:
        """Colour the graph by the snapshot's belief; put the robot and its target on it."""
        graph, layout = self.graph, self.layout
        if graph is None or layout is None:
            return
        n_loc = graph.n_locations
        step = snap.step
        goal = None if snap.task is None or snap.task.state != "underway" else snap.task.goal
        # compute first, then send in one atomic batch
        robot_at = target_at = None
        if step is not None and len(step.state_belief) == graph.n_states:
            loc_p = step.state_belief[:n_loc]
            edge_p = step.state_belief[n_loc:]
            fine_edges = step.fine_belief[n_loc:]
            peak = float(fine_edges.max()) if len(fine_edges) else 0.0
            point_p = fine_edges / peak if peak > 0 else fine_edges
            robot_at = fine_position(layout, graph, int(np.argmax(step.fine_belief)))
            if step.target_image is not None:
                target_at = image_position(layout, graph, step.target_image)
        else:
            loc_p = np.zeros(n_loc)
            edge_p = np.zeros(graph.n_edges)
            point_p = np.zeros(sum(e.n_images for e in graph.edges))
        place_colors = belief_colors(loc_p)
        seg_colors = np.repeat(belief_colors(edge_p)[layout.segment_edge][:, None, :], 2, axis=1)
        point_colors = belief_colors(point_p)
        label_texts = [
            f"{loc.name} (goal)" if loc.name == goal else loc.name for loc in graph.locations
        ]
        with server.atomic():
            for k, handle in enumerate(self.places):
                colour = tuple(int(x) for x in place_colors[k])
                self._put(f"place.{k}.color", handle, "color", colour)
                scale = round(1.0 + 0.8 * math.sqrt(loc_p[k]), 3)
                self._put(f"place.{k}.scale", handle, "scale", scale)
                self._put(f"label.{k}", self.labels[k], "text", label_texts[k])
            if self.edges is not None and len(seg_colors):
                self.edges.colors = seg_colors
            if self.points is not None and len(point_colors):
                self.points.colors = point_colors
            if self.robot is not None:
                self.robot.visible = robot_at is not None
                if robot_at is not None:
                    self.robot.position = robot_at
            if self.target is not None:
                self.target.visible = target_at is not None
                if target_at is not None:
                    self.target.position = target_at
        self.fit(server)
