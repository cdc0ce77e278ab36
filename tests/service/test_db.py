"""Store on SQLite and PostgreSQL: schema, positions, calibrations, events, errors, threads."""

from __future__ import annotations

import math
import sqlite3
import threading
from collections.abc import Callable
from datetime import UTC
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import create_engine, insert

from recal.detect.slew_collect import ReducedSlew
from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.positions import Positions
from recal.sim.simulate import simulate_positions
from service import migrations
from service.store.errors import StoreError
from service.store.records import CalibrationRecord
from service.store.repository import Store
from service.store.rows import SchemaVersionRow
from service.store.schema import SCHEMA_VERSION


def simulated(n: int = 24, seed: int = 0, sensors: tuple[str, ...] = ("gyro", "accel")) -> dict:
    pos = simulate_positions(
        CoefficientSet.seed_truth(), "random", n_positions=n, seed=seed, sensors=sensors
    )
    return dict(pos.columns)


def test_schema_is_idempotent_and_versioned(store_url: str, store: Store) -> None:
    store.create_schema()
    assert store.schema_version() == SCHEMA_VERSION
    assert store.schema_revision() == migrations.head()
    reopened = Store(store_url)  # opening checks the recorded version and revision
    reopened.create_schema()
    assert reopened.schema_version() == SCHEMA_VERSION
    assert reopened.schema_revision() == migrations.head()
    reopened.close()


def test_positions_round_trip_exactly(store: Store) -> None:
    cols = simulated(6)
    cols["pressure_hpa"] = np.array([1013.0, 1012.5, math.nan, 1011.0, 1010.0, 1009.5])
    sid = store.add_session("replay://capture.bin", {"rate_hz": 1000})
    ids = store.add_positions(sid, cols)
    assert len(ids) == 6 and ids == sorted(ids)

    table, got_ids = store.positions()
    assert got_ids == ids
    assert isinstance(table, Positions) and set(table.columns) == set(cols)
    for name, values in cols.items():
        np.testing.assert_array_equal(table.columns[name], values)  # bit for bit
    assert Positions.from_csv_text(table.to_csv_text()).columns.keys() == cols.keys()
    assert store.count_positions() == 6 and store.count_positions(sid) == 6


def test_slews_are_stored_with_their_windows(store: Store) -> None:
    """Slews go in with the positions (one transaction), bit for bit; a dropped one keeps its
    reason; one whose first window was stored earlier links to it; a query returns only the
    slews with both windows in the asked ids."""
    rng = np.random.default_rng(1)
    G = 4

    def reduced(dropped=None):
        groups = None
        if dropped is None:
            groups = (rng.integers(0, 9, G), rng.normal(size=(G, 3)), rng.normal(size=(G, 3)),
                      rng.normal(size=(G, 3)))  # fmt: skip
        return ReducedSlew(None, None, rng.normal(size=3), 17, groups, dropped)

    sid = store.add_session("replay://x")
    first = store.add_positions(sid, simulated(2, seed=1), [(0, 1, reduced())], 0.005)
    a, b = reduced(), reduced("lost_frames")
    more = store.add_positions(sid, simulated(2, seed=2), [(-1, 0, a), (0, 1, b)], 0.005,
                               previous_id=first[-1])  # fmt: skip
    got = store.slews(first + more)
    assert [(r.first_id, r.second_id) for r in got] == [
        (first[0], first[1]),
        (first[1], more[0]),
        (more[0], more[1]),
    ]
    assert got[1].samples == 17 and got[1].period_s == 0.005
    np.testing.assert_array_equal(got[1].reference, a.reference)
    for x, y in zip(got[1].groups, a.groups, strict=True):
        np.testing.assert_array_equal(x, y)
    assert got[2].dropped == "lost_frames" and got[2].groups is None
    assert [(r.first_id, r.second_id) for r in store.slews(more)] == [(more[0], more[1])]


def test_positions_filters(store: Store) -> None:
    a = store.add_session("a")
    b = store.add_session("b")
    ids_a = store.add_positions(a, simulated(4, seed=1))
    ids_b = store.add_positions(b, simulated(3, seed=2))
    assert store.positions(session_id=b)[1] == ids_b
    assert store.positions(since_id=ids_a[1])[1] == ids_a[2:] + ids_b
    assert store.positions(since_id=ids_a[1], limit=3)[1] == ids_a[2:] + ids_b[:1]
    empty, none = store.positions(since_id=ids_b[-1])
    assert none == [] and len(empty) == 0 and empty.columns == {}
    assert store.count_positions(a) == 4


def test_positions_keep_only_columns_all_rows_have(store: Store) -> None:
    sid = store.add_session("mixed")
    gyro_only = simulated(3, sensors=("gyro",))
    gyro_only["note"] = np.ones(3)
    store.add_positions(sid, gyro_only)
    store.add_positions(sid, simulated(3, seed=5))
    table, ids = store.positions()
    assert len(ids) == 6 and table.has_gyro and not table.has_accel
    assert "note" not in table.columns and "gyro_x_std" in table.columns


def test_bad_positions_are_refused_before_writing(store: Store) -> None:
    sid = store.add_session("x")
    with pytest.raises(RecalInputError, match="missing column"):
        store.add_positions(sid, {"gyro_x": [1.0], "gyro_y": [2.0]})
    with pytest.raises(StoreError, match="unknown session 999"):
        store.add_positions(999, simulated(2))
    assert store.count_positions() == 0


def test_calibrations_versions_current_history(
    store: Store, make_record: Callable[..., CalibrationRecord], document: dict
) -> None:
    assert store.current() is None and store.history() == []
    v1 = store.add_calibration(make_record(positions_used=[1, 2, 3]))
    v2 = store.add_calibration(make_record(accepted=False, reasons=["chi2_red 9 exceeds 4"]))
    v3 = store.add_calibration(make_record(prior_version=v1, trigger="manual"))
    v4 = store.add_calibration(make_record(accepted=False, prior_version=v3))
    assert v1 < v2 < v3 < v4

    current = store.current()
    assert current is not None and current.version == v3 and current.prior_version == v1
    assert current.trigger == "manual" and current.document == document
    assert current.created_at.tzinfo is not None and current.created_at.utcoffset().seconds == 0

    first = store.calibration(v1)
    assert first is not None and first.positions_used == [1, 2, 3] and first.accepted
    rejected = store.calibration(v2)
    assert rejected is not None and rejected.reasons == ["chi2_red 9 exceeds 4"]
    assert store.calibration(v4 + 100) is None
    assert [r.version for r in store.history()] == [v4, v3, v2, v1]
    assert [r.version for r in store.history(limit=2)] == [v4, v3]


def test_calibration_write_is_atomic(
    store: Store, make_record: Callable[..., CalibrationRecord]
) -> None:
    with pytest.raises(StoreError):
        store.add_calibration(make_record(prior_version=12345))  # no such version
    assert store.history() == []


def test_non_finite_json_values_become_null(
    store: Store, make_record: Callable[..., CalibrationRecord]
) -> None:
    doc = {"coefficients": {"gyro": {"bias": [np.float64(0.1), math.nan, math.inf]}}}
    version = store.add_calibration(make_record(document=doc))
    stored = store.calibration(version)
    assert stored is not None
    assert stored.document == {"coefficients": {"gyro": {"bias": [0.1, None, None]}}}


def test_events_newest_first(store: Store) -> None:
    first = store.add_event("job", "calibration started", {"job": 1})
    second = store.add_event("reader", "CRC failure")
    events = store.events()
    assert [e["id"] for e in events] == [second, first]
    assert events[1] | {"created_at": None} == {
        "id": first,
        "created_at": None,
        "kind": "job",
        "message": "calibration started",
        "data": {"job": 1},
    }
    assert events[0]["data"] is None and events[0]["created_at"].endswith("+00:00")
    assert len(store.events(limit=1)) == 1


def test_concurrent_writers_and_readers(store: Store) -> None:
    sid = store.add_session("threads")
    cols = simulated(2)
    ids: list[int] = []
    errors: list[BaseException] = []

    def work(k: int) -> None:
        try:
            for i in range(8):
                ids.extend(store.add_positions(sid, cols))
                store.add_event("test", f"thread {k} write {i}")
                store.positions(limit=5)
        except BaseException as exc:  # reported by the main thread
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    assert len(set(ids)) == len(ids) == 64
    assert store.count_positions() == 64 and len(store.events(limit=1000)) == 32


def test_newer_schema_is_refused(store_url: str, store: Store) -> None:
    engine = create_engine(store_url)
    with engine.begin() as conn:
        conn.execute(insert(SchemaVersionRow).values(version=SCHEMA_VERSION + 1))
    engine.dispose()
    with pytest.raises(StoreError, match="newer than this code"):
        Store(store_url)
    with pytest.raises(StoreError, match="newer than this code"):
        store.create_schema()


@pytest.mark.parametrize(
    "url, message",
    [
        ("not a url", "bad database URL"),
        ("nosuchdb://host/db", "cannot use database URL"),
        ("postgresql+psycopg://postgres@127.0.0.1:1/none", "cannot open database"),
    ],
)
def test_unusable_urls_raise_one_line_store_errors(url: str, message: str) -> None:
    with pytest.raises(StoreError, match=message) as info:
        Store(url, connect_timeout_s=2)
    assert "\n" not in str(info.value)


def test_missing_tables_are_a_store_error(tmp_path: Path) -> None:
    st = Store(f"sqlite:///{tmp_path / 'empty.db'}")
    with pytest.raises(StoreError, match="no such table"):
        st.add_session("x")
    st.close()


def test_sqlite_file_uses_wal_and_foreign_keys(tmp_path: Path) -> None:
    path = tmp_path / "wal.db"
    st = Store(f"sqlite:///{path}")
    st.create_schema()
    st.add_session("x")
    with pytest.raises(StoreError, match="FOREIGN KEY"):
        st.add_calibration(
            CalibrationRecord(
                trigger="auto", method="lm", accepted=True, document={}, prior_version=7
            )
        )
    st.close()
    with sqlite3.connect(path) as conn:
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_in_memory_sqlite(make_record: Callable[..., CalibrationRecord]) -> None:
    st = Store("sqlite://")
    st.create_schema()
    version = st.add_calibration(make_record())
    current = st.current()
    assert current is not None and current.version == version
    assert current.created_at.tzinfo == UTC
    st.close()


def test_window_rate_counts_device_time_per_session(store: Store) -> None:
    """Each session restarts the device clock: the rate is windows over the sum of the spans
    from each session's first window to its last (here 5 + 3 windows over 20 h + 10 h)."""
    from service.config import SchedulerSettings, Settings
    from service.triggers import DEFAULT_WINDOWS_PER_DAY, windows_per_day

    settings = Settings(database_url="sqlite://", scheduler=SchedulerSettings())
    assert windows_per_day(store, settings) == (DEFAULT_WINDOWS_PER_DAY, False)  # nothing yet
    for name, n, hours in (("a", 5, 20.0), ("b", 3, 10.0)):
        cols = simulated(n, seed=n)
        cols["start_s"] = np.linspace(0.0, hours * 3600.0 - 600.0, n)
        cols["end_s"] = cols["start_s"] + 600.0
        store.add_positions(store.add_session(name), cols)
    assert store.window_rate() == (8, pytest.approx(30 * 3600.0))
    rate, measured = windows_per_day(store, settings)
    assert measured and rate == pytest.approx(8 / 30 * 24)
    fixed = Settings(database_url="sqlite://", scheduler=SchedulerSettings(windows_per_day=100))
    assert windows_per_day(store, fixed) == (100.0, False)  # a set rate wins


def test_the_old_service_db_path_warns_and_gives_the_stores_names() -> None:
    """``service.db`` (0.2.0) only re-exported service.store; it imports until 0.3.0 with a
    DeprecationWarning naming each name's module (service.moved, docs/api.md)."""
    from service.store.errors import StoreError as Error
    from service.store.repository import Store as Repository

    pattern = r"^service\.db is deprecated; import {} from {} .*removed in 0\.3\.0$"
    with pytest.warns(
        DeprecationWarning, match=pattern.format("Store", r"service\.store\.repository")
    ):
        from service.db import Store as Old
    with pytest.warns(
        DeprecationWarning, match=pattern.format("StoreError", r"service\.store\.errors")
    ):
        from service.db import StoreError as OldError
    assert Old is Repository and OldError is Error
