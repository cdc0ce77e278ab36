"""Alembic migrations of the shore's schema (service.fleet.schema), shipped in the package.

The vessel's pattern (service/migrations): no ``alembic.ini``, revisions written by hand in
``versions/`` and run on the store's own connection inside one transaction
(:meth:`service.fleet.store.FleetStore.create_schema`, at every ``recal fleet serve`` and
``add-unit``). The revision is kept in its own table, :data:`VERSION_TABLE`, so the shore can
share a database with the vessel's schema (``alembic_version``) or anything else.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import Any

#: This folder: Alembic's ``script_location``.
LOCATION = Path(__file__).resolve().parent
#: Where the shore's revision is recorded.
VERSION_TABLE = "fleet_alembic_version"


def alembic_config(connection: Any = None, url: str | None = None) -> Any:
    """An ``alembic.config.Config`` for this folder; ``env.py`` migrates ``connection`` (inside
    its transaction) or else opens ``url``."""
    from alembic.config import Config

    cfg = Config()
    cfg.set_main_option("script_location", str(LOCATION).replace("%", "%%"))
    if url is not None:
        cfg.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    cfg.attributes["connection"] = connection
    return cfg


@cache
def revisions() -> tuple[str, ...]:
    """Every revision this code knows, oldest first (the last one is the head)."""
    from alembic.script import ScriptDirectory

    script = ScriptDirectory.from_config(alembic_config())
    return tuple(s.revision for s in reversed(list(script.walk_revisions())))


def head() -> str:
    return revisions()[-1]
