"""Engines per backend: SQLite tuned for one writer and many readers (WAL, foreign keys,
``BEGIN IMMEDIATE`` for writers, one locked connection for ``:memory:``), PostgreSQL with a
connect timeout and pre-ping."""

from __future__ import annotations

import threading
from contextlib import AbstractContextManager, nullcontext
from typing import Any

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.pool import StaticPool

from service.store.codec import dumps

#: The execution option that marks a writer's connection (see :func:`sqlite_on_begin`).
WRITE_OPTION = "recal_write"


def make_engine(url: Any, connect_timeout_s: float) -> tuple[Engine, AbstractContextManager[Any]]:
    """The engine for a parsed URL and the lock its callers take turns with (a no-op but for
    an in-memory SQLite database, which one shared connection holds)."""
    backend = url.get_backend_name()
    if backend == "sqlite":
        memory = url.database in (None, "", ":memory:")
        args: dict[str, Any] = {"check_same_thread": False, "timeout": 30.0}
        lock: AbstractContextManager[Any] = nullcontext()
        if memory:
            # One shared connection holds the whole database; calls take turns on it.
            lock = threading.RLock()
            engine = create_engine(
                url, connect_args=args, poolclass=StaticPool, json_serializer=dumps
            )
        else:
            engine = create_engine(url, connect_args=args, json_serializer=dumps)
        event.listen(engine, "connect", sqlite_on_connect(wal=not memory))
        event.listen(engine, "begin", sqlite_on_begin)
        return engine, lock
    args = {"connect_timeout": max(1, round(connect_timeout_s))} if backend == "postgresql" else {}
    engine = create_engine(url, connect_args=args, pool_pre_ping=True, json_serializer=dumps)
    return engine, nullcontext()


def sqlite_on_connect(wal: bool) -> Any:
    def on_connect(dbapi_conn: Any, _record: Any) -> None:
        # Hand transaction control to SQLAlchemy's "begin" event (pysqlite would defer BEGIN).
        dbapi_conn.isolation_level = None
        cursor = dbapi_conn.cursor()
        cursor.execute("PRAGMA foreign_keys=ON")
        if wal:  # readers never block the writer, and the writer never blocks readers
            cursor.execute("PRAGMA journal_mode=WAL")
        cursor.close()

    return on_connect


def sqlite_on_begin(conn: Any) -> None:
    # IMMEDIATE: a writer waits (busy timeout) for the lock at BEGIN instead of failing later
    # when its read snapshot turns out stale.
    write = conn.get_execution_options().get(WRITE_OPTION, False)
    conn.exec_driver_sql("BEGIN IMMEDIATE" if write else "BEGIN")
