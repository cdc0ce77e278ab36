"""The schema's version: what a database records, whether this code may use it, and bringing
it to this code's version with the migrations (service/migrations)."""

from __future__ import annotations

import time
from collections.abc import Sequence
from contextlib import AbstractContextManager
from typing import Any

from sqlalchemy import Engine, func, inspect, select, text
from sqlalchemy.exc import SQLAlchemyError

from service.store.engine import WRITE_OPTION
from service.store.errors import StoreError, one_line
from service.store.rows import SchemaVersionRow

#: Schema version this code writes, kept by the migrations (service/migrations: revision 0006
#: records 6); a database with a newer one is refused, and so is one at an Alembic revision
#: this code does not know.
SCHEMA_VERSION = 6


def recorded_schema(conn: Any) -> tuple[int | None, list[str]]:
    """The integer schema version and the Alembic revisions a database records."""
    tables = set(inspect(conn).get_table_names())
    found = None
    if SchemaVersionRow.__tablename__ in tables:
        found = conn.execute(select(func.max(SchemaVersionRow.version))).scalar()
    revisions = []
    if "alembic_version" in tables:
        revisions = sorted(conn.execute(text("SELECT version_num FROM alembic_version")).scalars())
    return found, revisions


def require_known(found: int | None, revisions: Sequence[str], url: str) -> None:
    """Refuse (StoreError) a database newer than this code: a higher schema version, or an
    Alembic revision it does not know."""
    if found is not None and found > SCHEMA_VERSION:
        raise StoreError(
            f"database {url} has schema version {found}, newer than this code knows "
            f"({SCHEMA_VERSION}): upgrade fog-recal"
        )
    if revisions:
        from service.migrations import head
        from service.migrations import revisions as known

        unknown = [r for r in revisions if r not in known()]
        if unknown:
            raise StoreError(
                f"database {url} is at schema revision {', '.join(unknown)}, newer than this "
                f"code knows ({head()}): upgrade fog-recal"
            )


def check_on_open(engine: Engine, lock: AbstractContextManager[Any], url: str) -> None:
    """Connect once and refuse a database this code does not know (StoreError)."""
    # SQLite answers "database is locked" at once (no busy wait) when a new connection's
    # WAL set-up meets another process migrating the file: wait for it, as a writer would
    deadline = time.monotonic() + 30.0
    while True:
        try:
            with lock, engine.connect() as conn:
                found, revisions = recorded_schema(conn)
            break
        except SQLAlchemyError as exc:
            line = one_line(exc)
            if "locked" in line and time.monotonic() < deadline:
                time.sleep(0.05)
                continue
            raise StoreError(f"cannot open database {url}: {line}") from None
    require_known(found, revisions, url)


def upgrade(engine: Engine, lock: AbstractContextManager[Any], url: str) -> None:
    """Bring the schema to this code's version with the migrations (idempotent); see
    :meth:`service.store.Store.create_schema`."""
    from alembic import command
    from alembic.util import CommandError

    from service.migrations import LEGACY_REVISIONS, alembic_config

    try:
        with (
            lock,
            engine.execution_options(**{WRITE_OPTION: True}).connect() as conn,
            conn.begin(),
        ):
            if engine.dialect.name == "postgresql":  # two processes starting at once: one migrates
                conn.execute(text("SELECT pg_advisory_xact_lock(7310599)"))
            found, revisions = recorded_schema(conn)
            require_known(found, revisions, url)
            cfg = alembic_config(conn)
            if found is not None and not revisions:
                if found not in LEGACY_REVISIONS:
                    raise StoreError(
                        f"database {url} has schema version {found} but no migration "
                        "record (table alembic_version): cannot upgrade it"
                    )
                command.stamp(cfg, LEGACY_REVISIONS[found])
            command.upgrade(cfg, "head")
    except SQLAlchemyError as exc:
        raise StoreError(f"database {url}: {one_line(exc)}") from exc
    except CommandError as exc:
        raise StoreError(f"database {url}: migration failed: {one_line(exc)}") from exc


def recorded(
    engine: Engine, lock: AbstractContextManager[Any], url: str
) -> tuple[int | None, str | None]:
    """The integer schema version and the Alembic revision recorded, None where absent."""
    try:
        with lock, engine.connect() as conn:
            found, revisions = recorded_schema(conn)
    except SQLAlchemyError as exc:
        raise StoreError(f"database {url}: {one_line(exc)}") from exc
    return found, ",".join(revisions) or None
