"""``recal fleet serve|add-unit|reanalyse --config shore.toml``: the fleet's shore service
(docs/fleet.md).

``serve`` upgrades the shore's schema and serves its API until SIGINT/SIGTERM; ``add-unit
SERIAL`` registers a unit and prints its token alone on one line of stdout (the shore keeps
only its hash: it cannot be shown again; ``--rotate`` issues a new one). ``reanalyse``
re-analyses every unit's history on Dask (service.fleet.reanalysis: a local cluster of
``--workers`` processes, or an existing one at ``--scheduler``), with ``--effects``/``--plugin``
re-fits every unit's windows with and without the effect (service.fleet.workbench), prints a
summary (JSON with ``--json``) and keeps the JSON next to the config for the dashboard's
re-analysis page (``SHORE.reanalysis.json``, docs/fleet.md#fleet-analysis-on-dask).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from service.cli.calibrate import METHODS
from service.cli.serve import SETTINGS_MARK, SettingsHelpFormatter

_CONFIG_HELP = (
    "the shore's TOML settings: database_url, [api] host, port, token (the administrator's); "
    "RECAL_* environment variables override them (RECAL_DATABASE_URL, RECAL_API__TOKEN)"
)


class _ShoreHelpFormatter(SettingsHelpFormatter):
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
        epilog=SETTINGS_MARK,
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
        help="re-analyse every unit on Dask: fleet prior outliers, drift tests, effect refits",
        description="Re-analyse every unit's history on Dask (a local cluster of --workers "
        "processes, or an existing cluster at --scheduler): per model the fleet prior's rates "
        "and each unit's outlier statistic, per unit a drift test of its newest windows against "
        "its current version; with --effects or --plugin, each unit's windows re-fitted with and "
        "without each effect, and per model a verdict (systematic, local, absent). Prints a "
        "summary (JSON with --json, or to -o) and keeps the JSON next to the config "
        "(SHORE.reanalysis.json) for the fleet dashboard's re-analysis page.",
    )
    q.add_argument("--config", required=True, metavar="FILE.toml", help=_CONFIG_HELP)
    q.add_argument("--scheduler", metavar="tcp://HOST:8786",
                   help="an existing Dask cluster's scheduler (its workers need fog-recal, not "
                   "the database); default: a local cluster of --workers processes")  # fmt: skip
    q.add_argument("--workers", type=int, default=os.cpu_count() or 1, metavar="N",
                   help="worker processes of the local cluster (default: the CPUs; 1: in this "
                   "process, no cluster); ignored with --scheduler")  # fmt: skip
    q.add_argument("--model", help="only the units of this model")
    q.add_argument("--windows", type=int, default=200, metavar="N",
                   help="newest windows since a unit's current version its drift test and "
                   "refit read (default 200)")  # fmt: skip
    q.add_argument("--effects", metavar="+NAME,...",
                   help="catalogue or plugin effects to try on every unit's windows (as recal "
                   "calibrate --effects)")  # fmt: skip
    q.add_argument("--plugin", metavar="FILE.py", action="append", default=[],
                   help="Python file defining TERMS = [...] (as recal diagnose --plugin); "
                   "without --effects its terms are the effects tried")  # fmt: skip
    q.add_argument("--method", choices=METHODS, default="lm",
                   help="the refit's method: lm (default), or a swarm repeated --mc times")  # fmt: skip
    q.add_argument("--mc", type=int, default=100, help="Monte Carlo runs for swarms (default 100)")
    q.add_argument("--json", action="store_true", help="print the JSON on stdout")
    q.add_argument("-o", "--output", metavar="OUT.json", help="write the JSON here")
    q.set_defaults(func=run_reanalyse)
    return p


def _settings(args: argparse.Namespace):  # -> ShoreSettings
    from service.fleet.config import load_shore_settings

    return load_shore_settings(args.config)


def _open(settings):  # -> FleetStore
    from service.cli.errors import CliInputError
    from service.fleet.server import open_store
    from service.store.errors import StoreError

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
    from service.store.errors import StoreError

    try:
        return serve(
            _settings(args),
            log_level=args.log_level.lower(),
            reanalysis=reanalysis_path(args.config),
        )
    except StoreError as exc:  # a database that cannot be used: one line, exit code 2
        raise CliInputError(str(exc)) from None


def run_add_unit(args: argparse.Namespace) -> int:
    from service.cli.errors import CliInputError
    from service.store.errors import StoreError

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


def reanalysis_path(config: str) -> Path:
    """Where ``reanalyse`` keeps its newest JSON and ``serve`` reads it: beside the config,
    ``shore.toml`` -> ``shore.reanalysis.json``."""
    p = Path(config)
    return p.with_name(f"{p.stem}.reanalysis.json")


def run_reanalyse(args: argparse.Namespace) -> int:
    import json
    import time

    from service.cli.common import atomic_write, load_plugin, parse_effects, progress_bar, read_text
    from service.cli.errors import CliInputError
    from service.fleet.reanalysis import ClusterError, reanalyse
    from service.store.errors import StoreError

    if args.workers < 1 or args.windows < 2 or args.mc < 1:
        raise CliInputError("--workers and --mc must be at least 1 and --windows at least 2")
    settings = _settings(args)
    plugins = []
    for path in args.plugin:
        load_plugin(path)  # checked here: a mistake in it is one line, before any task
        plugins.append((path, read_text(Path(path), "plugin")))
    _open(settings).close()  # the schema at this code's revision, or a one-line error
    started = time.perf_counter()
    bar = progress_bar(None, "units", unit="unit")  # type: ignore[arg-type]
    try:
        report = reanalyse(settings.database_url, workers=args.workers, model=args.model,
                           windows=args.windows, scheduler=args.scheduler,
                           effects=parse_effects(args.effects), plugins=plugins,
                           method=args.method, mc=args.mc, progress=bar.update)  # fmt: skip
    except (StoreError, ClusterError) as exc:
        raise CliInputError(str(exc)) from None
    finally:
        bar.close()
    text = json.dumps(report, indent=1, allow_nan=False) + "\n"
    atomic_write(str(reanalysis_path(args.config)), text)
    if args.output:
        with open(args.output, "w", encoding="utf-8") as fh:
            fh.write(text)
    if args.json:
        sys.stdout.write(text)
    elif not args.output:
        sys.stdout.write(format_reanalysis(report))
    flagged = sum(u["outlier"] for u in report["units"])
    alarms = sum(u["drift_alarm"] for u in report["units"])
    where = f"the cluster at {args.scheduler}" if args.scheduler else "process(es)"
    found = ""
    for m, by_effect in (report.get("refit") or {}).get("models", {}).items():
        for e, v in by_effect.items():
            found += f"; {e} {v['verdict']} in {m or 'no model'} ({v['significant']}/{v['tested']})"
    print(f"recal fleet: re-analysed {len(report['units'])} units on {report['workers']} {where} "
          f"in {time.perf_counter() - started:.1f} s: {flagged} outliers, {alarms} drift alarms"
          f"{found}", file=sys.stderr)  # fmt: skip
    return 0


def format_reanalysis(report: dict) -> str:
    """The text summary: a line per unit (windows, drift, outlier, each effect's refit), then
    each model's verdict per effect."""

    def fig(v: float | None) -> str:
        return "-" if v is None else f"{v:.3g}"

    lines = []
    for u in report["units"]:
        drift = "-" if u["drift"] is None else ("ALARM" if u["drift_alarm"] else "ok")
        lines.append(f"{u['unit']:20s} {u['model'] or '-':12s} windows {u['windows']:5d}  "
                     f"drift {drift:5s}  outlier {'YES' if u['outlier'] else 'no'}")  # fmt: skip
        refit = u.get("refit")
        if refit and refit.get("error"):
            lines.append(f"  refit: {refit['error']}")
        for e, r in (refit or {}).get("effects", {}).items():
            lines.append(f"  {e}: chi2_red {fig(refit['chi2_red_before'])} -> "
                         f"{fig(r['chi2_red_after'])}, significant "
                         f"{'YES' if r['significant'] else 'no'} (p {fig(r['p_adjusted'])}, "
                         f"dBIC {fig(r['delta_bic'])})")  # fmt: skip
    for m, by_effect in (report.get("refit") or {}).get("models", {}).items():
        for e, v in by_effect.items():
            same = v["homogeneity"]
            tail = "" if same is None else f"; one value? p {fig(same['p_value'])}"
            lines.append(f"model {m or '-'}: {e} {v['verdict']} (significant in "
                         f"{v['significant']} of {v['tested']} units{tail})")  # fmt: skip
    return "\n".join(lines) + "\n"
