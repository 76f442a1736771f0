"""The live dashboard: a viser app on its own port, fed by the :class:`~web.publisher.Publisher`.

What it shows, for the robot picked in the selector and the tour it uses: the tour graph in 3D
(places as labelled spheres, taught paths as lines, laid out from the recorded odometry when
the tour has it, else a seeded networkx layout), the belief per place and path as colour and
size and along each path as coloured points, the camera frame beside the best-matching stored
image, the action with its target image and the vote mass of every action, the belief entropy,
plots of the belief along the active path and of the top belief over time, the navigation task,
and the teaching progress.

Controls (robot selector; goal, Go, Stop; place name, Mark, Finish, Abort) call the same service
layer as the REST routes, so the same checks apply; a refused action shows its message.

Design (STYLE principle 9): the dashboard holds viser handles, not state. Its selection lives
in the selector handles; everything drawn comes from the latest snapshot. The GUI and scene are
*shared* (``server.gui`` / ``server.scene``): every browser sees the same robot, and the cost of
a refresh does not grow with the number of browsers. All viser updates happen in the publisher
thread (button callbacks only call services and write the message line); arrays and images are
prepared before ``server.atomic()`` so nothing blocks inside it, and no lock is held while
talking to viser.
"""

from __future__ import annotations

import logging
import math
import re
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import cv2
import networkx as nx
import numpy as np
import numpy.typing as npt
import viser
import viser.uplot
from pydantic import ValidationError

from server import schemas
from server.errors import DomainError
from web.publisher import Publisher, Snapshot, StepView

if TYPE_CHECKING:
    from server.domain import Edge, TourGraph
    from server.services.container import Services
    from server.session import Segment

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
ImageArray = npt.NDArray[np.uint8]

NONE = "—"
"""Placeholder option of a dropdown with nothing to choose."""

ACTIONS = ("navigate", "rotate_and_find_edge", "explore", "do_nothing")
PANEL_IMAGE_HEIGHT = 200
"""Height (px) each image is scaled to in the side-by-side camera / best match view."""


# --- layout of the tour graph ----------------------------------------------------------------


@dataclass(frozen=True)
class GraphLayout:
    """Where the graph is drawn (metres when ``odometry``; arbitrary units otherwise).

    * ``places``: ``(n_locations, 3)`` float32 position of every location.
    * ``edge_points``: per edge, ``(n_images_e, 3)`` float32 position of each of its images.
    * ``segments``: ``(n_segments, 2, 3)`` float32 line segments of all edges;
      ``segment_edge``: ``(n_segments,)`` the edge each segment belongs to.
    * ``extent``: size of the drawing (>= 1), to scale markers; ``center``: its middle.
    """

    places: npt.NDArray[np.float32]
    edge_points: tuple[npt.NDArray[np.float32], ...]
    segments: npt.NDArray[np.float32]
    segment_edge: npt.NDArray[np.int64]
    odometry: bool
    extent: float
    center: npt.NDArray[np.float32]


def has_odometry(edge: Edge) -> bool:
    """True when the edge recorded timestamps and a non-zero motion to integrate."""
    t = np.asarray(edge.timestamps, dtype=np.float64)
    if len(t) < 2 or not np.all(np.isfinite(t)) or t[-1] <= t[0]:
        return False
    v = np.asarray(edge.v, dtype=np.float64)
    return bool(np.sum(np.abs(v[:-1]) * np.diff(t)) > 1e-3)


def integrate_edge(edge: Edge) -> FloatArray:
    """``(n_images + 2, 3)`` poses ``(x, y, heading)`` along an edge in its start frame:
    the source place, every image, then the target place.

    Unicycle dead reckoning over the edge's timestamps with the (v, w) recorded at each
    image; the places are one median frame interval before the first / after the last image.
    """
    t = np.asarray(edge.timestamps, dtype=np.float64)
    n = len(t)
    if n == 0:
        return np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    dt0 = float(np.median(np.diff(t))) if n > 1 else 0.1
    times = np.concatenate([[t[0] - dt0], t, [t[-1] + dt0]])
    v = np.asarray(edge.v, dtype=np.float64)
    w = np.asarray(edge.w, dtype=np.float64)
    v = np.concatenate([[v[0]], v, [v[-1]]])
    w = np.concatenate([[w[0]], w, [w[-1]]])
    poses = np.zeros((n + 2, 3))
    for k in range(1, n + 2):
        dt = max(0.0, times[k] - times[k - 1])
        x, y, th = poses[k - 1]
        mid = th + 0.5 * w[k - 1] * dt
        poses[k] = (
            x + v[k - 1] * math.cos(mid) * dt,
            y + v[k - 1] * math.sin(mid) * dt,
            th + w[k - 1] * dt,
        )
    return poses


def _fit(raw: FloatArray, start: FloatArray, end: FloatArray) -> FloatArray:
    """Map a path ``raw`` (m, 2) whose first point is the origin onto ``start`` -> ``end`` by a
    rotation and scale (straight line when the raw path returns to where it began)."""
    d_raw = raw[-1] - raw[0]
    d_act = end - start
    n_raw = float(np.hypot(*d_raw))
    if n_raw < 1e-9:
        s = np.linspace(0.0, 1.0, len(raw))[:, None]
        return start + s * d_act
    angle = math.atan2(d_act[1], d_act[0]) - math.atan2(d_raw[1], d_raw[0])
    scale = float(np.hypot(*d_act)) / n_raw
    c, s_ = math.cos(angle), math.sin(angle)
    rot = np.array([[c, -s_], [s_, c]])
    return start + scale * (raw - raw[0]) @ rot.T


def _odometry_places(graph: TourGraph, raws: list[FloatArray]) -> FloatArray:
    """``(n_locations, 2)`` positions by chaining edges from location 0 (spanning tree);
    ``raws`` are the ``(n_images + 2, 3)`` poses of every edge in its start frame."""
    n = graph.n_locations
    pose: dict[int, tuple[float, float, float]] = {}
    gap = max(1.0, max((float(np.ptp(r[:, 0])) for r in raws), default=1.0))
    while len(pose) < n:
        if not pose or not _grow(graph, raws, pose):
            root = next(k for k in range(n) if k not in pose)
            x0 = max((p[0] for p in pose.values()), default=-gap) + gap
            pose[root] = (x0, 0.0, 0.0)
            continue
    return np.array([[pose[k][0], pose[k][1]] for k in range(n)], dtype=np.float64)


def _grow(
    graph: TourGraph, raws: list[FloatArray], pose: dict[int, tuple[float, float, float]]
) -> bool:
    """Place one more location through an edge that touches a placed one; False if none."""
    for j, e in enumerate(graph.edges):
        raw = raws[j]
        dx, dy, dth = raw[-1]
        if e.source in pose and e.target not in pose:
            x, y, th = pose[e.source]
            c, s = math.cos(th), math.sin(th)
            pose[e.target] = (x + c * dx - s * dy, y + s * dx + c * dy, th + dth)
            return True
        if e.target in pose and e.source not in pose:
            x, y, th = pose[e.target]
            th0 = th - dth
            c, s = math.cos(th0), math.sin(th0)
            pose[e.source] = (x - (c * dx - s * dy), y - (s * dx + c * dy), th0)
            return True
    return False


def graph_layout(graph: TourGraph, *, seed: int = 0) -> GraphLayout:
    """Positions of every place and edge image, from odometry when every edge has it.

    Otherwise a networkx spring layout with a fixed ``seed`` (the same graph is always drawn
    the same way) and straight paths. Paths between the same two places (both directions, or
    taught twice) bow out to their right so each stays visible.
    """
    n_loc = graph.n_locations
    odometry = graph.n_edges > 0 and all(has_odometry(e) for e in graph.edges)
    raws: list[FloatArray] = []
    if odometry:
        raws = [integrate_edge(e) for e in graph.edges]
        places2 = _odometry_places(graph, raws)
    elif n_loc:
        g = nx.Graph()
        g.add_nodes_from(range(n_loc))
        g.add_edges_from((e.source, e.target) for e in graph.edges if e.source != e.target)
        if n_loc == 1:
            places2 = np.zeros((1, 2))
        else:
            pos = nx.spring_layout(g, seed=seed)
            places2 = np.array([pos[k] for k in range(n_loc)], dtype=np.float64)
            places2 *= 1.5 * math.sqrt(n_loc)
    else:
        places2 = np.zeros((0, 2))

    extent = 1.0
    if n_loc > 1:
        extent = max(1.0, float(np.ptp(places2, axis=0).max()))
    pair_rank: dict[tuple[int, int], int] = {}
    edge_points: list[npt.NDArray[np.float32]] = []
    segments: list[FloatArray] = []
    segment_edge: list[int] = []
    pairs = {(e.source, e.target) for e in graph.edges}
    for j, e in enumerate(graph.edges):
        start, end = places2[e.source], places2[e.target]
        n = e.n_images
        if odometry:
            path = _fit(raws[j][:, :2], start, end)  # (n + 2, 2) incl. both places
        else:
            s = np.linspace(0.0, 1.0, n + 2)[:, None]
            path = start + s * (end - start)
        rank = pair_rank.get((e.source, e.target), 0)
        pair_rank[(e.source, e.target)] = rank + 1
        if e.source == e.target:  # a loop: draw a circle beside the place
            ang = np.linspace(0.0, 2 * math.pi, n + 2)
            radius = 0.08 * extent * (1 + rank)
            path = start + radius * np.stack([np.sin(ang), 1 - np.cos(ang)], axis=1)
        elif (e.target, e.source) in pairs or rank > 0:
            d = end - start
            length = float(np.hypot(*d))
            if length > 1e-9:
                right = np.array([d[1], -d[0]]) / length
                s = np.linspace(0.0, 1.0, len(path))
                bow = 0.06 * max(length, 0.2 * extent) * (1 + rank)
                path = path + (bow * np.sin(math.pi * s))[:, None] * right
        path3 = np.concatenate([path, np.zeros((len(path), 1))], axis=1)
        edge_points.append(path3[1:-1].astype(np.float32))
        segments.append(np.stack([path3[:-1], path3[1:]], axis=1))
        segment_edge.extend([j] * (len(path3) - 1))
    places = np.concatenate([places2, np.zeros((n_loc, 1))], axis=1).astype(np.float32)
    all_xy = np.concatenate([places2, *[p[:, :2] for p in edge_points]], axis=0)
    if len(all_xy):
        extent = max(1.0, float(np.ptp(all_xy, axis=0).max()))
        center = np.append(0.5 * (all_xy.min(axis=0) + all_xy.max(axis=0)), 0.0)
    else:
        center = np.zeros(3)
    return GraphLayout(
        places=places,
        edge_points=tuple(edge_points),
        segments=(
            np.concatenate(segments, axis=0).astype(np.float32)
            if segments
            else np.zeros((0, 2, 3), dtype=np.float32)
        ),
        segment_edge=np.asarray(segment_edge, dtype=np.int64),
        odometry=odometry,
        extent=extent,
        center=center.astype(np.float32),
    )


# --- colours and images ----------------------------------------------------------------------

_STOPS = np.array([[96, 108, 128], [66, 135, 245], [255, 170, 0], [220, 38, 38]], dtype=np.float64)


def belief_colors(p: npt.ArrayLike) -> ImageArray:
    """``(n, 3)`` uint8 colours for probabilities ``p`` in [0, 1]: slate (none) through blue
    and amber to red (all the mass). A square root makes small masses visible."""
    t = np.sqrt(np.clip(np.asarray(p, dtype=np.float64), 0.0, 1.0)) * (len(_STOPS) - 1)
    lo = np.minimum(np.floor(t).astype(np.int64), len(_STOPS) - 2)
    frac = (t - lo)[..., None]
    out = _STOPS[lo] * (1 - frac) + _STOPS[lo + 1] * frac
    return np.round(out).astype(np.uint8)


def decode_rgb(jpeg: bytes | None) -> ImageArray | None:
    """RGB ``(h, w, 3)`` uint8 of JPEG bytes (cv2), or None when they do not decode."""
    if not jpeg:
        return None
    bgr = cv2.imdecode(np.frombuffer(jpeg, dtype=np.uint8), cv2.IMREAD_COLOR)
    if bgr is None:
        return None
    return np.asarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), dtype=np.uint8)


def placeholder(text: str, *, width: int = 320, height: int = PANEL_IMAGE_HEIGHT) -> ImageArray:
    """A dark tile with ``text`` in the middle."""
    img = np.full((height, width, 3), 38, dtype=np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    (tw, th), _ = cv2.getTextSize(text, font, 0.55, 1)
    org = (max(4, (width - tw) // 2), (height + th) // 2)
    cv2.putText(img, text, org, font, 0.55, (170, 176, 190), 1, cv2.LINE_AA)
    return img


def captioned(image: ImageArray | None, caption: str, *, height: int) -> ImageArray:
    """``image`` scaled to ``height`` with a caption bar on top (a placeholder when None)."""
    if image is None:
        tile = placeholder("no image", width=int(height * 4 / 3), height=height)
    else:
        h, w = image.shape[:2]
        width = max(1, round(w * height / h))
        tile = np.asarray(
            cv2.resize(image, (width, height), interpolation=cv2.INTER_LINEAR), dtype=np.uint8
        )
    bar = np.full((26, tile.shape[1], 3), 24, dtype=np.uint8)
    cv2.putText(
        bar, caption, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (235, 235, 240), 1, cv2.LINE_AA
    )
    return np.ascontiguousarray(np.concatenate([bar, tile], axis=0))


def side_by_side(
    left: ImageArray | None,
    right: ImageArray | None,
    captions: tuple[str, str],
    *,
    height: int = PANEL_IMAGE_HEIGHT,
) -> ImageArray:
    """The two images at the same height next to each other, each with its caption."""
    a = captioned(left, captions[0], height=height)
    b = captioned(right, captions[1], height=height)
    gap = np.full((a.shape[0], 6, 3), 255, dtype=np.uint8)
    return np.ascontiguousarray(np.concatenate([a, gap, b], axis=1))


BEHAVIOUR_COLOURS: dict[str, tuple[int, int, int]] = {
    "follow": (37, 99, 235),
    "leave": (14, 165, 233),
    "search": (234, 179, 8),
    "explore": (168, 85, 247),
    "unstick": (220, 38, 38),
    "backoff": (249, 115, 22),
    "escape": (190, 24, 93),
    "dock": (22, 163, 74),
    "place-dock": (132, 204, 22),
    "settle": (13, 148, 136),
    "stand": (148, 163, 184),
}
"""RGB colour of each behaviour in the dashboard's strip (server.navigation.BEHAVIOURS)."""


def behaviour_strip(timeline: Sequence[Segment], *, width: int = 540) -> ImageArray:
    """The current task's behaviours over time as a coloured strip (robot seconds from the
    task's first frame along x), with a legend of the behaviours it shows and their share."""
    bar_h, legend_h = 22, 22
    img = np.full((bar_h + 16 + legend_h, width, 3), 255, dtype=np.uint8)
    if not timeline:
        cv2.putText(
            img,
            "behaviours: no task yet",
            (6, 16),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.45,
            (90, 90, 90),
            1,
            cv2.LINE_AA,
        )
        return img
    t0 = timeline[0].t0
    span = max(timeline[-1].t1 - t0, 1e-6)
    share: dict[str, float] = {}
    for seg in timeline:
        x0 = int((seg.t0 - t0) / span * (width - 1))
        x1 = max(x0 + 1, int((seg.t1 - t0) / span * (width - 1)) + 1)
        img[:bar_h, x0:x1] = BEHAVIOUR_COLOURS.get(seg.behaviour, (60, 60, 60))
        share[seg.behaviour] = share.get(seg.behaviour, 0.0) + seg.t1 - seg.t0 + 0.1
    for k in range(0, int(span) + 1, max(1, int(span) // 6 or 1)):
        x = int(k / span * (width - 1))
        cv2.putText(
            img,
            f"{k}s",
            (min(x, width - 30), bar_h + 12),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.35,
            (90, 90, 90),
            1,
            cv2.LINE_AA,
        )
    x = 4
    total = sum(share.values())
    for name, t in sorted(share.items(), key=lambda kv: -kv[1]):
        label = f"{name} {t / total:.0%}"
        cv2.rectangle(
            img,
            (x, bar_h + 20),
            (x + 10, bar_h + 30),
            BEHAVIOUR_COLOURS.get(name, (60, 60, 60)),
            -1,
        )
        cv2.putText(
            img,
            label,
            (x + 13, bar_h + 30),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.38,
            (40, 40, 40),
            1,
            cv2.LINE_AA,
        )
        x += 20 + 7 * len(label)
        if x > width - 60:
            break
    return img


def error_text(exc: Exception) -> str:
    """What to tell the user about a refused action."""
    if isinstance(exc, DomainError):
        return exc.message
    if isinstance(exc, ValidationError):
        parts = []
        for err in exc.errors():
            where = ".".join(str(p) for p in err.get("loc", ())) or "input"
            parts.append(f"{where}: {err.get('msg', 'invalid')}")
        return "invalid input - " + "; ".join(parts)
    return f"unexpected error: {exc}"


def _bar(p: float, width: int = 16) -> str:
    filled = round(max(0.0, min(1.0, p)) * width)
    return "█" * filled + "·" * (width - filled)


def _assign(handle: Any, value: object) -> None:
    """``handle.value = value`` (viser's setter, which also runs the handle's callbacks)."""
    handle.value = value


def _tour_label(tour_id: int, name: str) -> str:
    return f"{name} (#{tour_id})"


def _tour_id(label: str) -> int | None:
    found = re.search(r"\(#(\d+)\)$", label)
    return int(found.group(1)) if found else None


# --- the app ---------------------------------------------------------------------------------


@dataclass
class Controls:
    """The GUI handles; assigning ``.value = True`` to a button clicks it (as tests do)."""

    message: viser.GuiMarkdownHandle
    robot: viser.GuiDropdownHandle[str]
    status: viser.GuiMarkdownHandle
    tour: viser.GuiDropdownHandle[str]
    goal: viser.GuiDropdownHandle[str]
    go: viser.GuiButtonHandle
    stop: viser.GuiButtonHandle
    teaching: viser.GuiMarkdownHandle
    place_name: viser.GuiTextHandle
    mark: viser.GuiButtonHandle
    finish: viser.GuiButtonHandle
    abort: viser.GuiButtonHandle
    images: viser.GuiImageHandle
    action: viser.GuiMarkdownHandle
    strip: viser.GuiImageHandle
    target: viser.GuiImageHandle
    votes: viser.GuiMarkdownHandle
    along_label: viser.GuiMarkdownHandle
    along_edge: viser.GuiUplotHandle
    over_time: viser.GuiUplotHandle


@dataclass
class _Scene:
    """Scene handles of the graph on screen (rebuilt when the graph changes)."""

    key: tuple[object, ...]
    layout: GraphLayout | None
    places: list[viser.IcosphereHandle]
    labels: list[viser.LabelHandle]
    edges: viser.LineSegmentsHandle | None
    points: viser.PointCloudHandle | None
    robot: viser.IcosphereHandle | None
    robot_label: viser.LabelHandle | None
    target: viser.IcosphereHandle | None
    radius: float
    right: FloatArray  # screen-right direction of the initial view (labels go there)

    def remove(self) -> None:
        handles: list[Any] = [*self.places, *self.labels]
        handles += [self.edges, self.points, self.robot, self.robot_label, self.target]
        for h in handles:
            if h is not None:
                h.remove()


class Dashboard:
    """The viser dashboard of one server. ``start()`` serves it; ``stop()`` ends it.

    ``port`` 0 picks any free port; when the requested port is busy viser silently takes the
    next one, which :meth:`start` detects, warns about and reports in ``port``.
    """

    def __init__(
        self,
        services: Services,
        *,
        host: str = "127.0.0.1",
        port: int = 8080,
        refresh_hz: float = 5.0,
    ) -> None:
        self.services = services
        self.host = host
        self.requested_port = port
        self.port = port
        self.refresh_hz = refresh_hz
        self.server: viser.ViserServer | None = None
        self.controls: Controls | None = None
        self.publisher = Publisher(
            services, selection=self._selection, sink=self._render, hz=refresh_hz
        )
        self._scene: _Scene | None = None
        self._sent: dict[str, object] = {}
        self._step_key: tuple[object, ...] | None = None
        self._bound_seen: tuple[str | None, int | None] | None = None
        self._task_seen: int | None = None

    # --- lifecycle ------------------------------------------------------------------------

    def start(self) -> int:
        """Serve the dashboard and start publishing; returns the port actually used."""
        if self.server is not None:
            return self.port
        server = viser.ViserServer(host=self.host, port=self.requested_port, verbose=False)
        self.server = server
        self.port = server.get_port()
        if self.requested_port not in (0, self.port):
            message = (
                f"dashboard port {self.requested_port} is busy; the dashboard is on port "
                f"{self.port} instead (choose one with --dashboard-port, 0 = any free port)"
            )
            warnings.warn(message, RuntimeWarning, stacklevel=2)
            log.warning(message)
        self.controls = self._build_gui(server)
        self.publisher.start()
        return self.port

    def stop(self) -> None:
        """Stop publishing and serving (idempotent)."""
        self.publisher.stop()
        if self.server is not None:
            self.server.stop()
            self.server = None

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}"

    def refresh(self, timeout_s: float = 5.0) -> Snapshot | None:
        """Publish a fresh snapshot now (robot and tour lists re-read) and return it; waits for
        the publisher thread when it runs."""
        self.publisher.refresh_lists()
        if self.publisher.running:
            before = self.publisher.published
            self.publisher.poke()
            self.publisher.wait_published(before, timeout_s)
            return self.publisher.latest
        return self.publisher.publish_once()

    # --- selection (read from the handles) ------------------------------------------------

    def _selection(self) -> tuple[str | None, int | None]:
        c = self.controls
        if c is None:
            return None, None
        robot = c.robot.value if c.robot.value != NONE else None
        return robot, _tour_id(c.tour.value)

    # --- GUI ------------------------------------------------------------------------------

    def _build_gui(self, server: viser.ViserServer) -> Controls:
        gui = server.gui
        gui.configure_theme(
            control_width="large",
            show_share_button=False,
            show_logo=False,
            brand_color=(37, 99, 235),
            titlebar_content=None,
        )
        gui.set_panel_label("teachrepeat")
        server.scene.set_up_direction("+z")
        server.scene.add_grid(
            "/grid",
            width=40.0,
            height=40.0,
            plane="xy",
            position=(0.0, 0.0, -0.02),
            cell_color=(225, 228, 235),
            section_color=(200, 205, 215),
            shadow_opacity=0.0,
        )
        main = gui.main_panel
        main.dock_left()
        main.set_width(380)

        message = gui.add_markdown("")
        gui.add_markdown(
            "Places are spheres, taught paths lines; colour and size show the belief "
            "(slate 0, blue, amber, red 1). The ring is the most likely position."
        )
        with gui.add_folder("Robot"):
            robot = gui.add_dropdown("Robot", (NONE,), hint="The robot shown and controlled")
            status = gui.add_markdown("*waiting for the first snapshot...*")
        with gui.add_folder("Go to a place"):
            tour = gui.add_dropdown("Tour", (NONE,), hint="The tour whose places are listed")
            goal = gui.add_dropdown("Goal", (NONE,), hint="Where the robot should go")
            go = gui.add_button("Go", color="blue", hint="POST /robots/{robot}/goto")
            stop = gui.add_button("Stop", color="red", hint="POST /robots/{robot}/stop")
        with gui.add_folder("Teach"):
            teaching = gui.add_markdown("")
            place_name = gui.add_text("Name this place", "", hint="e.g. kitchen")
            mark = gui.add_button("Mark", hint="POST /robots/{robot}/teach/locations")
            finish = gui.add_button("Finish", color="green", hint="POST .../teach/finish")
            abort = gui.add_button("Abort", color="gray", hint="POST .../teach/abort")

        panel = gui.add_panel()
        with panel.add_tab("Camera and belief"):
            images = gui.add_image(
                side_by_side(None, None, ("camera", "best match")), label=None, format="jpeg"
            )
            action = gui.add_markdown("")
            strip = gui.add_image(behaviour_strip(()), label=None, format="png")
            target = gui.add_image(
                captioned(None, "target image", height=120), label=None, format="jpeg"
            )
            votes = gui.add_markdown("")
            along_label = gui.add_markdown("")
            along_edge = gui.add_uplot(
                data=(np.zeros(1), np.zeros(1), np.zeros(1)),
                series=(
                    viser.uplot.Series(label="image"),
                    viser.uplot.Series(label="b(i|e)", stroke="#dc2626", width=2),
                    viser.uplot.Series(label="similarity", stroke="#2563eb", width=1.5),
                ),
                title="belief along the active path (by image)",
                scales={"x": viser.uplot.Scale(time=False, auto=True)},
                legend=viser.uplot.Legend(show=True),
                aspect=2.0,
            )
            over_time = gui.add_uplot(
                data=(np.zeros(1), np.zeros(1), np.zeros(1)),
                series=(
                    viser.uplot.Series(label="t (s)"),
                    viser.uplot.Series(label="top b(s)", stroke="#dc2626", width=2),
                    viser.uplot.Series(label="entropy / max", stroke="#6b7280", width=1.5),
                ),
                title="top belief over time",
                scales={
                    "x": viser.uplot.Scale(time=False, auto=True),
                    "y": viser.uplot.Scale(auto=False, range=(0.0, 1.0)),
                },
                legend=viser.uplot.Legend(show=True),
                aspect=2.0,
            )
        panel.dock_right()
        panel.set_width(560)

        controls = Controls(
            message=message,
            robot=robot,
            status=status,
            tour=tour,
            goal=goal,
            go=go,
            stop=stop,
            teaching=teaching,
            place_name=place_name,
            mark=mark,
            finish=finish,
            abort=abort,
            images=images,
            action=action,
            strip=strip,
            target=target,
            votes=votes,
            along_label=along_label,
            along_edge=along_edge,
            over_time=over_time,
        )
        robot.on_update(lambda _: self.publisher.poke())
        tour.on_update(lambda _: self.publisher.poke())
        go.on_click(self._on_go)
        stop.on_click(self._on_stop)
        mark.on_click(self._on_mark)
        finish.on_click(self._on_finish)
        abort.on_click(self._on_abort)
        return controls

    # --- actions (the same service calls as the REST routes) ------------------------------

    def _act(
        self,
        event: viser.GuiEvent[Any],
        what: str,
        call: Callable[[str], str],
    ) -> None:
        """Run ``call(robot)``; show its success text or the error message."""
        c = self.controls
        if c is None:
            return
        robot = c.robot.value
        if robot == NONE:
            self._say(event, f"{what}: no robot selected - register one with POST /robots", True)
            return
        try:
            done = call(robot)
        except (DomainError, ValidationError) as exc:
            self._say(event, f"{what} refused: {error_text(exc)}", True)
        except Exception as exc:  # shown, not swallowed: the user must see that it failed
            log.exception("dashboard action %s failed", what)
            self._say(event, f"{what} failed: {error_text(exc)}", True)
        else:
            self._say(event, done, False)
        finally:
            self.publisher.refresh_lists()
            self.publisher.poke()

    def _say(self, event: viser.GuiEvent[Any], text: str, error: bool) -> None:
        c = self.controls
        if c is not None:
            c.message.content = ("**Error:** " if error else "") + text
        if event.client is not None:
            event.client.add_notification(
                "Refused" if error else "Done",
                text,
                color="red" if error else "green",
                auto_close_seconds=10.0 if error else 4.0,
            )

    def _on_go(self, event: viser.GuiEvent[Any]) -> None:
        c = self.controls
        assert c is not None
        goal, tour = c.goal.value, _tour_id(c.tour.value)

        def call(robot: str) -> str:
            if goal == NONE:
                raise DomainError("no place to go to: teach a tour first, then pick a goal")
            task = self.services.navigation.goto(
                robot, schemas.GotoRequest(location=goal, tour=tour)
            )
            return f"{robot}: task {task.id} to **{task.goal}** is {task.state}"

        self._act(event, "Go", call)

    def _on_stop(self, event: viser.GuiEvent[Any]) -> None:
        def call(robot: str) -> str:
            task = self.services.navigation.stop(robot)
            return f"{robot}: task {task.id} to {task.goal} {task.state}"

        self._act(event, "Stop", call)

    def _on_mark(self, event: viser.GuiEvent[Any]) -> None:
        c = self.controls
        assert c is not None
        name = c.place_name.value

        def call(robot: str) -> str:
            result = self.services.teaching.mark(robot, schemas.LocationMark(name=name))
            made = "new place" if result.created else "known place"
            edge = "" if result.edge is None else f", closing a path of {result.edge.image_count}"
            return f"{robot}: marked {made} **{result.location.name}**{edge}"

        self._act(event, "Mark", call)

    def _on_finish(self, event: viser.GuiEvent[Any]) -> None:
        def call(robot: str) -> str:
            ended = self.services.teaching.finish(robot)
            tour = ended.tour
            return (
                f"{robot}: finished teaching *{tour.name}*: {len(tour.locations)} places, "
                f"{len(tour.edges)} paths"
            )

        self._act(event, "Finish", call)

    def _on_abort(self, event: viser.GuiEvent[Any]) -> None:
        def call(robot: str) -> str:
            ended = self.services.teaching.abort(robot)
            return (
                f"{robot}: teaching aborted; {ended.discarded_images} images of the open "
                "path discarded"
            )

        self._act(event, "Abort", call)

    # --- rendering (publisher thread only) ------------------------------------------------

    def _put(self, key: str, handle: Any, attr: str, value: object) -> None:
        """Assign ``handle.attr = value`` only when it changed (each assignment is a message)."""
        if self._sent.get(key) == value:
            return
        setattr(handle, attr, value)
        self._sent[key] = value

    def _render(self, snap: Snapshot) -> None:
        server, c = self.server, self.controls
        if server is None or c is None:
            return
        # selectors first: setting a dropdown's options may change its value (and fire a poke)
        self._put("robot.options", c.robot, "options", snap.robots or (NONE,))
        if snap.robot is not None and c.robot.value not in snap.robots:
            _assign(c.robot, snap.robot)
        labels = tuple(_tour_label(i, n) for i, n in snap.tours) or (NONE,)
        self._put("tour.options", c.tour, "options", labels)
        bound = (snap.robot, snap.tour_id if snap.bound else None)
        if snap.tour_id is not None and (
            (snap.bound and bound != self._bound_seen) or _tour_id(c.tour.value) is None
        ):
            _assign(c.tour, _tour_label(snap.tour_id, snap.tour_name or ""))
        self._bound_seen = bound
        graph = snap.graph
        names = tuple(loc.name for loc in graph.locations) if graph is not None else ()
        self._put("goal.options", c.goal, "options", names or (NONE,))
        if snap.task is not None and snap.task.id != self._task_seen:
            self._task_seen = snap.task.id
            if snap.task.goal in names:
                _assign(c.goal, snap.task.goal)

        # prepare everything before talking to viser
        self._put("status", c.status, "content", _status_text(snap))
        self._put("teaching", c.teaching, "content", _teaching_text(snap))
        self._render_scene(server, snap)
        self._render_step(snap)

    def _render_step(self, snap: Snapshot) -> None:
        c = self.controls
        assert c is not None
        step, graph = snap.step, snap.graph
        key = (snap.robot, snap.graph_key, None if step is None else (step.index, step.timestamp))
        if key == self._step_key:
            return
        self._step_key = key
        if step is None or graph is None:
            waiting = "no navigation frames yet" if snap.robot else "no robot registered"
            c.images.image = side_by_side(None, None, ("camera", "best match"))
            c.target.image = captioned(None, "target image", height=120)
            self._put("action", c.action, "content", f"*{waiting}*")
            self._put("votes", c.votes, "content", "")
            return
        camera = decode_rgb(step.jpeg)
        best = None
        best_caption = "best match: -"
        if step.best_image is not None:
            best = decode_rgb(self.publisher.image(int(graph.image_ids[step.best_image])))
            sim = "" if step.best_similarity is None else f" ({step.best_similarity:.2f})"
            best_caption = f"best: {graph.state_name(step.best_state)}{sim}"
        target = None
        target_caption = "target image: none"
        if step.target_image is not None:
            target = decode_rgb(self.publisher.image(int(graph.image_ids[step.target_image])))
            target_caption = f"target image #{int(graph.image_ids[step.target_image])}"
        images = side_by_side(camera, best, (f"camera  t={step.timestamp:.1f} s", best_caption))
        target_img = captioned(target, target_caption, height=120)
        action_md = _action_text(step, graph)
        votes_md = _votes_text(step, graph)
        along = _along_edge_data(step, graph)
        over = _over_time_data(snap, graph)
        strip = behaviour_strip(snap.timeline)
        server = self.server
        assert server is not None
        with server.atomic():
            c.images.image = images
            c.target.image = target_img
            self._put("action", c.action, "content", action_md)
            c.strip.image = strip
            self._put("votes", c.votes, "content", votes_md)
            if along is not None:
                title, data = along
                self._put("along.label", c.along_label, "content", f"Active path: **{title}**")
                c.along_edge.data = data
            c.over_time.data = over

    def _render_scene(self, server: viser.ViserServer, snap: Snapshot) -> None:
        graph = snap.graph
        scene = self._scene
        if scene is None or scene.key != snap.graph_key:
            layout = None if graph is None else graph_layout(graph)
            if scene is not None:
                scene.remove()
            scene = self._scene = self._build_scene(server, graph, layout, snap.graph_key)
            self._step_key = None  # redraw the belief on the new scene
        layout = scene.layout
        if graph is None or layout is None:
            return
        n_loc = graph.n_locations
        step = snap.step
        goal = None if snap.task is None or snap.task.state != "underway" else snap.task.goal
        # compute first, then send in one atomic batch
        if step is not None and len(step.state_belief) == graph.n_states:
            loc_p = step.state_belief[:n_loc]
            edge_p = step.state_belief[n_loc:]
            fine_edges = step.fine_belief[n_loc:]
            peak = float(fine_edges.max()) if len(fine_edges) else 0.0
            point_p = fine_edges / peak if peak > 0 else fine_edges
            fine = int(np.argmax(step.fine_belief))
            robot_at = _fine_position(layout, graph, fine)
            target_at = (
                None
                if step.target_image is None
                else _image_position(layout, graph, step.target_image)
            )
        else:
            loc_p = np.zeros(n_loc)
            edge_p = np.zeros(graph.n_edges)
            point_p = np.zeros(sum(e.n_images for e in graph.edges))
            robot_at = target_at = None
        place_colors = belief_colors(loc_p)
        seg_colors = np.repeat(belief_colors(edge_p)[layout.segment_edge][:, None, :], 2, axis=1)
        point_colors = belief_colors(point_p)
        label_texts = [
            f"{loc.name}  (goal)" if loc.name == goal else loc.name for loc in graph.locations
        ]
        with server.atomic():
            for k, handle in enumerate(scene.places):
                self._put(
                    f"place.{k}.color", handle, "color", tuple(int(x) for x in place_colors[k])
                )
                self._put(
                    f"place.{k}.scale", handle, "scale", round(1.0 + 0.8 * math.sqrt(loc_p[k]), 3)
                )
                self._put(f"label.{k}", scene.labels[k], "text", label_texts[k])
            if scene.edges is not None and len(seg_colors):
                scene.edges.colors = seg_colors
            if scene.points is not None and len(point_colors):
                scene.points.colors = point_colors
            if scene.robot is not None and scene.robot_label is not None:
                scene.robot.visible = robot_at is not None
                scene.robot_label.visible = robot_at is not None
                if robot_at is not None:
                    scene.robot.position = robot_at
                    scene.robot_label.position = robot_at - 2.4 * scene.radius * scene.right
            if scene.target is not None:
                scene.target.visible = target_at is not None
                if target_at is not None:
                    scene.target.position = target_at

    def _build_scene(
        self,
        server: viser.ViserServer,
        graph: TourGraph | None,
        layout: GraphLayout | None,
        key: tuple[object, ...],
    ) -> _Scene:
        for stale in [key for key in self._sent if key.startswith(("place.", "label."))]:
            del self._sent[stale]
        if graph is None or layout is None:
            return _Scene(key, None, [], [], None, None, None, None, None, 0.1, np.zeros(3))
        sc = server.scene
        radius = float(np.clip(0.035 * layout.extent, 0.05, 1.0))
        eye, look, right = _camera(layout)
        places, labels = [], []
        for k, loc in enumerate(graph.locations):
            pos = layout.places[k]
            places.append(
                sc.add_icosphere(
                    f"/graph/place/{k}",
                    radius=radius,
                    color=(96, 108, 128),
                    position=pos,
                    subdivisions=2,
                )
            )
            labels.append(
                sc.add_label(
                    f"/graph/label/{k}",
                    loc.name,
                    position=pos + 2.2 * radius * right,
                    anchor="center-left",
                    font_screen_scale=1.1,
                )
            )
        edges = None
        if len(layout.segments):
            edges = sc.add_line_segments(
                "/graph/edges",
                points=layout.segments,
                colors=np.full((*layout.segments.shape[:2], 3), 150, dtype=np.uint8),
                thickness=3.0,
                thickness_units="screen",
            )
        points = None
        all_points = [p for p in layout.edge_points if len(p)]
        if all_points:
            pts = np.concatenate(all_points, axis=0) + np.array([0, 0, 0.2 * radius])
            points = sc.add_point_cloud(
                "/graph/belief",
                points=pts.astype(np.float32),
                colors=np.full((len(pts), 3), 150, dtype=np.uint8),
                point_size=0.5 * radius,
                point_shape="circle",
                precision="float32",
            )
        robot = sc.add_icosphere(
            "/graph/robot",
            radius=1.9 * radius,
            color=(20, 20, 20),
            wireframe=True,
            subdivisions=1,
            visible=False,
        )
        robot_label = sc.add_label(
            "/graph/robot_label",
            "robot",
            anchor="center-right",
            visible=False,
            font_screen_scale=0.9,
        )
        target = sc.add_icosphere(
            "/graph/target",
            radius=0.7 * radius,
            color=(22, 163, 74),
            visible=False,
            subdivisions=1,
        )
        server.initial_camera.position = eye
        server.initial_camera.look_at = look
        for client in server.get_clients().values():
            client.camera.position = eye
            client.camera.look_at = look
        return _Scene(
            key, layout, places, labels, edges, points, robot, robot_label, target, radius, right
        )


# --- text and plot data ----------------------------------------------------------------------


def _status_text(snap: Snapshot) -> str:
    if snap.robot is None:
        return "No robot registered yet: `POST /robots` (admin token) registers one."
    lines = [f"**{snap.robot}** is **{snap.mode}**"]
    if snap.tour_name is not None:
        lines[0] += f" - tour *{snap.tour_name}*" + ("" if snap.bound else " (not bound)")
    task = snap.task
    if task is not None:
        text = f"Task {task.id} to **{task.goal}**: **{task.state}** after {task.steps} steps"
        if task.reason:
            text += f" ({task.reason})"
        lines.append(text)
    elif snap.mode == "idle":
        lines.append("No task. Pick a goal and press **Go**.")
    step = snap.step
    if step is not None:
        lines.append(f"Last frame t = {step.timestamp:.1f} s, step {step.step_ms:.0f} ms")
    return "\n\n".join(lines)


def _teaching_text(snap: Snapshot) -> str:
    t = snap.teaching
    if t is None:
        robot = snap.robot or "{robot}"
        return f"Not teaching. Start from the robot: `POST /robots/{robot}/teach/start`."
    at = f"at **{t.current_location}**" if t.current_location else "no place marked yet"
    return (
        f"Teaching *{t.tour_name}*: {at}; **{t.open_path_images}** images on the open path; "
        f"{t.locations} places and {t.edges} paths so far."
    )


def _action_text(step: StepView, graph: TourGraph) -> str:
    where = ""
    if step.action_edge is not None and 0 <= step.action_edge < graph.n_edges:
        where = f" on {graph.state_name(graph.n_locations + step.action_edge)}"
    top = ", ".join(f"{graph.state_name(s)} {p:.2f}" for s, p in step.top_states[:3])
    loc = "yes" if step.localised else "no"
    why = f"Why: {step.reason}\n\n" if step.reason else ""
    return (
        f"**Action: {step.action}**{where} ({step.behaviour}) - v {step.v:.2f} m/s, "
        f"w {step.w:.2f} rad/s\n\n{why}"
        f"Top states: {top}\n\n"
        f"Entropy **{step.entropy:.2f}** nats - localised: {loc}\n\n"
        f"{_appearance_text(step)}"
    )


#: names of the engine's appearance models, in TourIndex.model_weights() order
APPEARANCE_MODELS = ("as taught", "changed light")


def _appearance_text(step: StepView) -> str:
    """Which appearance model the belief trusts, and each model's signature block weights."""
    blocks = ("hist", "thumb", "desc_mean", "desc_var", "patch")
    parts = []
    for k, p in enumerate(step.appearance):
        name = APPEARANCE_MODELS[k] if k < len(APPEARANCE_MODELS) else f"model {k}"
        w = step.model_weights[k] if k < len(step.model_weights) else ()
        shown = " ".join(f"{b} {x:.2f}" for b, x in zip(blocks, w, strict=False) if x >= 0.005)
        parts.append(f"{name} **{p:.2f}**" + (f" ({shown})" if shown else ""))
    return "Appearance: " + "; ".join(parts)


def _votes_text(step: StepView, graph: TourGraph) -> str:
    if not step.votes:
        return "*no votes: no task underway*"
    rows = [f"{a:<22}{_bar(step.votes.get(a, 0.0))} {step.votes.get(a, 0.0):.2f}" for a in ACTIONS]
    return "Vote mass\n```\n" + "\n".join(rows) + "\n```"


def _along_edge_data(step: StepView, graph: TourGraph) -> tuple[str, tuple[FloatArray, ...]] | None:
    n_loc = graph.n_locations
    edge = step.active_edge
    if edge is None and graph.n_edges:
        edge = int(np.argmax(step.state_belief[n_loc:]))
    if edge is None or not 0 <= edge < len(step.along_edge) or graph.edges[edge].n_images == 0:
        return None
    b = step.along_edge[edge]
    x = np.arange(len(b), dtype=np.float64)
    # canonical order: every place's spin images, then every edge's images in edge order
    first = graph.n_images - int(graph.edge_offsets[-1]) + int(graph.edge_offsets[edge])
    sims = step.image_similarity[first : first + len(b)]
    if len(sims) != len(b):
        sims = np.zeros(len(b))
    return graph.state_name(n_loc + edge), (x, b, sims)


def _over_time_data(snap: Snapshot, graph: TourGraph) -> tuple[FloatArray, ...]:
    t = snap.history_t
    if len(t) == 0:
        return (np.zeros(1), np.zeros(1), np.zeros(1))
    h_max = math.log(max(2, graph.n_states))
    return (t - t[0], snap.history_top, snap.history_entropy / h_max)


def _camera(
    layout: GraphLayout,
) -> tuple[tuple[float, float, float], tuple[float, float, float], FloatArray]:
    """Eye, look-at and screen-right direction of a view from above and slightly behind, with
    the graph's long side running up the screen (the 3D view is tall and narrow)."""
    c, e = layout.center, layout.extent
    xy = np.concatenate([layout.places[:, :2], *[p[:, :2] for p in layout.edge_points]])
    span = np.ptp(xy, axis=0) if len(xy) else np.ones(2)
    back, up = 0.3 * e, 0.95 * e + 0.3
    if span[0] >= span[1]:  # looking along +x: screen right is -y
        eye = (float(c[0] - back), float(c[1]), float(up))
        right = np.array([0.0, -1.0, 0.0])
    else:  # looking along +y: screen right is +x
        eye = (float(c[0]), float(c[1] - back), float(up))
        right = np.array([1.0, 0.0, 0.0])
    return eye, (float(c[0]), float(c[1]), 0.0), right


def _image_position(layout: GraphLayout, graph: TourGraph, image: int) -> FloatArray | None:
    """Position of canonical image ``image`` (a place's spin image sits on its place)."""
    state = int(graph.image_state[image])
    if state < graph.n_locations:
        return np.asarray(layout.places[state], dtype=np.float64)
    fine = int(graph.image_fine[image])
    return _fine_position(layout, graph, fine)


def _fine_position(layout: GraphLayout, graph: TourGraph, fine: int) -> FloatArray | None:
    n_loc = graph.n_locations
    if fine < n_loc:
        return np.asarray(layout.places[fine], dtype=np.float64)
    flat = fine - n_loc
    edge = int(np.searchsorted(graph.edge_offsets, flat, side="right")) - 1
    if not 0 <= edge < graph.n_edges:
        return None
    k = flat - int(graph.edge_offsets[edge])
    pts = layout.edge_points[edge]
    return None if k >= len(pts) else np.asarray(pts[k], dtype=np.float64)
