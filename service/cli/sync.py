"""``recal sync --config FILE.toml``: send what the outbox holds to the shore now, until it is
empty.

The daemon sends its outbox by itself (``[sync]``, docs/fleet.md); this command is for the
times a person wants it done and to know it is done: in port before a long passage, after
``recal serve`` was stopped, or to try a new token. It uses the daemon's own sync client, so
delivery is the same (at least once, stored once on shore) and running it beside a daemon on
the same database is safe. It adds no rows of its own: what happened goes to stderr, a summary
to stdout (``--json``: one object).

Exit codes: 0 the outbox is empty; 2 bad input (no ``[sync]`` section, no database); 1 the
outbox is not empty at ``--timeout`` (the link is down or the shore refuses: the last error is
printed).
"""

from __future__ import annotations

import argparse
import json
import sys
import time


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "sync",
        help="send the outbox to the shore now, until it is empty (docs/fleet.md)",
        description=__doc__.splitlines()[0].replace("``", ""),
    )
    p.add_argument("--config", metavar="FILE.toml", required=True,
                   help="the daemon's TOML config: its database_url and [sync] section")  # fmt: skip
    p.add_argument("--timeout", type=float, default=600.0, metavar="S",
                   help="give up after S seconds with rows still to send (default 600)")  # fmt: skip
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from service.cli.db import open_vessel_store
    from service.cli.errors import CliInputError
    from service.config import load_settings
    from service.store.errors import StoreError
    from service.sync.loop import SyncThread

    if not args.timeout > 0:
        raise CliInputError(f"--timeout must be > 0 s, not {args.timeout:g}")
    settings = load_settings(args.config)
    if settings.sync.url is None:
        raise CliInputError(f"{args.config} has no [sync] section (url, unit, token): nothing "
                            "to send to")  # fmt: skip
    args.database = None
    store = open_vessel_store(args, create=False)
    client = SyncThread.from_settings(store, settings.sync, backoff_cap_s=10.0)
    t0 = time.monotonic()
    try:
        start = store.outbox_count()
        left = _drain(client, store, start, t0 + args.timeout)
    except StoreError as exc:
        raise CliInputError(str(exc)) from None
    finally:
        client.stop(wait_s=0)
        store.close()
    health = client.health(left)
    summary = {
        "unit": settings.sync.unit,
        "url": settings.sync.url,
        "rows_at_start": start,
        "rows_sent": start - left if left <= start else None,
        "backlog": left,
        "batches": client.batches,
        "seconds": round(time.monotonic() - t0, 3),
        "state": health["state"],
        "last_error": health["last_error"],
    }
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"{settings.sync.unit}: {summary['batches']} batch(es) acknowledged by "
              f"{settings.sync.url}, {left} row(s) left in the outbox")  # fmt: skip
    if left:
        print(f"recal sync: {left} row(s) still to send after {args.timeout:g} s: "
              f"{health['last_error'] or 'the link is slow'}", file=sys.stderr)  # fmt: skip
        return 1
    return 0


def _drain(client, store, start: int, deadline: float) -> int:  # noqa: ANN001 - see run
    """Step the sync client until the outbox is empty or ``deadline`` passes; the rows left."""
    from service.cli.common import progress_bar

    left = start
    with progress_bar(total=start, unit="row", desc="sync") as bar:
        while left and time.monotonic() < deadline:
            wait = client.step()
            now_left = store.outbox_count()
            bar.update(max(0, left - now_left))
            left = now_left
            if left and wait > 0:
                time.sleep(min(wait, max(0.0, deadline - time.monotonic())))
    return left
