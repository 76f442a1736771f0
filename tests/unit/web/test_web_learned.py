"""The dashboard's list of a tour's learned changes (docs/learning.md)."""

from __future__ import annotations

import numpy as np

from server.schemas import LearnedChange
from web.panels import learned_text


def test_learned_changes_are_listed_newest_first_as_inert_text() -> None:
    assert "learned nothing" in learned_text(())
    changes = [
        LearnedChange(
            id=k,
            tour=1,
            kind=kind,
            created_at=1.7e9 + k,
            source=f"robot <b>rover</b>, task {k}",
            summary=f"{k} images",
            images=k,
        )
        for k, kind in ((1, "experience"), (2, "transitions"))
    ]
    text = learned_text(changes)
    assert text.index("#2 transitions") < text.index("#1 experience")
    assert "<b>" not in text and "task 1" in text


def test_junctions_are_listed_and_drawn_unnamed() -> None:
    from server.belief.junctions import Junction, refine
    from server.domain import Edge, Location, TourGraph
    from web.scene import place_label

    junction = LearnedChange(
        id=3,
        tour=1,
        kind="junction",
        created_at=1.7e9,
        source="junction search of the taught paths at 2026-01-01T00:00:00Z",
        summary="hall -> office and hall -> kitchen share their first 20 / 22 images",
        images=0,
    )
    assert "#3 junction" in learned_text([junction])

    def edge(s: int, t: int, ids: range) -> Edge:
        n = len(ids)
        return Edge(s, t, tuple(ids), np.arange(n) * 0.5, np.full(n, 0.25), np.zeros(n))

    graph = TourGraph(
        (Location("hall", (1,), 1), Location("office", (2,), 2), Location("kitchen", (3,), 3)),
        (edge(0, 1, range(10, 30)), edge(0, 2, range(40, 60))),
    )
    refined = refine(graph, [Junction(10, 40, 8, 8, tuple(range(8)))]).graph
    labels = [place_label(loc) for loc in refined.locations]
    assert labels[:3] == ["hall", "office", "kitchen"] and labels[3] == "\u25c7"
