"""No silent loss (issue 37): a vessel whose database is deleted and made again numbers its rows
from 1 again, and every row it makes afterwards reaches the shore (the batch's ``instance`` is
part of the shore's key); a row sent again with other content is a conflict, kept whole and
shown, never dropped; the same content sent again stays a plain duplicate. Real vessel
databases, the real sync thread, the real shore over HTTP, on SQLite and PostgreSQL."""

from __future__ import annotations

import copy
import gzip
import json
import time
from pathlib import Path
from typing import Any

from sqlalchemy import text, update

from recal.model.coefficients import CoefficientSet
from recal.sim.simulate import simulate_positions
from service.fleet.batch import content_digest
from service.fleet.schema import WindowRow
from service.store.outbox import OutboxEntry
from service.store.records import CalibrationRecord
from service.store.repository import Store
from service.sync import SyncThread
from service.sync.batch import build, wire_row

UNIT = "KVH-1750-SN0037"
FAST = {"backoff_base_s": 0.05, "backoff_cap_s": 0.2, "connect_timeout_s": 2.0,
        "read_timeout_s": 5.0}  # fmt: skip
KIND_TABLES = {"session": "sessions", "window": "positions", "version": "calibrations",
               "event": "events"}  # fmt: skip


def vessel(path: Path, windows: int, seed: int) -> Store:
    """A vessel's database made afresh: a session, ``windows`` windows, an accepted version
    and an event (the outbox holds them all)."""
    store = Store(f"sqlite:///{path}")
    store.create_schema()
    sid = store.add_session(f"replay:///capture-{seed}.bin", {"rate_hz": 1000.0})
    table = simulate_positions(CoefficientSet.seed_truth(), "random", n_positions=windows,
                               seed=seed)  # fmt: skip
    ids = store.add_positions(sid, dict(table.columns))
    store.add_calibration(CalibrationRecord(trigger="auto", method="lm", accepted=True,
                                            document={"chi2_red": 1.0 + seed},
                                            positions_used=ids))  # fmt: skip
    store.add_event("start", f"service started ({seed})", {"session": sid})
    return store


def sync(store: Store, shore: Any, token: str) -> None:
    """The vessel's sync thread until its outbox is empty."""
    thread = SyncThread(store, shore.url, UNIT, token, **FAST)
    thread.start()
    try:
        deadline = time.monotonic() + 30
        while store.outbox_count():
            assert time.monotonic() < deadline, "the outbox did not drain"
            time.sleep(0.02)
    finally:
        assert thread.stop()


def sent(store: Store) -> dict[tuple[str, int], str]:
    """Every row of the vessel's database as the wire carries it, by (kind, id): its digest."""
    out = {}
    with store._tx() as s:  # every row, through the outbox's loader (what a batch carries)
        entries = [OutboxEntry(0, kind, i) for kind, table in KIND_TABLES.items()
                   for (i,) in s.execute(text(f"SELECT id FROM {table}"))]  # noqa: S608 # fmt: skip
    for (kind, ident), stored in store.outbox_rows(entries).items():
        out[(kind, ident)] = content_digest(wire_row(kind, ident, stored)["data"])
    return out


def on_shore(shore: Any, token: str, path: str, page: int = 7) -> list[dict[str, Any]]:
    """Every row of a unit's list, page by page (``after``, ``limit``)."""
    rows: list[dict[str, Any]] = []
    after = None
    while True:
        params = {"limit": page} | ({} if after is None else {"after": after})
        got = shore.get(token, f"/fleet/units/{UNIT}/{path}", **params).json()
        if not got:
            return rows
        rows += got
        after = got[-1]["version" if path == "versions" else "id"]


def test_a_rebuilt_vessel_database_loses_nothing(shore: Any, tmp_path: Path) -> None:
    """The acceptance: a vessel synced, its database deleted and made again, then synced again:
    every row made afterwards is on shore with its content, beside the first database's."""
    token = shore.store.add_unit(UNIT, "KVH-1750")
    path = tmp_path / "vessel.db"
    first = vessel(path, windows=12, seed=1)
    header = json.loads(gzip.decompress(build(first, UNIT).body))
    assert header["instance"] == first.instance() and len(header["instance"]) == 36
    sync(first, shore, token)
    old, old_rows = first.instance(), sent(first)
    first.close()
    for leftover in tmp_path.glob("vessel.db*"):  # the disk swap: database and WAL gone
        leftover.unlink()

    second = vessel(path, windows=8, seed=2)  # the same ids again (1..8), other content
    new, new_rows = second.instance(), sent(second)
    assert new != old and set(new_rows) <= set(old_rows)
    sync(second, shore, token)
    second.close()

    unit = shore.get(token, f"/fleet/units/{UNIT}").json()
    assert unit["rows"] == {"session": 2, "window": 20, "slew": 0, "version": 2, "event": 2}
    assert unit["conflicts"] == 0 and unit["conflict_rows"] == []
    assert unit["instance"] == new
    # the current version follows the newest database, though its number is lower
    assert (unit["current_version"], unit["current_instance"]) == (1, new)
    for path_, kind in (("windows", "window"), ("events", "event"), ("versions", "version")):
        rows = on_shore(shore, token, path_, page=3)
        key = "version" if kind == "version" else "id"
        got = {(r["instance"], r[key]): r for r in rows}
        assert len(got) == len(rows)  # each row once, pages or not
        for instance, mine in ((old, old_rows), (new, new_rows)):
            expected = {i: d for (k, i), d in mine.items() if k == kind}
            shore_side = {i: content_digest(r["document"] if kind == "version" else r["data"])
                          for (inst, i), r in got.items() if inst == instance}  # fmt: skip
            assert shore_side == expected, (kind, instance)
    view = shore.get(token, "/fleet/overview").json()["units"][0]
    assert (view["current_version"], view["current_instance"]) == (1, new)
    assert view["conflicts"] == 0 and "conflicts" not in view["attention"]


def test_a_row_sent_again_with_other_content_is_a_conflict(shore: Any, wire: Any) -> None:
    """Same content (whatever its key order or number spelling): a duplicate. Other content
    under a stored key: a conflict, kept whole, counted once however often it is retried, in
    the ingest answer, the unit, the overview; never stored over the first."""
    token = shore.store.add_unit(UNIT, "KVH-1750")
    rows = wire.rows_of(3)
    batch = wire.batch(UNIT, rows) | {"instance": "7b1d0c4e-1f7a-4c55-9a53-5f2f3c9f0a11"}
    assert shore.send(token, batch).json() == {"stored": 8, "duplicates": 0, "conflicts": 0}
    # the same content, keys reordered and numbers spelt otherwise: a duplicate
    same = copy.deepcopy(batch)
    window = same["rows"][2]
    assert window["kind"] == "window" and window["data"]["accel_x"] == 0.01
    window["data"] = dict(reversed(list(window["data"].items())))
    window["data"]["session"] = 1.0
    assert shore.send(token, same).json() == {"stored": 0, "duplicates": 8, "conflicts": 0}

    changed = copy.deepcopy(batch)
    changed["rows"][2]["data"]["accel_x"] = 0.02  # window 2, other content
    for _ in range(2):  # a retry of the same batch records nothing more
        r = shore.send(token, changed)
        assert r.json() == {"stored": 0, "duplicates": 7, "conflicts": 1}
    unit = shore.get(token, f"/fleet/units/{UNIT}").json()
    assert unit["conflicts"] == 1 and unit["rows"]["window"] == 3
    (conflict,) = unit["conflict_rows"]
    assert (conflict["kind"], conflict["id"], conflict["instance"]) == (
        "window",
        2,
        batch["instance"],
    )
    assert conflict["data"] == changed["rows"][2]["data"] and conflict["received_at"]
    assert conflict["stored_digest"] == content_digest(rows[2]["data"]) != conflict["digest"]
    windows = shore.get(token, f"/fleet/units/{UNIT}/windows").json()
    assert windows[1]["data"]["accel_x"] == 0.01  # the first stays
    view = shore.get(token, "/fleet/overview").json()
    assert "conflicts" in view["units"][0]["attention"] and view["totals"]["conflicts"] == 1

    # a legacy batch (no instance) with the same ids: another database's rows, stored
    legacy = shore.send(token, wire.batch(UNIT, rows)).json()
    assert legacy == {"stored": 8, "duplicates": 0, "conflicts": 0}
    assert shore.get(token, f"/fleet/units/{UNIT}").json()["rows"]["window"] == 6


def test_rows_stored_before_digests_are_compared_as_stored(shore: Any, wire: Any) -> None:
    """A row stored before migration 0007 has no digest: its document, as the database gives
    it back (JSONB on PostgreSQL: keys reordered, numbers respelt), is what a row received again
    is compared with."""
    token = shore.store.add_unit(UNIT, "KVH-1750")
    rows = wire.rows_of(3)
    rows[2]["data"] |= {"gyro_x": 1e20, "temperature_c": -0.0, "z": {"b": 1, "a": [2.5, 3]}}
    assert shore.send(token, wire.batch(UNIT, rows)).json()["stored"] == 8
    with shore.store._tx(write=True) as s:
        s.execute(update(WindowRow).values(digest=None))
    assert shore.send(token, wire.batch(UNIT, rows)).json()["conflicts"] == 0
    rows[2]["data"]["z"]["a"][1] = 4
    assert shore.send(token, wire.batch(UNIT, rows)).json() == {
        "stored": 0, "duplicates": 7, "conflicts": 1}  # fmt: skip


def test_migration_0007_keeps_a_shores_rows_as_the_legacy_instance(
    fleet_store: Any, wire: Any
) -> None:
    """A shore's rows from before instances become the legacy instance's (""), their unit keeps
    its current version (now with its time), and a vessel of the release before, sending its
    rows again, finds them: duplicates, not new rows."""
    from alembic import command

    from service.fleet.batch import read_batch
    from service.fleet.migrations import alembic_config, head

    fleet_store.add_unit(UNIT, "KVH-1750")
    unit = fleet_store.unit_by_serial(UNIT)
    body = json.dumps(wire.batch(UNIT, wire.rows_of(3))).encode()
    assert fleet_store.ingest(unit, read_batch(body, None, 10**6), 0) == (8, 0, 0)
    before = fleet_store.units()
    with fleet_store._engine.connect() as conn, conn.begin():
        command.downgrade(alembic_config(conn), "0006")
    fleet_store.create_schema()
    assert fleet_store.schema_revision() == head()
    (after,) = fleet_store.units()
    assert after == before[0] | {"current_instance": ""}  # version 1: the accepted one
    assert after["current_version"] == 1 and after["instance"] == ""
    rows = fleet_store.rows("window", unit)
    assert [(r["instance"], r["id"]) for r in rows] == [("", 1), ("", 2), ("", 3)]
    assert fleet_store.ingest(unit, read_batch(body, None, 10**6), 0) == (0, 8, 0)
