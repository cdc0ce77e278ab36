"""``recal db upgrade|current``: migrate the service's database, or show its schema revision.

The daemon upgrades the database itself at start; ``recal db upgrade`` does it beforehand (a
maintenance window, a database shared by several units). Both print the revision on stdout
(``0002 (head)``), what happened on stderr.
"""

from __future__ import annotations

import argparse
import sys

_URL_HELP = "database URL, e.g. sqlite:///var/lib/recal/recal.db (default: the --config file's)"
_CONFIG_HELP = (
    "the service's TOML config (as for recal serve): its database_url, RECAL_DATABASE_URL "
    "overriding it"
)


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "db",
        help="upgrade the database schema (migrations) or show its revision",
        description=__doc__.splitlines()[0].replace("``", ""),
    )
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    for name, func, text in (
        ("upgrade", run_upgrade, "bring the schema to this version's head revision (idempotent)"),
        ("current", run_current, "show the schema revision of the database, change nothing"),
    ):
        q = actions.add_parser(name, help=text, description=text[0].upper() + text[1:] + ".")
        q.add_argument("--database", metavar="URL", help=_URL_HELP)
        q.add_argument("--config", metavar="FILE.toml", help=_CONFIG_HELP)
        q.set_defaults(func=func)
    return p


def _url(args: argparse.Namespace) -> str:
    import os

    from service.cli.errors import CliInputError

    if args.database:
        return args.database
    if args.config:
        from service.config import load_settings

        return load_settings(args.config).database_url
    if os.environ.get("RECAL_DATABASE_URL"):
        return os.environ["RECAL_DATABASE_URL"]
    raise CliInputError("no database: give --database URL or --config FILE.toml")


def open_vessel_store(args: argparse.Namespace, create: bool):  # -> Store
    """The Store of the URL; a StoreError or an unusable SQLite path is bad input (exit 2)."""
    from pathlib import Path

    from service.cli.errors import CliInputError
    from service.startup import check_sqlite_folder, sqlite_folder
    from service.store.errors import StoreError
    from service.store.repository import Store

    url = _url(args)
    folder = sqlite_folder(url)
    if folder is not None:
        from sqlalchemy.engine import make_url

        path = Path(make_url(url).database).absolute()
        if not create and not path.is_file():  # opening would create an empty file
            raise CliInputError(f"database file {path} does not exist")
        check_sqlite_folder(folder)
    try:
        return Store(url)
    except StoreError as exc:
        raise CliInputError(str(exc)) from None


def _describe(version: int | None, revision: str | None) -> str:
    from service.migrations import head

    if revision == head():
        return f"{revision} (head)"
    if revision is not None:
        return f"{revision} (head is {head()}: run recal db upgrade)"
    if version is None:
        return "none (empty database: run recal db upgrade)"
    return f"none (schema version {version}, made before migrations: run recal db upgrade)"


def run_upgrade(args: argparse.Namespace) -> int:
    import logging

    from service.cli.errors import CliInputError
    from service.store.errors import StoreError

    store = open_vessel_store(args, create=True)
    log = logging.getLogger("alembic.runtime.migration")  # "Running upgrade 0001 -> 0002, ..."
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("recal db: %(message)s"))
    handler.addFilter(lambda record: record.getMessage().startswith("Running"))
    log.addHandler(handler)
    log.setLevel(logging.INFO)
    try:
        before = store.schema_revision()
        store.create_schema()
        after = store.schema_revision()
    except StoreError as exc:
        raise CliInputError(str(exc)) from None
    finally:
        log.removeHandler(handler)
        store.close()
    what = "already at" if before == after else f"upgraded from {before or 'none'} to"
    print(f"recal db: {store.url}: {what} {after}", file=sys.stderr)
    print(f"{after} (head)")
    return 0


def run_current(args: argparse.Namespace) -> int:
    from service.cli.errors import CliInputError
    from service.store.errors import StoreError

    store = open_vessel_store(args, create=False)
    try:
        print(_describe(*store.recorded_schema()))
    except StoreError as exc:
        raise CliInputError(str(exc)) from None
    finally:
        store.close()
    return 0
