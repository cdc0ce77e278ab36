"""Alembic environment: migrates the connection :func:`service.migrations.alembic_config` was
given (the caller owns its transaction), else the ``sqlalchemy.url`` option."""

from __future__ import annotations

from alembic import context
from sqlalchemy import create_engine

from service.store.rows import Base

config = context.config
options = {
    "target_metadata": Base.metadata,  # for `alembic revision --autogenerate` by developers
    "render_as_batch": True,  # SQLite cannot ALTER most things: copy-and-move tables instead
    "compare_type": True,
}


def run_offline() -> None:
    context.configure(url=config.get_main_option("sqlalchemy.url"), literal_binds=True, **options)
    with context.begin_transaction():
        context.run_migrations()


def run_online() -> None:
    connection = config.attributes.get("connection")
    if connection is not None:
        # inside the caller's transaction: the whole upgrade commits or rolls back as one
        # (SQLite included: the Store issues BEGIN itself, so its DDL is transactional too)
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
