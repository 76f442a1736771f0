"""Camera imagery of the dashboard: belief colours, decoded frames, captioned tiles side by
side, the strip of a task's behaviours, and the top-down map of the taught paths.

Pure drawing (NumPy and OpenCV) on RGB ``(h, w, 3)`` uint8 images; no viser.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from server.domain import TourGraph
    from server.layout import GraphLayout
    from server.session import Segment

FloatArray = npt.NDArray[np.float64]
ImageArray = npt.NDArray[np.uint8]

PANEL_IMAGE_HEIGHT = 200
"""Height (px) each image is scaled to in the side-by-side camera / best match view."""


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


MAP_SIZE = (460, 300)
"""Width and height (px) of the top-down map."""
_MAP_BG = (250, 250, 252)
_PATH_GREY = (170, 178, 190)
_ROBOT = (220, 38, 38)
_TRAIL = (244, 114, 182)
_GOAL = (22, 163, 74)
_TEXT = (40, 44, 52)


class MapFrame:
    """How layout coordinates map to the pixels of a top-down map of ``size`` (x right, y up;
    the drawing's aspect kept, a margin for the labels)."""

    def __init__(self, layout: GraphLayout, size: tuple[int, int], margin: int = 26) -> None:
        xy = np.concatenate([layout.places[:, :2], *[p[:, :2] for p in layout.edge_points]])
        lo = xy.min(axis=0) if len(xy) else np.zeros(2)
        hi = xy.max(axis=0) if len(xy) else np.ones(2)
        span = np.maximum(hi - lo, 1e-6)
        w, h = size
        self.scale = float(min((w - 2 * margin) / span[0], (h - 2 * margin) / span[1]))
        self.offset = np.array([w, h]) / 2 - self.scale * (lo + hi) / 2 * np.array([1, -1])
        self.size = size

    def px(self, xy: npt.ArrayLike) -> npt.NDArray[np.int32]:
        """``(..., 2)`` pixel coordinates of layout points ``(..., 2+)``."""
        p = np.asarray(xy, dtype=np.float64)[..., :2] * np.array([1.0, -1.0])
        return np.round(p * self.scale + self.offset).astype(np.int32)


def top_down(
    graph: TourGraph,
    layout: GraphLayout,
    *,
    states: npt.ArrayLike | None = None,
    position: npt.ArrayLike | None = None,
    trail: npt.ArrayLike | None = None,
    goal: str | None = None,
    size: tuple[int, int] = MAP_SIZE,
    tracked: Tracked | None = None,
) -> ImageArray:
    """The taught paths seen from above (layout metres), each place named, paths and places
    coloured by their belief ``states`` (``(n_states,)`` b(s), optional), the robot's most
    likely ``position`` (a layout point) as a red dot, the ``trail`` of earlier positions
    (``(k, 2+)``) as a line, and the ``goal`` place ringed in green. ``tracked``: the path
    being tracked (topometric repeat), drawn thick, and the robot on it where the tracker puts
    it, with a circle of its lateral uncertainty (teal while locked, amber while not)."""
    w, h = size
    img = np.full((h, w, 3), _MAP_BG, dtype=np.uint8)
    if graph.n_locations == 0:
        cv2.putText(img, "no places taught yet", (10, h // 2), 0, 0.5, _TEXT, 1, cv2.LINE_AA)
        return img
    frame = MapFrame(layout, size)
    b = None if states is None else np.asarray(states, dtype=np.float64)
    colours = None if b is None or len(b) != graph.n_states else belief_colors(b)
    for j, e in enumerate(graph.edges):
        pts = [layout.places[e.source], *layout.edge_points[j], layout.places[e.target]]
        colour = (
            _PATH_GREY if colours is None else tuple(int(c) for c in colours[graph.n_locations + j])
        )
        cv2.polylines(img, [frame.px(np.asarray(pts))], False, colour, 2, cv2.LINE_AA)
    if tracked is not None:
        j = tracked.edge
        pts = [layout.places[graph.edges[j].source], *layout.edge_points[j]]
        pts.append(layout.places[graph.edges[j].target])
        cv2.polylines(img, [frame.px(np.asarray(pts))], False, _TRACKED, 5, cv2.LINE_AA)
    if trail is not None and len(np.asarray(trail)) > 1:
        cv2.polylines(img, [frame.px(np.asarray(trail))], False, _TRAIL, 2, cv2.LINE_AA)
    radius = 6
    for k, loc in enumerate(graph.locations):
        c = frame.px(layout.places[k])
        colour = (96, 108, 128) if colours is None else tuple(int(x) for x in colours[k])
        cv2.circle(img, (int(c[0]), int(c[1])), radius, colour, -1, cv2.LINE_AA)
        if loc.name == goal:
            cv2.circle(img, (int(c[0]), int(c[1])), radius + 4, _GOAL, 2, cv2.LINE_AA)
        _label(img, loc.name, (int(c[0]), int(c[1]) + radius + 13))
    if position is not None:
        c = frame.px(np.asarray(position))
        cv2.circle(img, (int(c[0]), int(c[1])), radius + 2, (255, 255, 255), -1, cv2.LINE_AA)
        cv2.circle(img, (int(c[0]), int(c[1])), radius, _ROBOT, -1, cv2.LINE_AA)
    if tracked is not None and tracked.position is not None:
        colour = _TRACKED if tracked.locked else _UNSURE
        c = frame.px(np.asarray(tracked.position))
        ring = int(np.clip(round(2 * tracked.sigma_m * frame.scale), 4, img.shape[0] // 2))
        cv2.circle(img, (int(c[0]), int(c[1])), ring, colour, 2, cv2.LINE_AA)
        cv2.circle(img, (int(c[0]), int(c[1])), 3, colour, -1, cv2.LINE_AA)
    return img


_TRACKED = (13, 148, 136)
_UNSURE = (217, 119, 6)


@dataclass(frozen=True)
class Tracked:
    """The path tracker on the map: the ``edge`` tracked, the robot's layout ``position``
    there (``None``: not drawable), its lateral standard deviation ``sigma_m`` (metres) and
    whether the tracker is ``locked``."""

    edge: int
    position: npt.ArrayLike | None
    sigma_m: float
    locked: bool


def _label(img: ImageArray, text: str, centre: tuple[int, int]) -> None:
    """``text`` centred on ``centre`` (kept inside the image) on a light backing."""
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.4
    (tw, th), _ = cv2.getTextSize(text, font, scale, 1)
    h, w = img.shape[:2]
    x = int(np.clip(centre[0] - tw // 2, 2, max(2, w - tw - 2)))
    y = int(np.clip(centre[1], th + 2, h - 3))
    cv2.rectangle(img, (x - 2, y - th - 2), (x + tw + 2, y + 3), (255, 255, 255), -1)
    cv2.putText(img, text, (x, y), font, scale, _TEXT, 1, cv2.LINE_AA)
