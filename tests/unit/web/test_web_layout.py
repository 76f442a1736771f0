"""The dashboard's pure helpers: graph layout from odometry, colours, images, error texts."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from server import schemas
from server.domain import Edge, Location, TourGraph
from server.errors import Conflict
from server.imaging import encode_jpeg
from server.layout import graph_layout, has_odometry, integrate_edge
from web.imagery import belief_colors, decode_rgb, side_by_side
from web.panels import error_text


def edge(source: int, target: int, n: int, *, v: float = 0.5, w: float = 0.0) -> Edge:
    t = np.arange(n, dtype=np.float64) * 0.1
    return Edge(
        source=source,
        target=target,
        image_ids=tuple(
            range(100 * (source + 1) + 10 * target, 100 * (source + 1) + 10 * target + n)
        ),
        timestamps=t,
        v=np.full(n, v),
        w=np.full(n, w),
    )


def places(*names: str) -> tuple[Location, ...]:
    return tuple(Location(name, (k,)) for k, name in enumerate(names))


def test_straight_edge_integrates_to_its_length() -> None:
    poses = integrate_edge(edge(0, 1, 11, v=0.5))
    # 11 images 0.1 s apart plus one interval at each end: 12 intervals of 0.05 m
    assert poses.shape == (13, 3)
    np.testing.assert_allclose(poses[-1], [0.6, 0.0, 0.0], atol=1e-9)
    assert np.all(np.diff(poses[:, 0]) > 0)


def test_turning_edge_bends_left() -> None:
    # 33 images 0.1 s apart: a half turn over 3.2 s, then the place straight on
    poses = integrate_edge(edge(0, 1, 33, v=0.5, w=math.pi / 3.2))
    assert abs(poses[-2, 2]) == pytest.approx(math.pi)
    assert abs(poses[-1, 2]) == pytest.approx(math.pi)
    assert poses[-1, 1] > 0.3  # counter-clockwise: ends up on the left
    assert abs(poses[-1, 0]) < 0.1


def test_odometry_layout_chains_edges_from_the_first_place() -> None:
    graph = TourGraph(places("a", "b", "c"), (edge(0, 1, 10), edge(1, 2, 20)))
    layout = graph_layout(graph)
    assert layout.odometry
    np.testing.assert_allclose(layout.places[0], [0, 0, 0], atol=1e-6)
    np.testing.assert_allclose(layout.places[1], [0.55, 0, 0], atol=1e-5)
    np.testing.assert_allclose(layout.places[2], [0.55 + 1.05, 0, 0], atol=1e-5)
    assert [len(p) for p in layout.edge_points] == [10, 20]
    # the images lie between their places, in order
    xs = layout.edge_points[1][:, 0]
    assert np.all(np.diff(xs) > 0) and xs[0] > 0.55 and xs[-1] < 1.6
    assert len(layout.segments) == len(layout.segment_edge) == 11 + 21


def test_reverse_edge_is_fitted_between_known_places_and_bows_to_its_right() -> None:
    graph = TourGraph(places("a", "b"), (edge(0, 1, 10), edge(1, 0, 10)))
    layout = graph_layout(graph)
    back = layout.edge_points[1]
    # taught going back: fitted from b to a (its own heading is unknown), offset to one side
    assert back[0, 0] > back[-1, 0]
    forth = layout.edge_points[0]
    assert np.all(forth[1:-1, 1] < 0) and np.all(back[1:-1, 1] > 0)


def test_without_odometry_the_fallback_layout_is_stable() -> None:
    edges = (edge(0, 1, 5, v=0.0), edge(1, 2, 5, v=0.0), edge(2, 3, 5, v=0.0))
    graph = TourGraph(places("a", "b", "c", "d"), edges)
    assert not any(has_odometry(e) for e in edges)
    one, two = graph_layout(graph), graph_layout(graph)
    assert not one.odometry
    np.testing.assert_array_equal(one.places, two.places)
    assert len({tuple(p) for p in one.places.round(3).tolist()}) == 4  # no two places coincide
    assert all(len(p) == 5 for p in one.edge_points)


def test_a_graph_without_edges_or_places_still_lays_out() -> None:
    assert graph_layout(TourGraph(places("only"))).places.shape == (1, 3)
    assert graph_layout(TourGraph(())).segments.shape == (0, 2, 3)


def test_belief_colours_go_from_slate_to_red() -> None:
    c = belief_colors([0.0, 0.25, 1.0])
    assert c.dtype == np.uint8 and c.shape == (3, 3)
    assert tuple(c[0]) == (96, 108, 128) and tuple(c[2]) == (220, 38, 38)


def test_side_by_side_decodes_and_scales_both_images() -> None:
    rng = np.random.default_rng(0)
    a = decode_rgb(encode_jpeg(rng.integers(0, 255, (120, 160, 3), dtype=np.uint8)))
    assert a is not None and a.shape == (120, 160, 3)
    assert decode_rgb(b"not a jpeg") is None
    out = side_by_side(a, None, ("camera", "best match"), height=240)
    assert out.shape[0] == 240 + 26 and out.shape[1] > 2 * 300
    assert out.dtype == np.uint8


def test_error_text_shows_domain_and_validation_messages() -> None:
    assert error_text(Conflict("nothing to stop")) == "nothing to stop"
    with pytest.raises(ValidationError) as info:
        schemas.LocationMark(name="   ")
    text = error_text(info.value)
    assert text.startswith("invalid input - name:") and "white space" in text


def test_the_view_fits_the_whole_graph_on_a_narrow_canvas() -> None:
    import math

    from web.scene import MARGIN, fit_view

    graph = TourGraph(places("a", "b", "c"), (edge(0, 1, 40), edge(1, 2, 40, w=0.4)))
    layout = graph_layout(graph)
    fov = math.radians(75)
    for aspect in (0.25, 1.0, 2.0):
        view = fit_view(layout, aspect=aspect, fov=fov)
        height = view.eye[2]
        xy = np.concatenate([layout.places[:, :2], *[p[:, :2] for p in layout.edge_points]])
        rel = xy - np.asarray(view.look[:2])
        across = np.abs(rel @ view.right[:2]).max()
        along = np.abs(rel @ view.down[:2]).max()
        # every point within the canvas, seen from the camera's height (nearly from above)
        assert across <= height * math.tan(fov / 2) * aspect
        assert along <= height * math.tan(fov / 2) * (1 + 0.5 * (MARGIN - 1))
    assert fit_view(layout, aspect=0.25).eye[2] > fit_view(layout, aspect=2.0).eye[2]


def test_the_top_down_map_draws_places_paths_and_the_robot() -> None:
    from web.imagery import top_down

    graph = TourGraph(places("a", "b"), (edge(0, 1, 10),))
    layout = graph_layout(graph)
    plain = top_down(graph, layout, size=(200, 120))
    assert plain.shape == (120, 200, 3)
    mid = layout.edge_points[0][5]
    shown = top_down(graph, layout, position=mid, goal="b", size=(200, 120))
    red = (shown == (220, 38, 38)).all(axis=2)
    green = (shown == (22, 163, 74)).all(axis=2)
    assert red.any() and green.any() and not (plain == (220, 38, 38)).all(axis=2).any()
    _, xs = np.nonzero(red)
    assert 60 < xs.mean() < 140  # halfway between the two places
