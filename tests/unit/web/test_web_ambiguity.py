"""The dashboard's view of ambiguity: colours by entropy, the texts, a tour with taught poses
drawn where it was taught."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from server.domain import Edge, Location, TourGraph
from web.ambiguity import (
    AMBIGUOUS,
    DISTINCT,
    distinctiveness_text,
    edge_entropy,
    entropy_colors,
    place_entropy,
    step_lines,
)


def _graph() -> TourGraph:
    e = Edge(0, 1, (3, 4, 5), np.arange(3.0), np.full(3, 0.3), np.zeros(3))
    return TourGraph((Location("bedroom", (1,)), Location("guest room", (2,))), (e,))


def test_colours_run_from_green_to_red_and_grey_when_unknown() -> None:
    c = entropy_colors([0.0, math.log(3), 10.0, np.nan])
    assert c[0].tolist() == DISTINCT.astype(int).tolist()
    assert c[1].tolist() == c[2].tolist() == AMBIGUOUS.astype(int).tolist()
    assert c[3].tolist() == [150, 150, 150]


def test_entropies_per_edge_and_place_and_the_texts() -> None:
    g = _graph()
    assert all(np.isnan(h).all() for h in edge_entropy(g))
    assert "not computed" in distinctiveness_text(g)
    g = dataclasses.replace(g, image_entropy=np.array([0.7, 0.6, 0.1, 0.2, 0.3]))
    np.testing.assert_allclose(edge_entropy(g)[0], [0.1, 0.2, 0.3])
    np.testing.assert_allclose(place_entropy(g), [0.7, 0.6])
    assert "bedroom 0.70, guest room 0.60" in distinctiveness_text(g)
    assert step_lines(g) == ""  # no taught path tracked


def test_a_tour_with_taught_poses_is_drawn_where_it_was_taught() -> None:
    from server.layout import graph_layout
    from web.imagery import top_down

    g = _graph()
    poses = np.array(
        [[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [0.5, 0.0, 0.0], [1.5, 0.0, 0.0], [2.5, 0.0, 0.0]]
    )
    g = dataclasses.replace(g, image_pose=poses, image_entropy=np.zeros(5))
    layout = graph_layout(g)
    assert layout.odometry
    np.testing.assert_allclose(layout.places[:, :2], [[0.0, 0.0], [3.0, 0.0]])
    np.testing.assert_allclose(layout.edge_points[0][:, :2], poses[2:, :2])
    drawn = top_down(g, layout, size=(200, 120))
    assert drawn.shape == (120, 200, 3) and drawn.dtype == np.uint8
