"""Storage on temporary databases: migrations, pragmas, constraints, transactions, the graph.

The storage contract: every test taking ``repo`` or ``store`` runs on a new SQLite file and on
a new PostgreSQL database (tests/conftest.py; skipped, saying why, where no PostgreSQL server
can be started).
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import make_jpeg
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from server.errors import IntegrityViolation, NotFound, Unavailable
from server.storage.database import open_database
from server.storage.migrations import MIGRATIONS, current_version, migrate
from server.storage.repo import FrameRow, Repo


@pytest.fixture()
def repo(store: Path | str) -> Iterator[Repo]:
    repo = Repo(store)
    yield repo
    repo.close()


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


def test_fresh_file_is_migrated_in_wal_mode_with_foreign_keys(tmp_path: Path) -> None:
    repo = Repo(tmp_path / "t.sqlite")
    assert repo.db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert repo.db.execute("PRAGMA foreign_keys").fetchone()[0] == 1


def test_a_fresh_database_is_migrated(repo: Repo) -> None:
    assert repo.schema_version == MIGRATIONS[-1][0]
    assert {"tours", "locations", "edges", "images", "robots", "teaching"} <= set(
        repo.db.table_names()
    )


def test_both_databases_get_the_same_tables_and_columns(tmp_path: Path, postgres_url: str) -> None:
    """Migrations from empty to the newest give PostgreSQL what they give SQLite."""
    schemas = []
    for target in (tmp_path / "t.sqlite", postgres_url):
        repo = Repo(target)
        schemas.append({t: sorted(repo.db.columns(t)) for t in repo.db.table_names()})
        repo.close()
    assert schemas[0] == schemas[1]
    assert len(schemas[0]) >= 12 and all(schemas[0].values())


def test_migrating_twice_changes_nothing(store: Path | str) -> None:
    Repo(store).close()
    again = Repo(store)
    assert current_version(again.db) == MIGRATIONS[-1][0]
    assert migrate(again.db) == MIGRATIONS[-1][0]
    rows = again.db.execute("SELECT COUNT(*) FROM schema_migrations").fetchone()[0]
    assert rows == len(MIGRATIONS)


def test_foreign_keys_are_enforced(repo: Repo) -> None:
    with pytest.raises(IntegrityViolation), repo.transaction():
        repo.add_location(999, "nowhere")


def test_an_image_has_exactly_one_owner(repo: Repo) -> None:
    tour = repo.add_tour("t")
    with pytest.raises(IntegrityViolation), repo.transaction():
        repo.db.execute(
            "INSERT INTO images (tour_id, seq, timestamp, v, w, width, height, jpeg) "
            "VALUES (?, 0, 0, 0, 0, 1, 1, ?)",
            (tour.id, b"\x00"),
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


def _read_only(repo: Repo, on: bool) -> None:
    """Make the database refuse writes, as a read-only file (SQLite) or a standby server
    (PostgreSQL) would."""
    if repo.db.dialect == "sqlite":
        repo.db.execute(f"PRAGMA query_only = {'ON' if on else 'OFF'}")
    else:
        repo.db.execute(f"SET default_transaction_read_only = {'on' if on else 'off'}")


def test_a_snapshot_reads_a_read_only_file_and_refuses_writes_inside(repo: Repo) -> None:
    tour = repo.add_tour("kept")
    _read_only(repo, True)
    with pytest.raises(Unavailable, match="read-only"), repo.transaction():
        repo.add_tour("refused")
    with repo.snapshot():
        assert repo.tour(tour.id).name == "kept"
        with repo.snapshot():  # nesting joins
            assert [t.name for t, *_ in repo.tours()] == ["kept"]
        with pytest.raises(RuntimeError, match="read snapshot"), repo.transaction():
            pass
    assert not repo.db.in_transaction
    _read_only(repo, False)
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


_HOUSEHOLDS = itertools.count()


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(name=st.text(min_size=1, max_size=100))
def test_any_tour_name_round_trips(repo: Repo, name: str) -> None:
    if repo.db.dialect == "postgresql":  # PostgreSQL's text cannot hold U+0000 (docs/scale.md)
        name = name.replace("\x00", "") or "x"
    with repo.transaction():
        household = repo.add_household(f"h{next(_HOUSEHOLDS)}", None).id
        row = repo.add_tour(name, household)
    assert repo.tour(row.id).name == name
    assert repo.tour_by_name(name, household) == row


def _old(store: Path | str, version: int) -> Any:
    """A database at schema ``version`` (SQLite or PostgreSQL), to fill and upgrade."""
    db = open_database(store)
    assert migrate(db, upto=version) == version
    return db


def _images(x: Any, columns: str = "", values: str = "") -> None:
    """One spin image, two path images and one on the rover's open path, in tour 7."""
    jpeg = make_jpeg()
    for k, owner in enumerate(("location_id", "edge_id", "edge_id", "pending_robot")):
        value = {"location_id": 1, "edge_id": 1, "pending_robot": "rover"}[owner]
        x(
            f"INSERT INTO images (tour_id, {owner}, seq, timestamp, v, w, width, height, jpeg"
            f"{columns}) VALUES (7, ?, ?, ?, 0.2, 0.0, 64, 48, ?{values})",
            (value, k, float(k), jpeg),
        )


def _references_hold(repo: Repo) -> None:
    if repo.db.dialect == "sqlite":
        assert repo.db.execute("PRAGMA foreign_keys").fetchone()[0] == 1
        assert repo.db.execute("PRAGMA foreign_key_check").fetchall() == []
    assert repo.integrity_ok()
    with pytest.raises(IntegrityViolation), repo.transaction():
        repo.db.execute("DELETE FROM locations WHERE id = 1")


def test_a_database_from_before_households_upgrades_losing_nothing(store: Path | str) -> None:
    """Schema 2 (no households) -> newest: every robot, tour, place, edge, image, teaching and
    navigation row is kept, all of it in household 1, and every reference still holds."""
    db = _old(store, 2)
    x = db.execute
    x(
        "INSERT INTO robots (name, token_hash, created_at) "
        "VALUES ('rover', 'hash-rover', 1.0), ('mop', 'hash-mop', 2.0)"
    )
    x(
        "INSERT INTO tours (id, name, created_at, weights, weights_images) "
        "VALUES (7, 'home', 3.0, ?, 4)",
        (b"\x00",),
    )
    x(
        "INSERT INTO locations (id, tour_id, name, created_at) "
        "VALUES (1, 7, 'hall', 4.0), (2, 7, 'kitchen', 5.0)"
    )
    x("INSERT INTO edges (id, tour_id, source_id, target_id, created_at) VALUES (1, 7, 1, 2, 6.0)")
    _images(x)
    x(
        "INSERT INTO teaching (robot, tour_id, current_location_id, last_timestamp, started_at) "
        "VALUES ('rover', 7, 2, 3.0, 1.0)"
    )
    x(
        "INSERT INTO navigation (robot, tour_id, task_id, goal_location_id, state, started_at) "
        "VALUES ('mop', 7, 1, 2, 'underway', 1.0)"
    )
    before = _rows(db, ("locations", "edges", "images", "teaching", "navigation"))
    db.close()

    repo = Repo(store)
    try:
        assert repo.schema_version == MIGRATIONS[-1][0]
        assert _rows(repo.db, before) == before  # later migrations only add columns
        assert [(t.id, t.name, t.household_id) for t, *_ in repo.tours()] == [(7, "home", 1)]
        assert repo.tours(1)[0][1:] == (2, 1, 3)  # places, edges, stored images
        assert repo.tour_weights(7) == (b"\x00", 4)
        assert [(r.name, r.household_id, r.token_active) for r in repo.robots()] == [
            ("mop", 1, True),
            ("rover", 1, True),
        ]
        assert repo.robot_by_token_hash("hash-rover") == ("rover", 1, "default")
        assert repo.household(1).name == "default" and not repo.household(1).has_login
        assert repo.image_household(1) == 1
        with repo.transaction():  # new rows get new ids after the ones kept
            assert repo.add_household("next", None).id == 2
            assert repo.add_tour("next").id == 8
        _references_hold(repo)
    finally:
        repo.close()


def _rows(db: Any, tables: tuple[str, ...] | dict[str, object]) -> dict[str, object]:
    """Every row of ``tables``: the columns they had then (a dict from an earlier call) or
    all of them."""
    out: dict[str, object] = {}
    for table in tables:
        columns = "*"
        if isinstance(tables, dict):
            columns = ", ".join(tables[table][0])  # type: ignore[index]
        cur = db.execute(f"SELECT {columns} FROM {table} ORDER BY 1")
        out[table] = ([d[0] for d in cur.description], [tuple(r) for r in cur.fetchall()])
    return out


def test_a_schema_3_database_upgrades_losing_nothing(store: Path | str) -> None:
    """Schema 3 (households) -> newest: every row of every table is kept as it was; images
    gain their pose and distinctiveness (NULL: unknown), tours the count they cover."""
    db = _old(store, 3)
    x = db.execute
    x("INSERT INTO households (id, name, password_hash, created_at) VALUES (2, 'flat', 'ah', 1.0)")
    x(
        "INSERT INTO robots (name, household_id, token_hash, token_issued_at, created_at) "
        "VALUES ('rover', 2, 'hash-rover', 1.0, 1.0)"
    )
    x(
        "INSERT INTO tours (id, household_id, name, created_at, weights, weights_images) "
        "VALUES (7, 2, 'home', 3.0, ?, 3)",
        (b"\x00\x01",),
    )
    x(
        "INSERT INTO locations (id, tour_id, name, created_at) "
        "VALUES (1, 7, 'hall', 4.0), (2, 7, 'kitchen', 5.0)"
    )
    x("INSERT INTO edges (id, tour_id, source_id, target_id, created_at) VALUES (1, 7, 1, 2, 6.0)")
    _images(lambda sql, p: x(sql, (*p, b"\x02")), ", features", ", ?")
    x(
        "INSERT INTO teaching (robot, tour_id, current_location_id, last_timestamp, started_at) "
        "VALUES ('rover', 7, 2, 3.0, 1.0)"
    )
    x(
        "INSERT INTO navigation (robot, tour_id, task_id, goal_location_id, state, started_at, "
        "belief, belief_images) VALUES ('rover', 7, 1, 2, 'underway', 1.0, ?, 3)",
        (b"\x00",),
    )
    x(
        "INSERT INTO logins (token_hash, household_id, created_at, expires_at) "
        "VALUES ('login-hash', 2, 1.0, 9.0)"
    )
    x("INSERT INTO audit (at, actor, action, target, status) VALUES (1.0, 'admin', 'a', 't', 200)")
    before = _rows(db, tuple(t for t in db.table_names() if t != "schema_migrations"))
    db.close()

    repo = Repo(store)
    try:
        assert repo.schema_version == MIGRATIONS[-1][0] >= 4
        assert _rows(repo.db, before) == before
        graph = repo.graph(7)
        assert graph.n_images == 3 and graph.image_pose is None and graph.image_entropy is None
        assert repo.entropy_images(7) is None
        assert repo.tour_weights(7) == (b"\x00\x01", 3)
        _references_hold(repo)
    finally:
        repo.close()


def test_poses_and_entropies_round_trip_in_canonical_order(repo: Repo) -> None:
    """Poses come with the images that have them (NaN rows for the others, also on the copy a
    place gets of a path's last frame), entropies once set for the whole tour; both in the
    graph's canonical order (spin images by place, then edge images)."""
    with repo.transaction():
        tour = repo.add_tour("home").id
        repo.add_robot("rover", "hash")
        hall = repo.add_location(tour, "hall")
        kitchen = repo.add_location(tour, "kitchen")
        spin = add(repo, tour, location_id=hall)
        frames = [add(repo, tour, pending_robot="rover", pose=(k, 0.0, 0.1)) for k in (1.0, 2.0)]
        copy = repo.copy_last_pending_to_location("rover", kitchen)
        repo.move_pending_to_edge("rover", repo.add_edge(tour, hall, kitchen))
    graph = repo.graph(tour)
    assert graph.image_ids.tolist() == [spin, copy, *frames]
    assert graph.image_pose is not None and np.isnan(graph.image_pose[0]).all()
    assert graph.image_pose[1:].tolist() == [[2.0, 0.0, 0.1], [1.0, 0.0, 0.1], [2.0, 0.0, 0.1]]
    assert not graph.has_poses and graph.image_entropy is None
    repo.set_entropies(tour, [(i, 0.5 * k) for k, i in enumerate(graph.image_ids.tolist())])
    graph = repo.graph(tour)
    assert graph.has_entropy and graph.image_entropy is not None
    assert graph.image_entropy.tolist() == [0.0, 0.5, 1.0, 1.5]
    assert repo.entropy_images(tour) == 4


def test_tour_names_are_unique_per_household(repo: Repo) -> None:
    with repo.transaction():
        other = repo.add_household("other", None).id
        repo.add_tour("home")
        repo.add_tour("home", other)
        with pytest.raises(IntegrityViolation):
            repo.add_tour("home", other)


def test_old_audit_entries_and_expired_logins_are_forgotten(repo: Repo) -> None:
    with repo.transaction():
        household = repo.add_household("home", None).id
        repo.add_login("old", household, expires_at=100.0)
        repo.add_login("live", household, expires_at=300.0)
    for _ in range(2):
        repo.add_audit(
            actor="admin", action="POST /households", target="/", status=201, address=None
        )
    with repo.transaction():
        repo.db.execute("UPDATE audit SET at = 50.0 WHERE id = 1")
    assert repo.forget_before(audit_before=60.0, now=200.0) == (1, 1)
    assert [e.id for e in repo.audit()] == [2]
    assert repo.login("live") is not None and repo.login("old") is None


def test_a_schema_4_database_upgrades_losing_nothing(store: Path | str) -> None:
    """Schema 4 -> newest (5: learned changes): every row kept; the tour has learned nothing."""
    db = _old(store, 4)
    x = db.execute
    x("INSERT INTO households (id, name, password_hash, created_at) VALUES (2, 'flat', 'ah', 1.0)")
    x(
        "INSERT INTO tours (id, household_id, name, created_at, weights, weights_images, "
        "entropy_images) VALUES (7, 2, 'home', 3.0, ?, 3, 1)",
        (b"\x00\x01",),
    )
    x(
        "INSERT INTO locations (id, tour_id, name, created_at) "
        "VALUES (1, 7, 'hall', 4.0), (2, 7, 'kitchen', 5.0)"
    )
    x("INSERT INTO edges (id, tour_id, source_id, target_id, created_at) VALUES (1, 7, 1, 2, 6.0)")
    x(
        "INSERT INTO images (tour_id, edge_id, seq, timestamp, v, w, width, height, jpeg, "
        "features, pose_x, pose_y, pose_theta, entropy) "
        "VALUES (7, 1, 0, 0.0, 0.2, 0.0, 64, 48, ?, ?, 1.0, 2.0, 0.5, 0.7)",
        (make_jpeg(), b"\x02"),
    )
    before = _rows(db, tuple(t for t in db.table_names() if t != "schema_migrations"))
    db.close()
    repo = Repo(store)
    try:
        assert repo.schema_version == MIGRATIONS[-1][0] >= 5
        assert _rows(repo.db, before) == before
        assert repo.learned_changes(7) == []
        assert repo.integrity_ok()
    finally:
        repo.close()


def test_learned_changes_are_listed_and_removed_with_what_they_added(repo: Repo) -> None:
    """A look-alike pair and a new path (what answers to questions make): listed oldest
    first with the images of the edge a change added; removing one takes what it added with
    it (its look-alike pair; its edge and the edge's images) and nothing else."""
    tour = repo.add_tour("home").id
    with repo.transaction():
        hall = repo.add_location(tour, "hall")
        kitchen = repo.add_location(tour, "kitchen")
    spin = add(repo, tour, location_id=hall)
    frame = FrameRow(1.0, 0.2, 0.0, 64, 48, make_jpeg(), None)
    with repo.transaction():
        alike = repo.add_learned_change(tour, "look_alike", source="q 1", summary="s", now=1.0)
        repo.add_look_alike(alike, hall, None, spin)
        edge = repo.add_edge_with_images(tour, hall, kitchen, [frame, frame])
        path = repo.add_learned_change(
            tour, "new_path", source="q 2", summary="p", now=2.0, edge_id=edge
        )
    rows = repo.learned_changes(tour)
    assert [(r.id, r.kind, r.images, r.edge_id) for r in rows] == [
        (alike, "look_alike", 0, None),
        (path, "new_path", 2, edge),
    ]
    assert repo.look_alike_images(hall) == {spin}
    with pytest.raises(ValueError, match="unknown learned change kind"):
        repo.add_learned_change(tour, "guess", source="q", summary="s", now=3.0)
    with pytest.raises(NotFound, match="no learned change"):
        repo.remove_learned_change(tour, 999)
    other = repo.add_tour("other").id
    with pytest.raises(NotFound):
        repo.remove_learned_change(other, path)
    repo.remove_learned_change(tour, path)
    assert [e.id for e in repo.edges(tour)] == [] and repo.graph(tour).n_images == 1
    repo.remove_learned_change(tour, alike)
    assert repo.learned_changes(tour) == [] and repo.look_alike_images(hall) == set()


def test_a_lost_postgresql_connection_is_opened_again(postgres_url: str) -> None:
    """The database server ends the connection (a restart): that request is answered
    Unavailable, the next one works on a new connection."""
    import psycopg

    repo = Repo(postgres_url)
    try:
        repo.add_tour("before")
        pid = repo.db.execute("SELECT pg_backend_pid()").fetchone()[0]
        with psycopg.connect(postgres_url, autocommit=True) as other:
            other.execute("SELECT pg_terminate_backend(%s)", (pid,))
        with pytest.raises(Unavailable, match="lost the connection"):
            repo.tours()
        assert [t.name for t, *_ in repo.tours()] == ["before"]
        with pytest.raises(psycopg.DataError, match="0x00"), repo.transaction():  # scale.md
            repo.add_tour("nul\x00")
    finally:
        repo.close()


def test_a_write_waits_for_another_processs_write_then_is_told_busy(store: Path | str) -> None:
    """One writer at a time over every connection: while another holds the write lock past
    the timeout, a write is answered Unavailable and leaves no transaction open."""
    holder, repo = Repo(store), Repo(store)
    try:
        if repo.db.dialect == "sqlite":
            repo.db.execute("PRAGMA busy_timeout = 200")
        else:
            repo.db.execute("SET lock_timeout = 200")
        with holder.transaction():
            holder.add_tour("held")
            with pytest.raises(Unavailable, match="busy"), repo.transaction():
                repo.add_tour("waited")
            assert not repo.db.in_transaction
        with repo.transaction():
            repo.add_tour("after")
        assert sorted(t.name for t, *_ in repo.tours()) == ["after", "held"]
    finally:
        holder.close()
        repo.close()


def test_a_schema_5_database_upgrades_to_9_losing_nothing_and_junctions_go_with_their_change(
    store: Path | str,
) -> None:
    """Schema 5 -> 9 (7: junctions; the CHECK on the change's kind goes): every learned change
    and experience kept, with their ids; a junction row goes with its change, as the
    experiences do. (Schema 10 removes both kinds, tested below.)"""
    db = _old(store, 5)
    x = db.execute
    x("INSERT INTO households (id, name, password_hash, created_at) VALUES (2, 'flat', 'ah', 1.0)")
    x("INSERT INTO tours (id, household_id, name, created_at) VALUES (7, 2, 'home', 3.0)")
    x("INSERT INTO locations (id, tour_id, name, created_at) VALUES (1, 7, 'hall', 4.0)")
    for k in (1, 2):
        x(
            "INSERT INTO images (id, tour_id, location_id, seq, timestamp, v, w, width, height, "
            "jpeg) VALUES (?, 7, 1, ?, 0.0, 0.0, 0.0, 64, 48, ?)",
            (k, k, make_jpeg(k)),
        )
    x(
        "INSERT INTO learned_changes (id, tour_id, kind, created_at, source, summary, counts) "
        "VALUES (4, 7, 'experience', 1.0, 'run', 's', NULL), "
        "(5, 7, 'transitions', 2.0, 'run', 'c', ?)",
        (b"\x00",),
    )
    x(
        "INSERT INTO experiences (id, change_id, image_id, features, created_at) "
        "VALUES (9, 4, 1, ?, 1.0)",
        (b"\x01\x02",),
    )
    before = _rows(db, ("learned_changes", "experiences", "images", "tours"))
    try:
        assert migrate(db, upto=9) == 9
        assert _rows(db, before) == before
        assert db.integrity_ok()
        made = db.insert(
            "INSERT INTO learned_changes (tour_id, kind, created_at, source, summary) "
            "VALUES (7, 'junction', 3.0, 'search', 'j')"
        )
        assert made == 6  # past the copied ids, on PostgreSQL too
        x(
            "INSERT INTO junctions (change_id, keep_image_id, other_image_id, keep_shared, "
            "other_shared, mapping) VALUES (6, 1, 2, 3, 2, ?)",
            (b"\x00" * 8,),
        )
        x("DELETE FROM learned_changes WHERE id IN (4, 6)")
        assert x("SELECT count(*) FROM experiences").fetchone()[0] == 0
        assert x("SELECT count(*) FROM junctions").fetchone()[0] == 0
    finally:
        db.close()


def test_a_schema_5_database_upgrades_to_questions_losing_nothing(store: Path | str) -> None:
    """Schema 5 -> 6 (questions; learned_changes rebuilt): every learned change and experience
    kept, experiences still cascade with their change, any kind is accepted, and new changes
    get ids past the copied ones."""
    db = _old(store, 5)
    x = db.execute
    x("INSERT INTO tours (id, household_id, name, created_at) VALUES (7, 1, 'home', 3.0)")
    x("INSERT INTO locations (id, tour_id, name, created_at) VALUES (1, 7, 'hall', 4.0)")
    x(
        "INSERT INTO images (id, tour_id, location_id, seq, timestamp, v, w, width, height, "
        "jpeg) VALUES (5, 7, 1, 0, 0.0, 0.0, 0.0, 64, 48, ?)",
        (make_jpeg(),),
    )
    x(
        "INSERT INTO learned_changes (id, tour_id, kind, created_at, source, summary, counts) "
        "VALUES (3, 7, 'experience', 9.0, 'run', 's', NULL), "
        "(4, 7, 'transitions', 9.5, 'run', 'c', ?)",
        (b"\x00",),
    )
    x(
        "INSERT INTO experiences (id, change_id, image_id, features, created_at) "
        "VALUES (11, 3, 5, ?, 9.0)",
        (b"\x01\x02",),
    )
    before = _rows(db, ("learned_changes", "experiences"))
    try:
        assert migrate(db, upto=6) == 6
        assert _rows(db, before) == before  # the columns they had, every row
        edges = x("SELECT id, edge_id FROM learned_changes ORDER BY id").fetchall()
        assert [tuple(r) for r in edges] == [(3, None), (4, None)]
        assert db.integrity_ok()
        if db.dialect == "sqlite":
            assert x("PRAGMA foreign_key_check").fetchall() == []
        x("DELETE FROM learned_changes WHERE id = 3")  # the experience goes with its change
        assert x("SELECT count(*) FROM experiences").fetchone()[0] == 0
        made = db.insert(
            "INSERT INTO learned_changes (tour_id, kind, created_at, source, summary) "
            "VALUES (7, 'look_alike', 1.0, 'q', 's')"
        )
        assert made == 5  # past the copied ids, on PostgreSQL too
    finally:
        db.close()


def test_the_stored_kinds_of_learned_change_are_the_ones_the_api_names() -> None:
    """repo.LEARNED_KINDS (checked on insert) and the wire schema's Literal are written twice,
    since the wire schemas import pydantic only: this keeps them equal."""
    from typing import get_args

    from server import schemas
    from server.storage.repo import LEARNED_KINDS

    wire = get_args(schemas.LearnedChange.model_fields["kind"].annotation)
    assert set(wire) == set(LEARNED_KINDS) and len(wire) == len(LEARNED_KINDS)


def test_a_schema_7_database_upgrades_and_navigation_rows_keep_the_trackers_memory(
    store: Path | str,
) -> None:
    """Schema 7 -> 8 (``navigation.belief_memory``): a robot's navigation row is kept as it
    was, its memory unknown (NULL: the tracker starts it afresh); a saved row returns its
    memory as written, and a row saved without one clears it."""
    db = _old(store, 7)
    x = db.execute
    x(
        "INSERT INTO robots (name, household_id, token_hash, token_issued_at, created_at) "
        "VALUES ('rover', 1, 'h', 1.0, 1.0)"
    )
    x("INSERT INTO tours (id, household_id, name, created_at) VALUES (7, 1, 'home', 3.0)")
    x("INSERT INTO locations (id, tour_id, name, created_at) VALUES (2, 7, 'hall', 4.0)")
    x(
        "INSERT INTO navigation (robot, tour_id, task_id, goal_location_id, state, started_at, "
        "belief, belief_images) VALUES ('rover', 7, 1, 2, 'underway', 1.0, ?, 3)",
        (b"\x00\x01",),
    )
    before = _rows(db, ("navigation",))
    db.close()
    repo = Repo(store)
    try:
        assert repo.schema_version == MIGRATIONS[-1][0] >= 8
        assert _rows(repo.db, before) == before
        row = repo.navigation("rover")
        assert row is not None and row.belief == b"\x00\x01" and row.belief_memory is None
        memory = '{"appearance": [-1.5, 0.0], "familiar": 0.25}'
        repo.save_navigation(dataclasses.replace(row, steps=5, belief_memory=memory))
        again = repo.navigation("rover")
        assert again is not None and (again.steps, again.belief_memory) == (5, memory)
        repo.save_navigation(dataclasses.replace(again, belief=None, belief_memory=None))
        cleared = repo.navigation("rover")
        assert cleared is not None and cleared.belief is None and cleared.belief_memory is None
    finally:
        repo.close()


def test_a_schema_9_database_keeps_the_question_kinds_and_loses_the_removed_ones(
    store: Path | str,
) -> None:
    """Schema 9 -> 10 (learned transitions, experiences and junctions removed): a tour with one
    learned change of each of the six kinds keeps its loop closure, look-alike pair and new
    path as they were (ids, edges, images, pairs, the questions that made them) and loses the
    other three with their rows; the tables ``experiences`` and ``junctions`` are gone and
    every other row of every other table is as it was."""
    db = _old(store, 9)
    x = db.execute
    x(
        "INSERT INTO robots (name, household_id, token_hash, token_issued_at, created_at) "
        "VALUES ('rover', 1, 'h', 1.0, 1.0)"
    )
    x("INSERT INTO tours (id, household_id, name, created_at) VALUES (7, 1, 'home', 2.0)")
    x(
        "INSERT INTO locations (id, tour_id, name, created_at) "
        "VALUES (1, 7, 'hall', 3.0), (2, 7, 'kitchen', 3.0)"
    )
    x(
        "INSERT INTO edges (id, tour_id, source_id, target_id, created_at) "
        "VALUES (1, 7, 1, 2, 4.0), (2, 7, 2, 1, 5.0), (3, 7, 1, 2, 6.0)"
    )
    for image, owner, value in ((1, "location_id", 1), (2, "edge_id", 1), (3, "edge_id", 1)):
        x(
            f"INSERT INTO images (id, tour_id, {owner}, seq, timestamp, v, w, width, height, "
            "jpeg, features, depth) VALUES (?, 7, ?, ?, 0.0, 0.2, 0.0, 64, 48, ?, ?, ?)",
            (image, value, image, make_jpeg(image), b"\x02", b"\x00\x00\x80\x3f"),
        )
    for image, edge in ((4, 2), (5, 3), (6, 3)):  # the edges a loop closure, a new path added
        x(
            "INSERT INTO images (id, tour_id, edge_id, seq, timestamp, v, w, width, height, "
            "jpeg) VALUES (?, 7, ?, ?, 0.0, 0.2, 0.0, 64, 48, ?)",
            (image, edge, image, make_jpeg(image)),
        )
    x(
        "INSERT INTO learned_changes (id, tour_id, kind, created_at, source, summary, counts, "
        "edge_id) VALUES "
        "(1, 7, 'transitions', 7.0, 'run', 'c', ?, NULL), "
        "(2, 7, 'experience', 7.0, 'run', 'e', NULL, NULL), "
        "(3, 7, 'junction', 8.0, 'search', 'j', NULL, NULL), "
        "(4, 7, 'loop_closure', 9.0, 'question 1', 'l', NULL, 2), "
        "(5, 7, 'look_alike', 9.5, 'question 2', 'a', NULL, NULL), "
        "(6, 7, 'new_path', 10.0, 'question 3', 'n', NULL, 3)",
        (b"\x00" * 24,),
    )
    x(
        "INSERT INTO experiences (id, change_id, image_id, features, created_at) "
        "VALUES (1, 2, 2, ?, 7.0)",
        (b"\x01",),
    )
    x(
        "INSERT INTO junctions (id, change_id, keep_image_id, other_image_id, keep_shared, "
        "other_shared, mapping) VALUES (1, 3, 2, 5, 1, 1, ?)",
        (b"\x00" * 4,),
    )
    x(
        "INSERT INTO look_alikes (id, change_id, location_id, image_id, match_image_id) "
        "VALUES (1, 5, 1, NULL, 1)"
    )
    x(
        "INSERT INTO questions (id, robot, tour_id, kind, text, location_id, "
        "source_location_id, image_id, match_image_id, confidence, created_at, expires_at, "
        "state, answered_at, change_id) VALUES "
        "(1, 'rover', 7, 'same_place', 'Are we at hall?', 1, 2, NULL, 1, 0.9, 9.0, 99.0, "
        "'yes', 9.0, 4), "
        "(2, 'rover', 7, 'same_place', 'Are we at hall?', 1, 2, NULL, 1, 0.9, 9.5, 99.0, "
        "'no', 9.5, 5), "
        "(3, 'rover', 7, 'new_path', 'Keep it?', 2, 1, NULL, NULL, 0.8, 10.0, 99.0, "
        "'yes', 10.0, 6)"
    )
    x(
        "INSERT INTO navigation (robot, tour_id, task_id, goal_location_id, state, started_at, "
        "belief, belief_images, belief_memory) "
        "VALUES ('rover', 7, 1, 2, 'arrived', 1.0, ?, 6, '{}')",
        (b"\x00\x01",),
    )
    removed = ("learned_changes", "experiences", "junctions", "schema_migrations")
    others = _rows(db, tuple(t for t in db.table_names() if t not in removed))
    changes = _rows(db, ("learned_changes",))
    db.close()

    repo = Repo(store)
    try:
        assert repo.schema_version == MIGRATIONS[-1][0] == 10
        assert not {"experiences", "junctions"} & set(repo.db.table_names())
        assert _rows(repo.db, others) == others  # nothing else changed
        columns, rows = changes["learned_changes"]  # type: ignore[misc]
        kept = {"learned_changes": (columns, [r for r in rows if r[0] in (4, 5, 6)])}
        assert _rows(repo.db, kept) == kept
        assert [(r.id, r.kind, r.images, r.edge_id) for r in repo.learned_changes(7)] == [
            (4, "loop_closure", 1, 2),
            (5, "look_alike", 0, None),
            (6, "new_path", 2, 3),
        ]
        assert repo.look_alike_images(1) == {1}
        _references_hold(repo)
        repo.remove_learned_change(7, 6)  # undo still takes the edge it added with it
        assert [e.id for e in repo.edges(7)] == [1, 2]
        assert repo.question(3) is not None and repo.question(3).change_id is None  # type: ignore[union-attr]
    finally:
        repo.close()
