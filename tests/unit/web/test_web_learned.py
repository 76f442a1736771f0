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
            source=f"question {k} to robot <b>rover</b>",
            summary=f"{k} images",
            images=k,
        )
        for k, kind in ((1, "look_alike"), (2, "new_path"))
    ]
    text = learned_text(changes)
    assert text.index("#2 new_path") < text.index("#1 look_alike")
    assert "<b>" not in text and "question 1 to robot" in text
