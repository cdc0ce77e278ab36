"""Alembic environment of the shore: migrates the connection :func:`alembic_config` was given
(the caller owns its transaction), else the ``sqlalchemy.url`` option; the revision goes to
``fleet_alembic_version``."""

from __future__ import annotations

from alembic import context
from sqlalchemy import create_engine

from service.fleet.migrations import VERSION_TABLE
from service.fleet.schema import FleetBase

config = context.config
options = {
    "target_metadata": FleetBase.metadata,  # `alembic revision --autogenerate` by developers
    "version_table": VERSION_TABLE,
    "render_as_batch": True,
    "compare_type": True,
    # autogenerate looks at the shore's tables only, whatever else shares the database
    "include_name": lambda name, type_, _parent: type_ != "table" or name.startswith("fleet_"),
}


def run_offline() -> None:
    context.configure(url=config.get_main_option("sqlalchemy.url"), literal_binds=True, **options)
    with context.begin_transaction():
        context.run_migrations()


def run_online() -> None:
    connection = config.attributes.get("connection")
    if connection is not None:
        context.configure(connection=connection, transactional_ddl=True, **options)
        with context.begin_transaction():
            context.run_migrations()
        return
    engine = create_engine(config.get_main_option("sqlalchemy.url"))
    try:
        with engine.connect() as conn:
            context.configure(connection=conn, **options)
            with context.begin_transaction():
                context.run_migrations()
    finally:
        engine.dispose()


if context.is_offline_mode():
    run_offline()
else:
    run_online()
