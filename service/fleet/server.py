"""``recal fleet serve``: the shore's schema upgraded, then its API served by uvicorn."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from service.fleet.config import ShoreSettings


def open_store(settings: ShoreSettings) -> Any:
    """The shore's store with its schema at this code's revision (the migrations run at every
    start, as the vessel's daemon's do)."""
    from service.fleet.store import FleetStore

    store = FleetStore(settings.database_url)
    try:
        store.create_schema()
    except BaseException:
        store.close()
        raise
    return store


def make_server(
    settings: ShoreSettings, store: Any, log_level: str = "info", reanalysis: Path | None = None
) -> Any:
    """The uvicorn server of the shore API (not started). SIGINT and SIGTERM make it finish
    the requests under way and return normally (uvicorn would re-raise them). ``reanalysis``:
    where ``recal fleet reanalyse`` keeps its JSON (the dashboard's re-analysis page)."""
    import uvicorn

    from service.fleet.api import create_app

    class Server(uvicorn.Server):
        @contextlib.contextmanager
        def capture_signals(self) -> Iterator[None]:
            if threading.current_thread() is not threading.main_thread():
                yield
                return
            sigs = (signal.SIGINT, signal.SIGTERM)
            previous = {sig: signal.signal(sig, self.handle_exit) for sig in sigs}
            try:
                yield
            finally:
                for sig, handler in previous.items():
                    signal.signal(sig, handler)

    app = create_app(store, settings.api)
    app.state.reanalysis_path = reanalysis
    config = uvicorn.Config(
        app,
        host=settings.api.host,
        port=settings.api.port,
        log_level=log_level,
        access_log=False,
        timeout_graceful_shutdown=10,
    )
    return Server(config)


def serve(settings: ShoreSettings, log_level: str = "info", reanalysis: Path | None = None) -> int:
    """Serve until SIGINT or SIGTERM; the exit code. A database that cannot be used raises
    :class:`service.store.errors.StoreError`, a port that cannot be bound a one-line input error."""
    from recal.errors import RecalInputError

    store = open_store(settings)
    server = make_server(settings, store, log_level, reanalysis)
    try:
        server.run()
    except SystemExit as exc:  # uvicorn's answer to a bind failure
        if server.started:
            raise
        api = settings.api
        raise RecalInputError(
            f"[api] port {api.port} on {api.host} cannot be served (already in use?): change "
            "[api] port or stop the other program"
        ) from exc
    finally:
        store.close()
    return 0
