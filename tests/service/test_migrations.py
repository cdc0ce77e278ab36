"""Schema migrations (service/migrations) on SQLite and PostgreSQL: a database of the release
before migrations (git 612b796, schema version 1) is upgraded keeping every version and
position bit for bit; upgrades are idempotent; newer databases are refused; the migrated schema
equals the ORM models; ``recal db``.

tests/data/release_612b796.db was written by that release's own code: regenerate it with
``git show 612b796:service/db.py > /tmp/db612.py`` then
``python tests/service/test_migrations.py /tmp/db612.py tests/data/release_612b796.db``.
"""

from __future__ import annotations

import shutil
import sqlite3
import threading
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from sqlalchemy import create_engine, inspect, text

from recal.detect.slew_collect import ReducedSlew
from recal.model.coefficients import CoefficientSet
from recal.model.positions import SHIP_COLUMNS
from recal.sim.simulate import simulate_positions
from service import migrations
from service.cli.main import main
from service.store.errors import StoreError
from service.store.records import CalibrationRecord
from service.store.repository import Store
from service.store.rows import Base
from service.store.schema import SCHEMA_VERSION

RELEASE_DB = Path(__file__).parents[1] / "data" / "release_612b796.db"
#: The tables of the release, with the column that orders their rows.
RELEASE_TABLES = {
    "schema_version": "version",
    "sessions": "id",
    "positions": "id",
    "calibrations": "id",
    "events": "id",
    "noise_floors": "id",
}


# ---- building old databases ---------------------------------------------------------------


def fill(store: Any, record: type, document: dict[str, Any]) -> None:
    """Sessions, positions (``*_sem`` and an extra column with a NaN), three calibrations (one
    rejected), events and a noise floor, through the Store API of either code base."""
    truth = CoefficientSet.seed_truth()
    cols = dict(simulate_positions(truth, seed=1).columns)
    for axis in ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z"):
        cols[f"{axis}_sem"] = cols[f"{axis}_std"] / np.sqrt(cols["samples"])
    cols["pressure_hpa"] = np.linspace(1013.25, 1001.0, len(cols["samples"]))
    cols["pressure_hpa"][3] = np.nan
    s1 = store.add_session("replay:///data/capture.bin?speed=1", {"rate_hz": 1000.0})
    ids = store.add_positions(s1, cols)
    s2 = store.add_session("/dev/ttyUSB0", {"format": "kvh-a"})
    more = dict(simulate_positions(truth, "random", n_positions=6, seed=2).columns)
    ids2 = store.add_positions(s2, more)
    when = datetime(2026, 11, 20, 8, 30, 15, 123456, tzinfo=UTC)
    v1 = store.add_calibration(
        record(
            created_at=when,
            trigger="auto",
            method="lm",
            accepted=True,
            document=document,
            positions_used=ids[:14],
        )  # fmt: skip
    )
    store.add_calibration(
        record(
            trigger="auto",
            method="lm",
            accepted=False,
            reasons=["chi2_red 9.10 > 4"],
            document={**document, "chi2_red": 9.1},
            positions_used=ids,
            prior_version=v1,
        )  # fmt: skip
    )
    store.add_calibration(
        record(
            trigger="manual",
            method="nafsa",
            accepted=True,
            document=document,
            positions_used=ids + ids2,
            prior_version=v1,
        )  # fmt: skip
    )
    store.add_event("start", "service started, reading /dev/ttyUSB0", {"url": "/dev/ttyUSB0"})
    store.add_event("calibration_rejected", "chi2_red 9.10 > 4", {"version": v1 + 1})
    store.add_event("reader_error", "no frame for 2 s", None)
    floor = {"accel": 1.25e-4, "gyro": 1 / 3 * 1e-6, "window_samples": 1000,
             "source": "init_still", "windows": 12}  # fmt: skip
    store.save_noise_floor("/dev/ttyUSB0 kvh-a 1000 Hz", floor)


def at_revision(url: str, revision: str, legacy: bool = False) -> None:
    """Migrate an empty database to ``revision``; ``legacy``: then drop the migration record,
    leaving what the release's create_all made (its tables and schema_version 1)."""
    engine = create_engine(url)
    with engine.begin() as conn:
        command.upgrade(migrations.alembic_config(conn), revision)
        if legacy:
            conn.execute(text("DROP TABLE alembic_version"))
    engine.dispose()


# ---- what must survive --------------------------------------------------------------------


def _exact(value: Any) -> Any:
    return value.hex() if isinstance(value, float) else value  # bit for bit, -0.0 and NaN too


def dump(url: str) -> dict[str, list[tuple]]:
    """Every row of the release's tables, as the driver returns them (no ORM in between)."""
    engine = create_engine(url)
    with engine.connect() as conn:
        out = {
            table: [
                tuple(_exact(v) for v in row)
                for row in conn.execute(text(f"SELECT * FROM {table} ORDER BY {key}"))
            ]  # fmt: skip
            for table, key in RELEASE_TABLES.items()
        }
        if engine.dialect.name == "sqlite":  # AUTOINCREMENT's memory: versions never repeat
            out["sqlite_sequence"] = list(conn.execute(text("SELECT * FROM sqlite_sequence")))
    engine.dispose()
    return out


def snapshot(store: Store) -> dict[str, Any]:
    """What the Store serves: every calibration, every position (bits), events, noise floor."""
    out: dict[str, Any] = {}
    for session in (1, 2):
        positions, ids = store.positions(session_id=session)
        out[f"ids{session}"] = ids
        out[f"positions{session}"] = {
            k: v.view(np.uint64).tolist() for k, v in positions.columns.items()
        }
    return out | {
        "history": [vars(r) for r in store.history(limit=1000)],
        "current": store.current().version,
        "all": store.positions()[1],
        "events": store.events(limit=1000),
        "floor": store.noise_floor("/dev/ttyUSB0 kvh-a 1000 Hz"),
    }


def reduced(seed: int) -> ReducedSlew:
    rng = np.random.default_rng(seed)
    groups = (rng.integers(1, 9, 4), rng.normal(size=(4, 3)), rng.normal(size=(4, 3)),
              rng.normal(size=(4, 3)))  # fmt: skip
    return ReducedSlew(None, None, rng.normal(size=3), 400, groups, None)


def check_history_is_in_the_outbox(store: Store, served: dict[str, Any]) -> None:
    """Revision 0004 gave every stored row an outbox row (fleet sync sends the history), once,
    oldest first, a session before its windows."""
    entries = store.outbox(10_000)
    keys = [(e.kind, e.ref_id) for e in entries]
    expected = (
        {("session", 1), ("session", 2)}
        | {("window", i) for i in served["all"]}
        | {("version", r["version"]) for r in served["history"]}
        | {("event", e["id"]) for e in served["events"]}
    )
    assert len(keys) == len(expected) == 38 and set(keys) == expected
    assert [e.seq for e in entries] == sorted(e.seq for e in entries)
    assert keys.index(("session", 1)) < keys.index(("window", served["ids1"][0]))
    assert keys.index(("session", 2)) < keys.index(("window", served["ids2"][0]))
    assert keys[0] == ("version", 1)  # stored with an earlier time than anything else


def check_upgrade_keeps_everything(url: str) -> None:
    old = Store(url)  # the release's database opens as it is (schema version 1 is known)
    before, served = dump(url), snapshot(old)
    assert [r["version"] for r in served["history"]] == [3, 2, 1]
    assert [r["accepted"] for r in served["history"]] == [True, False, True]
    assert served["current"] == 3 and len(served["ids1"]) == 24 and len(served["ids2"]) == 6
    assert {"gyro_x_sem", "pressure_hpa"} <= set(served["positions1"])
    assert np.isnan(np.array(served["positions1"]["pressure_hpa"]).view(float)).sum() == 1

    old.create_schema()
    old.close()
    store = Store(url)
    after = dump(url)
    assert after.pop("schema_version")[:-5] == before.pop("schema_version")
    # revision 0005 added the ship's columns at the end of positions: NULL in every old row
    ship = len(SHIP_COLUMNS)
    assert all(row[-ship:] == (None,) * ship for row in after["positions"])
    after["positions"] = [row[:-ship] for row in after["positions"]]
    if "sqlite_sequence" in after:  # the outbox's numbers are new; the versions' kept
        after["sqlite_sequence"] = [r for r in after["sqlite_sequence"] if r[0] != "outbox"]
    assert after == before
    assert snapshot(store) == served
    assert store.schema_version() == SCHEMA_VERSION == 6  # the release refuses it from now on
    assert store.schema_revision() == migrations.head()
    check_history_is_in_the_outbox(store, served)

    # the new table works, and versions go on from the last one
    last = served["ids1"][-1]
    two = simulate_positions(CoefficientSet.seed_truth(), "random", n_positions=2, seed=3)
    new = store.add_positions(1, dict(two.columns),
                              [(-1, 0, reduced(1)), (0, 1, reduced(2))], 0.001,
                              previous_id=last)  # fmt: skip
    slews = store.slews([last, *new])
    assert [(s.first_id, s.second_id) for s in slews] == [(last, new[0]), (new[0], new[1])]
    np.testing.assert_array_equal(slews[1].groups[1], reduced(2).groups[1])
    assert store.add_calibration(CalibrationRecord(trigger="auto", method="lm", accepted=True,
                                                   document={})) == 4  # fmt: skip
    store.close()


# ---- tests --------------------------------------------------------------------------------


def test_release_database_file_upgrades_keeping_everything(tmp_path: Path) -> None:
    path = tmp_path / "recal.db"
    shutil.copyfile(RELEASE_DB, path)
    with sqlite3.connect(path) as conn:  # really the release's: no migration record
        tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master")}
        assert "alembic_version" not in tables and "slews" not in tables
        assert conn.execute("SELECT version FROM schema_version").fetchall() == [(1,)]
    check_upgrade_keeps_everything(f"sqlite:///{path}")


@pytest.mark.parametrize("legacy", [True, False], ids=["release-made", "migrated-0001"])
def test_upgrade_from_the_release_schema_keeps_everything(
    store_url: str, legacy: bool, document: dict[str, Any]
) -> None:
    at_revision(store_url, "0001", legacy=legacy)
    st = Store(store_url)
    fill(st, CalibrationRecord, document)
    st.close()
    check_upgrade_keeps_everything(store_url)


def test_upgrade_is_idempotent(store_url: str, store: Store, document: dict[str, Any]) -> None:
    fill(store, CalibrationRecord, document)
    before = dump(store_url)
    store.create_schema()
    again = Store(store_url)
    again.create_schema()
    command.upgrade(migrations.alembic_config(url=store_url), "head")
    assert dump(store_url) == before  # one schema_version row per version, data untouched
    assert [r[0] for r in before["schema_version"]] == [1, 2, 3, 4, 5, 6]
    assert again.recorded_schema() == (SCHEMA_VERSION, migrations.head())
    again.close()


def test_ship_columns_are_added_and_extra_values_move_into_them(
    store_url: str, document: dict[str, Any]
) -> None:
    """Revision 0005: a database at 0004 whose windows carried the ship's state as extra
    columns keeps it, in the new columns; windows without it read as before (no such column)."""
    at_revision(store_url, "0004")
    engine = create_engine(store_url)
    with engine.begin() as conn:
        conn.execute(text("INSERT INTO sessions (id, created_at, source, meta) VALUES "
                          "(1, '2026-11-30 10:00:00', 'x', '{}')"))  # fmt: skip
        for pid, extra in ((1, '{"latitude_deg": 57.7, "sog_kn": 0.2, "pressure_hpa": 1013}'),
                           (2, '{"pressure_hpa": 1001}')):  # fmt: skip
            conn.execute(text("INSERT INTO positions (id, session_id, created_at, start_s, "
                              "end_s, samples, gyro_x, gyro_y, gyro_z, extra) VALUES (:id, 1, "
                              "'2026-11-30 10:00:00', 0, 1, 10, 1, 2, 3, :extra)"),
                         {"id": pid, "extra": extra})  # fmt: skip
    engine.dispose()
    store = Store(store_url)
    store.create_schema()
    positions, ids = store.positions()
    assert ids == [1, 2] and store.recorded_schema() == (SCHEMA_VERSION, migrations.head())
    np.testing.assert_array_equal(positions.columns["latitude_deg"], [57.7, np.nan])
    np.testing.assert_array_equal(positions.columns["sog_kn"], [0.2, np.nan])
    assert "heading_deg" not in positions.columns  # no window has it
    assert positions.columns["pressure_hpa"].tolist() == [1013, 1001]
    assert "latitude_deg" not in store.positions(since_id=1)[0].columns
    store.close()


def test_every_database_gets_its_own_instance_id(store_url: str, tmp_path: Path) -> None:
    """Revision 0006: a database made before it gets an instance id when migrated, kept from
    then on; a database made afresh gets a new one (what the shore tells a rebuilt vessel by)."""
    at_revision(store_url, "0005")
    old = Store(store_url)
    assert old.instance() == ""  # not migrated yet: the shore's legacy instance
    old.close()
    store = Store(store_url)
    store.create_schema()
    first = store.instance()
    assert len(first) == 36 and first.count("-") == 4
    store.create_schema()  # idempotent: the id stays
    again = Store(store_url)
    assert again.instance() == first
    again.close()
    store.close()
    other = Store(f"sqlite:///{tmp_path / 'fresh.db'}")
    other.create_schema()
    assert other.instance() not in ("", first)
    other.close()


def test_concurrent_starts_migrate_once(store_url: str) -> None:
    errors: list[BaseException] = []

    def start() -> None:
        try:
            st = Store(store_url)
            st.create_schema()
            st.close()
        except BaseException as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=start) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    assert [r[0] for r in dump(store_url)["schema_version"]] == [1, 2, 3, 4, 5, 6]


def test_downgrade_and_upgrade_again(store_url: str, store: Store) -> None:
    cfg = migrations.alembic_config(url=store_url)
    command.downgrade(cfg, "0001")
    assert store.recorded_schema() == (1, "0001")
    command.downgrade(cfg, "base")
    store.create_schema()
    assert store.recorded_schema() == (SCHEMA_VERSION, migrations.head())


def test_unknown_newer_revision_is_refused(
    store_url: str, store: Store, capsys: pytest.CaptureFixture[str]
) -> None:
    engine = create_engine(store_url)
    with engine.begin() as conn:
        conn.execute(text("UPDATE alembic_version SET version_num = '0099'"))
    engine.dispose()
    for attempt in (lambda: Store(store_url), store.create_schema):
        with pytest.raises(StoreError, match="revision 0099, newer than this code knows") as e:
            attempt()
        assert "\n" not in str(e.value)
    assert main(["db", "upgrade", "--database", store_url]) == 2
    err = capsys.readouterr().err
    assert err.startswith("recal db: error: ") and "0099" in err and err.count("\n") == 1


def test_migrations_match_the_orm_models(store_url: str, store: Store) -> None:
    engine = create_engine(store_url)
    with engine.connect() as conn:
        context = MigrationContext.configure(conn, opts={"compare_type": True})
        assert compare_metadata(context, Base.metadata) == []
        tables = set(inspect(conn).get_table_names())
    engine.dispose()
    assert tables == set(Base.metadata.tables) | {"alembic_version"}


def test_cli_db_upgrade_and_current(
    store_url: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    head = migrations.head()
    config = tmp_path / "recal.toml"
    config.write_text(f'database_url = "{store_url}"\n')
    if store_url.startswith("sqlite"):  # `current` does not create a database file
        assert main(["db", "current", "--database", store_url]) == 2
        assert "does not exist" in capsys.readouterr().err
    at_revision(store_url, "0001", legacy=True)
    assert main(["db", "current", "--config", str(config)]) == 0
    assert capsys.readouterr().out.startswith("none (schema version 1, made before migrations")

    assert main(["db", "upgrade", "--database", store_url]) == 0
    out, err = capsys.readouterr()
    assert out == f"{head} (head)\n"
    assert "Running upgrade 0001 -> 0002" in err and f"upgraded from none to {head}" in err
    assert main(["db", "upgrade", "--config", str(config), "--debug"]) == 0
    out, err = capsys.readouterr()
    assert out == f"{head} (head)\n" and f"already at {head}" in err
    assert main(["db", "current", "--database", store_url]) == 0
    assert capsys.readouterr().out == f"{head} (head)\n"
    st = Store(store_url)
    assert st.recorded_schema() == (SCHEMA_VERSION, head)
    st.close()


@pytest.mark.parametrize(
    "argv, message",
    [
        (["db", "upgrade"], "no database: give --database URL or --config FILE.toml"),
        (["db", "current", "--config", "/nonexistent/recal.toml"], "does not exist"),
        (["db", "upgrade", "--database", "postgresql+psycopg://u@127.0.0.1:1/x"], "cannot open"),
        (["db", "upgrade", "--database", "not a url"], "bad database URL"),
    ],
)
def test_cli_db_bad_input_is_one_line(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str], monkeypatch: Any
) -> None:
    monkeypatch.delenv("RECAL_DATABASE_URL", raising=False)
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.startswith("recal db: error: ") and message in err
    assert err.count("\n") == 1


if __name__ == "__main__":  # regenerate tests/data/release_612b796.db with the release's code
    import importlib.util
    import sys

    from recal.solve.calibrate import calibrate

    spec = importlib.util.spec_from_file_location("release_db", sys.argv[1])
    release = importlib.util.module_from_spec(spec)
    sys.modules["release_db"] = release  # dataclasses look their module up
    spec.loader.exec_module(release)
    assert release.SCHEMA_VERSION == 1 and not hasattr(release, "SlewRow")
    out = Path(sys.argv[2])
    out.unlink(missing_ok=True)
    st = release.Store(f"sqlite:///{out}")
    st.create_schema()
    doc = calibrate(simulate_positions(CoefficientSet.seed_truth(), seed=1)).to_json_dict()
    fill(st, release.CalibrationRecord, doc)
    st.close()
    with sqlite3.connect(out) as conn:  # one self-contained file
        conn.execute("PRAGMA journal_mode=DELETE")
    print(f"wrote {out} ({out.stat().st_size} bytes)")
