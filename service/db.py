"""The Store's historical import path: ``from service.db import Store, StoreError, ...``.

The Store lives in the :mod:`service.store` package, one idea a module (the repository, the
ORM rows, the records, the conversions, the schema checks, the SQLite tuning); this module
re-exports every name it used to define (its former private helpers too, under their former
names), so callers need not change.
"""

from __future__ import annotations

from service.store.codec import as_utc as _as_utc  # noqa: F401
from service.store.codec import columns_of as _columns_of  # noqa: F401
from service.store.codec import dumps as _dumps  # noqa: F401
from service.store.codec import finite_or_none as _finite_or_none  # noqa: F401
from service.store.codec import plain as _plain  # noqa: F401
from service.store.codec import record_of as _record  # noqa: F401
from service.store.codec import slew_record as _slew_record  # noqa: F401
from service.store.codec import slew_rows as _slew_rows  # noqa: F401
from service.store.engine import sqlite_on_begin as _sqlite_on_begin  # noqa: F401
from service.store.engine import sqlite_on_connect as _sqlite_on_connect  # noqa: F401
from service.store.errors import StoreError, UnknownSessionError
from service.store.errors import one_line as _one_line  # noqa: F401
from service.store.records import CalibrationRecord, SlewRecord, utc_now
from service.store.repository import Store
from service.store.repository import keyed as _keyed  # noqa: F401
from service.store.rows import (
    POSITION_COLUMNS,
    Base,
    CalibrationRow,
    EventRow,
    NoiseFloorRow,
    PositionRow,
    SchemaVersionRow,
    SessionRow,
    SlewRow,
    SpoolBatchRow,
)
from service.store.schema import SCHEMA_VERSION
from service.store.schema import recorded_schema as _recorded_schema  # noqa: F401
from service.store.schema import require_known as _require_known  # noqa: F401

__all__ = [
    "POSITION_COLUMNS",
    "SCHEMA_VERSION",
    "Base",
    "CalibrationRecord",
    "CalibrationRow",
    "EventRow",
    "NoiseFloorRow",
    "PositionRow",
    "SchemaVersionRow",
    "SessionRow",
    "SlewRecord",
    "SlewRow",
    "SpoolBatchRow",
    "Store",
    "StoreError",
    "UnknownSessionError",
    "utc_now",
]
