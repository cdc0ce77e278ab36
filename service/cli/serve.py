"""``recal serve --config FILE.toml``: the onboard daemon (reader, pipeline, HTTP API)."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "serve",
        help="run the onboard service: read the IMU, find static windows, recalibrate, publish",
        description="Run the daemon described by a TOML config (see service/config.py; every "
        "setting can be overridden with RECAL_* environment variables, e.g. "
        "RECAL_SITE__LATITUDE_DEG=57.7; the API's write token is [api] token or RECAL_API__TOKEN). "
        "Stops cleanly on SIGINT/SIGTERM.",
    )
    p.add_argument("--config", required=True, metavar="FILE.toml")
    p.add_argument("--log-level", default="INFO", choices=("DEBUG", "INFO", "WARNING", "ERROR"))
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    import logging
    import signal
    import sys

    # a stop asked for while loading and checking the settings is a clean exit (run_daemon
    # installs its own handlers before it opens anything)
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: sys.exit(0))

    from service.config import load_settings
    from service.daemon import run_daemon
    from service.startup import check_startup

    logging.basicConfig(level=args.log_level, format="%(asctime)s %(name)s %(message)s")
    settings = load_settings(args.config)
    check_startup(settings)  # a setting this machine cannot honour: one line, exit code 2
    return run_daemon(settings)
