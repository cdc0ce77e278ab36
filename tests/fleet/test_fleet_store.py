"""The shore's schema and store: migrations that match the models, a database shared with the
vessel's schema, units and their tokens."""

from __future__ import annotations

import json

import pytest
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from sqlalchemy import create_engine, inspect

from service.fleet.migrations import VERSION_TABLE, head
from service.fleet.schema import FleetBase
from service.fleet.store import FleetStore, UnitExistsError, UnknownUnitError, token_hash
from service.store.errors import StoreError
from service.store.repository import Store


def test_the_migrations_build_the_models_schema(fleet_store: FleetStore, fleet_url: str) -> None:
    assert fleet_store.schema_revision() == head()
    fleet_store.create_schema()  # idempotent
    engine = create_engine(fleet_url)
    try:
        with engine.connect() as conn:
            ctx = MigrationContext.configure(
                conn,
                opts={"compare_type": True, "version_table": VERSION_TABLE,
                      "include_name": lambda name, type_, _p:
                      type_ != "table" or name.startswith("fleet_")},
            )  # fmt: skip
            diff = compare_metadata(ctx, FleetBase.metadata)
            tables = set(inspect(conn).get_table_names())
    finally:
        engine.dispose()
    assert diff == []
    assert VERSION_TABLE in tables and "alembic_version" not in tables


def test_the_shore_shares_a_database_with_the_vessel(fleet_url: str) -> None:
    """Both schemas in one database, each migrated by its own code, neither disturbed."""
    vessel = Store(fleet_url)
    vessel.create_schema()
    shore = FleetStore(fleet_url)
    try:
        shore.create_schema()
        vessel_revision = vessel.schema_revision()
        vessel.create_schema()
        shore.create_schema()
        assert vessel.schema_revision() == vessel_revision
        assert shore.schema_revision() == head()
        shore.add_unit("SN-1")
        vessel.add_session("test")
    finally:
        shore.close()
        vessel.close()
        engine = create_engine(fleet_url)
        from service.store.rows import Base

        Base.metadata.drop_all(engine)
        with engine.begin() as conn:
            conn.exec_driver_sql("DROP TABLE IF EXISTS alembic_version")
        engine.dispose()


def test_units_and_tokens(fleet_store: FleetStore) -> None:
    token = fleet_store.add_unit("KVH-1750-SN0042", "KVH-1750")
    assert len(token) >= 43 and token.strip() == token
    unit = fleet_store.unit_of_token(token)
    assert unit is not None and (unit.serial, unit.model) == ("KVH-1750-SN0042", "KVH-1750")
    assert fleet_store.unit_of_token(token[:-1]) is None
    with pytest.raises(UnitExistsError, match="already registered"):
        fleet_store.add_unit("KVH-1750-SN0042")
    new = fleet_store.add_unit("KVH-1750-SN0042", rotate=True)
    assert fleet_store.unit_of_token(token) is None
    assert fleet_store.unit_of_token(new).model == "KVH-1750"  # kept when not given
    with pytest.raises(UnknownUnitError):
        fleet_store.add_unit("SN-NEW", rotate=True)
    for bad in ("", "a b", "-x", "x" * 65, "sn/1"):
        with pytest.raises(StoreError, match="serial"):
            fleet_store.add_unit(bad)
    assert token_hash(new) != new and len(token_hash(new)) == 64


def test_a_database_from_a_newer_shore_is_refused(fleet_store: FleetStore, fleet_url: str) -> None:
    engine = create_engine(fleet_url)
    with engine.begin() as conn:
        conn.exec_driver_sql(f"UPDATE {VERSION_TABLE} SET version_num = '9999'")
    engine.dispose()
    with pytest.raises(StoreError, match="newer than this code knows"):
        FleetStore(fleet_url).create_schema()


def test_bad_database_urls_are_one_line_errors() -> None:
    for url, says in (("nonsense", "bad database URL"), ("mysql://x/y", "cannot use|PostgreSQL")):
        with pytest.raises(StoreError, match=says) as err:
            FleetStore(url)
        assert "\n" not in str(err.value)


def test_migration_0006_fills_the_flat_part_of_the_versions_stored_before(
    fleet_store: FleetStore, wire, simulated_fleet
) -> None:
    """Versions stored before 0006 get their flat part (in batches), as ingest keeps it now."""
    from alembic import command
    from sqlalchemy import select

    from recal.fleet.history import flat_version
    from service.fleet.batch import read_batch
    from service.fleet.migrations import alembic_config
    from service.fleet.priors import coefficient_names
    from service.fleet.schema import VersionRow

    sim = simulated_fleet(units=3)
    for serial, rows in sim["units"].items():
        fleet_store.add_unit(serial, "KVH-1750")
        body = json.dumps(wire.batch(serial, rows)).encode()
        fleet_store.ingest(fleet_store.unit_by_serial(serial), read_batch(body, None, 10**8), 0)
    with fleet_store._engine.connect() as conn, conn.begin():
        command.downgrade(alembic_config(conn), "0005")
    assert fleet_store.schema_revision() == "0005"
    fleet_store.create_schema()
    assert fleet_store.schema_revision() == head()
    names = coefficient_names()
    with fleet_store._tx() as s:
        found = s.execute(select(VersionRow.data, VersionRow.flat)).all()
    assert len(found) > 10
    for data, flat in found:
        assert flat == flat_version(data["document"], names) and flat["coefficients"]
