"""The dashboard's list of a tour's learned changes (docs/learning.md)."""

from __future__ import annotations

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
