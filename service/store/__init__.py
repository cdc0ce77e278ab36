"""The Store and what it is made of, one idea a module.

- :mod:`~service.store.repository`: :class:`Store`, the repository (every read and write);
- :mod:`~service.store.rows`: the ORM rows, one class per table;
- :mod:`~service.store.records`: the plain records the Store hands out (``CalibrationRecord``,
  ``SlewRecord``);
- :mod:`~service.store.codec`: conversions between records, columns and rows (JSON, UTC, slews);
- :mod:`~service.store.schema`: the schema version, refusing newer databases, migrating;
- :mod:`~service.store.engine`: engines per backend (SQLite's WAL, locking and pragmas);
- :mod:`~service.store.errors`: ``StoreError`` and its one-line messages.

``service.db``, the 0.2.0 path, forwards the names with a DeprecationWarning until 0.3.0
(service.moved).
"""

from __future__ import annotations

from service.store.errors import StoreError, UnknownSessionError
from service.store.records import CalibrationRecord, SlewRecord, utc_now
from service.store.repository import Store
from service.store.rows import POSITION_COLUMNS, Base
from service.store.schema import SCHEMA_VERSION

__all__ = [
    "POSITION_COLUMNS",
    "SCHEMA_VERSION",
    "Base",
    "CalibrationRecord",
    "SlewRecord",
    "Store",
    "StoreError",
    "UnknownSessionError",
    "utc_now",
]
