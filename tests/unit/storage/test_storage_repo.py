"""Storage on temporary databases: migrations, pragmas, constraints, transactions, the graph."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest
from conftest import make_jpeg
from hypothesis import given, settings
from hypothesis import strategies as st

from server.errors import NotFound
from server.storage.migrations import MIGRATIONS, current_version, migrate
from server.storage.repo import Repo


@pytest.fixture()
def repo(tmp_path: Path) -> Repo:
    return Repo(tmp_path / "t.sqlite")


def add(repo: Repo, tour_id: int, **owner: object) -> int:
    return repo.add_image(
        tour_id=tour_id,
        jpeg=make_jpeg(),
        width=64,
        height=48,
        timestamp=1.0,
        v=0.2,
        w=0.0,
        **owner,  # type: ignore[arg-type]
    )


def test_fresh_file_is_migrated_in_wal_mode_with_foreign_keys(repo: Repo) -> None:
    assert repo.schema_version == MIGRATIONS[-1][0]
    assert repo.db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert repo.db.execute("PRAGMA foreign_keys").fetchone()[0] == 1
    assert {"tours", "locations", "edges", "images", "robots", "teaching"} <= set(
        repo.db.table_names()
    )


def test_migrating_twice_changes_nothing(tmp_path: Path) -> None:
    Repo(tmp_path / "t.sqlite").close()
    again = Repo(tmp_path / "t.sqlite")
    assert current_version(again.db) == MIGRATIONS[-1][0]
    assert migrate(again.db) == MIGRATIONS[-1][0]
    rows = again.db.execute("SELECT COUNT(*) FROM schema_migrations").fetchone()[0]
    assert rows == len(MIGRATIONS)


def test_foreign_keys_are_enforced(repo: Repo) -> None:
    with pytest.raises(sqlite3.IntegrityError), repo.transaction():
        repo.add_location(999, "nowhere")


def test_an_image_has_exactly_one_owner(repo: Repo) -> None:
    tour = repo.add_tour("t")
    with pytest.raises(sqlite3.IntegrityError), repo.transaction():
        repo.db.execute(
            "INSERT INTO images (tour_id, seq, timestamp, v, w, width, height, jpeg) "
            "VALUES (?, 0, 0, 0, 0, 1, 1, x'00')",
            (tour.id,),
        )


def test_a_failed_transaction_leaves_nothing(repo: Repo) -> None:
    with pytest.raises(RuntimeError), repo.transaction():
        repo.add_tour("half")
        raise RuntimeError("boom")
    assert repo.tour_by_name("half") is None


def test_nested_transactions_join_the_outer_one(repo: Repo) -> None:
    with pytest.raises(RuntimeError), repo.transaction():
        with repo.transaction():
            repo.add_tour("inner")
        raise RuntimeError("boom")
    assert repo.tours() == []


def test_a_snapshot_reads_a_read_only_file_and_refuses_writes_inside(repo: Repo) -> None:
    tour = repo.add_tour("kept")
    repo.db.conn.execute("PRAGMA query_only = ON")  # as a read-only file would behave
    with pytest.raises(sqlite3.OperationalError):
        repo.db.conn.execute("BEGIN IMMEDIATE")  # what a write transaction needs
    with repo.snapshot():
        assert repo.tour(tour.id).name == "kept"
        with repo.snapshot():  # nesting joins
            assert [t.name for t, *_ in repo.tours()] == ["kept"]
        with pytest.raises(RuntimeError, match="read snapshot"), repo.transaction():
            pass
    assert not repo.db.conn.in_transaction
    repo.db.conn.execute("PRAGMA query_only = OFF")
    with repo.snapshot(), pytest.raises(RuntimeError, match="read snapshot"):
        repo.add_tour("written while reading")  # refused even where the file is writable
    assert repo.tour_by_name("written while reading") is None
    with repo.transaction(), repo.snapshot():  # a snapshot inside a transaction joins it
        repo.add_tour("joined")
    assert repo.tour_by_name("joined") is not None


def test_not_found_errors_say_what_to_do(repo: Repo) -> None:
    with pytest.raises(NotFound, match="GET /tours"):
        repo.tour(5)
    with pytest.raises(NotFound, match="register"):
        repo.robot("ghost")


def test_graph_keeps_order_and_owners(repo: Repo) -> None:
    repo.add_robot("r", "hash")
    tour = repo.add_tour("t")
    with repo.transaction():
        a = repo.add_location(tour.id, "a")
        b = repo.add_location(tour.id, "b")
        spin = add(repo, tour.id, location_id=a)
        pending = [add(repo, tour.id, pending_robot="r") for _ in range(3)]
        edge = repo.add_edge(tour.id, a, b)
        assert repo.move_pending_to_edge("r", edge) == 3
    graph = repo.graph(tour.id)
    assert [loc.name for loc in graph.locations] == ["a", "b"]
    assert graph.locations[0].image_ids == (spin,)
    assert graph.edges[0].image_ids == tuple(pending)
    assert (graph.edges[0].source, graph.edges[0].target) == (0, 1)
    assert graph.n_fine == 2 + 3
    np.testing.assert_array_equal(graph.image_ids, [spin, *pending])
    assert repo.short_edges() == []
    assert repo.pending_count("r") == 0


def test_features_round_trip(repo: Repo) -> None:
    tour = repo.add_tour("t")
    with repo.transaction():
        loc = repo.add_location(tour.id, "a")
        image = add(repo, tour.id, location_id=loc)
    assert repo.features([image]) == {image: None}
    repo.set_features([(image, b"\x01\x02")])
    assert repo.features([image]) == {image: b"\x01\x02"}


@settings(max_examples=25, deadline=None)
@given(name=st.text(min_size=1, max_size=100))
def test_any_tour_name_round_trips(name: str) -> None:
    repo = Repo(":memory:")
    with repo.transaction():
        row = repo.add_tour(name)
    assert repo.tour(row.id).name == name
    assert repo.tour_by_name(name) == row
