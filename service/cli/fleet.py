"""``recal fleet serve|add-unit --config shore.toml``: the fleet's shore service (docs/fleet.md).

``serve`` upgrades the shore's schema and serves its API until SIGINT/SIGTERM; ``add-unit
SERIAL`` registers a unit and prints its token alone on one line of stdout (the shore keeps
only its hash: it cannot be shown again; ``--rotate`` issues a new one).
"""

from __future__ import annotations

import argparse
import sys

from service.cli.serve import _SETTINGS, _SettingsHelpFormatter

_CONFIG_HELP = (
    "the shore's TOML settings: database_url, [api] host, port, token (the administrator's); "
    "RECAL_* environment variables override them (RECAL_DATABASE_URL, RECAL_API__TOKEN)"
)


class _ShoreHelpFormatter(_SettingsHelpFormatter):
    settings_cls = "service.fleet.config:ShoreSettings"


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "fleet",
        help="the fleet's shore service: serve it, register units",
        description=__doc__.splitlines()[0].replace("``", ""),
    )
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    q = actions.add_parser(
        "serve",
        help="upgrade the shore's schema and serve its API (POST /fleet/ingest, GET /fleet/...)",
        description="Upgrade the shore's database schema, then serve its HTTP API until "
        "SIGINT/SIGTERM.",
        epilog=_SETTINGS,
        formatter_class=_ShoreHelpFormatter,
    )
    q.add_argument("--config", required=True, metavar="FILE.toml", help=_CONFIG_HELP)
    q.add_argument("--log-level", default="INFO", choices=("DEBUG", "INFO", "WARNING", "ERROR"),
                   help="messages logged on stderr from this level up (default INFO)")  # fmt: skip
    q.set_defaults(func=run_serve)
    q = actions.add_parser(
        "add-unit",
        help="register a unit and print its token",
        description="Register a unit and print its token, alone on one line of stdout (the "
        "token is shown once: the shore keeps its hash). Give it to the vessel as [sync] token.",
    )
    q.add_argument("serial", metavar="SERIAL", help="the unit's serial, unique in the fleet")
    q.add_argument("--config", required=True, metavar="FILE.toml", help=_CONFIG_HELP)
    q.add_argument("--model", help="the unit's model (e.g. KVH-1750), for the fleet's queries")
    q.add_argument("--rotate", action="store_true",
                   help="the unit is registered: issue a new token (the old one stops working)")  # fmt: skip
    q.set_defaults(func=run_add_unit)
    return p


def _settings(args: argparse.Namespace):  # -> ShoreSettings
    from service.fleet.config import load_shore_settings

    return load_shore_settings(args.config)


def _open(settings):  # -> FleetStore
    from service.cli.errors import CliInputError
    from service.db import StoreError
    from service.fleet.server import open_store

    try:
        return open_store(settings)
    except StoreError as exc:
        raise CliInputError(str(exc)) from None


def run_serve(args: argparse.Namespace) -> int:
    import logging

    from service.fleet.server import serve

    logging.basicConfig(level=args.log_level, format="%(asctime)s %(name)s %(message)s")
    logging.getLogger("alembic.runtime.plugins").setLevel(logging.WARNING)
    from service.cli.errors import CliInputError
    from service.db import StoreError

    try:
        return serve(_settings(args), log_level=args.log_level.lower())
    except StoreError as exc:  # a database that cannot be used: one line, exit code 2
        raise CliInputError(str(exc)) from None


def run_add_unit(args: argparse.Namespace) -> int:
    from service.cli.errors import CliInputError
    from service.db import StoreError

    store = _open(_settings(args))
    try:
        token = store.add_unit(args.serial, args.model, rotate=args.rotate)
    except StoreError as exc:
        raise CliInputError(str(exc)) from None
    finally:
        store.close()
    what = "new token of" if args.rotate else "registered"
    print(f"recal fleet: {what} unit {args.serial}; its token follows on stdout", file=sys.stderr)
    print(token)
    return 0
