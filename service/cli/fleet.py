"""``recal fleet serve|add-unit|reanalyse --config shore.toml``: the fleet's shore service
(docs/fleet.md).

``serve`` upgrades the shore's schema and serves its API until SIGINT/SIGTERM; ``add-unit
SERIAL`` registers a unit and prints its token alone on one line of stdout (the shore keeps
only its hash: it cannot be shown again; ``--rotate`` issues a new one). ``reanalyse``
re-analyses every unit's history in parallel processes (service.fleet.reanalysis) and prints
the result as JSON.
"""

from __future__ import annotations

import argparse
import os
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
    q = actions.add_parser(
        "reanalyse",
        help="re-analyse every unit's history: fleet prior outliers, drift tests (JSON)",
        description="Re-analyse every unit's history in parallel processes: per model the "
        "fleet prior's rates and each unit's outlier statistic, per unit a drift test of its "
        "newest windows against its current version. Prints JSON (or writes it to -o).",
    )
    q.add_argument("--config", required=True, metavar="FILE.toml", help=_CONFIG_HELP)
    q.add_argument("--workers", type=int, default=os.cpu_count() or 1, metavar="N",
                   help="processes reading and testing units (default: the CPUs)")  # fmt: skip
    q.add_argument("--model", help="only the units of this model")
    q.add_argument("--windows", type=int, default=200, metavar="N",
                   help="newest windows since a unit's current version its drift test reads "
                   "(default 200)")  # fmt: skip
    q.add_argument("-o", "--output", metavar="OUT.json", help="write the JSON here, not stdout")
    q.set_defaults(func=run_reanalyse)
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


def run_reanalyse(args: argparse.Namespace) -> int:
    import json
    import time

    from service.cli.errors import CliInputError
    from service.db import StoreError
    from service.fleet.reanalysis import reanalyse

    if args.workers < 1 or args.windows < 2:
        raise CliInputError("--workers must be at least 1 and --windows at least 2")
    settings = _settings(args)
    _open(settings).close()  # the schema at this code's revision, or a one-line error
    started = time.perf_counter()
    try:
        report = reanalyse(settings.database_url, workers=args.workers,
                           model=args.model, windows=args.windows)  # fmt: skip
    except StoreError as exc:
        raise CliInputError(str(exc)) from None
    text = json.dumps(report, indent=1) + "\n"
    if args.output:
        with open(args.output, "w", encoding="utf-8") as fh:
            fh.write(text)
    else:
        sys.stdout.write(text)
    flagged = sum(u["outlier"] for u in report["units"])
    alarms = sum(u["drift_alarm"] for u in report["units"])
    print(f"recal fleet: re-analysed {len(report['units'])} units on {args.workers} process(es) "
          f"in {time.perf_counter() - started:.1f} s: {flagged} outliers, {alarms} drift alarms",
          file=sys.stderr)  # fmt: skip
    return 0
