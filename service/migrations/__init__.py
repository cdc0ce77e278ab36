"""Alembic migrations of the Store's schema, shipped inside the package (no ``alembic.ini``).

``Store.create_schema`` (the daemon at start, ``recal demo``) and ``recal db upgrade`` run them
on the Store's own connection through :func:`alembic_config`. Revisions are written by hand in
``versions/`` (explicit ``op`` calls, numbered ``0001``, ``0002``, ...); each one also records
its integer in the ``schema_version`` table, so a release that predates it refuses the database
instead of writing into a schema it does not know. Future ALTERs run in batch mode on SQLite.

A new revision, from a checkout (then edit it, and bump ``SCHEMA_VERSION`` in service/store/schema.py)::

    python -c "from alembic import command; from service.migrations import alembic_config; \\
        command.revision(alembic_config(), 'what it does', rev_id='0003')"
"""

from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import Any

#: This folder: Alembic's ``script_location``.
LOCATION = Path(__file__).resolve().parent
#: The integer ``schema_version`` of databases made before migrations, to the revision whose
#: schema they have (the release at git 612b796 wrote version 1).
LEGACY_REVISIONS: dict[int, str] = {1: "0001"}


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
    """The newest revision: the schema of this code's ORM models."""
    return revisions()[-1]
