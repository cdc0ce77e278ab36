"""The daemon: reader thread + pipeline + HTTP API in one process, with a clean shutdown.

``uvicorn.Server`` owns the main thread and the signals (SIGINT/SIGTERM end it gracefully);
the serial reader runs in its own thread and hands frames to the pipeline; calibrations run in
a supervised worker process. Under systemd (``Type=notify``) the daemon reports READY=1 once it
serves and pets the watchdog only while every part is alive: the reader thread, the detector
(frames that arrive are processed), the job supervisor and the housekeeping loop itself. A part
that is alive but failing (device unplugged, database down, publish file unwritable) makes
``/health`` say ``degraded`` with the reason; restarting would not mend those.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import socket
import threading
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from typing import Any

from service.config import Settings
from service.events import Events
from service.pipeline import FloorKeeper, Ingest, Scheduler, detector_config, window_frames

log = logging.getLogger("recal.daemon")

#: How often the published file is compared with the database, s.
SYNC_EVERY_S = 10.0


def sd_notify(message: str) -> bool:
    """Send a datagram to systemd's NOTIFY_SOCKET (no-op without it). Returns True if sent."""
    addr = os.environ.get("NOTIFY_SOCKET")
    if not addr:
        return False
    if addr.startswith("@"):  # abstract namespace
        addr = "\0" + addr[1:]
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
            sock.connect(addr)
            sock.sendall(message.encode())
        return True
    except OSError:
        return False


@dataclass
class Service:
    """The wired-up parts of a running service (also what tests and the demo drive)."""

    settings: Settings
    store: Any
    publisher: Any
    scheduler: Scheduler
    ingest: Ingest
    session_id: int
    events: Events
    reader: Any = None
    started: float = field(default_factory=time.monotonic)
    last_tick: float = field(default_factory=time.monotonic)
    last_sync: float = field(default_factory=time.monotonic)

    def problems(self) -> list[str]:
        """Why the service is degraded, in plain words (empty when all is well)."""
        out = []
        if self.reader is not None:
            h = self.reader.health()
            if not h.running:
                out.append("reader: the reader thread has stopped")
            elif getattr(h, "problem", None):  # disconnected, or connected but silent
                out.append(f"reader: {self.settings.device.url}: {h.problem}")
            elif not h.connected:
                out.append(f"reader: device {self.settings.device.url} is not connected"
                           + (f" ({h.last_error})" if h.last_error else ""))  # fmt: skip
        if self.ingest.store_error is not None:
            out.append(f"database: {self.ingest.spooled} window(s) waiting to be stored "
                       f"({self.ingest.store_error})")  # fmt: skip
        if not self.scheduler.alive:
            out.append("scheduler: the job supervisor is not running")
        if self.publisher.error is not None:
            out.append(f"publisher: {self.publisher.error}")
        return out

    def alive(self) -> bool:
        """Every thread the service needs runs and makes progress (what the watchdog reports)."""
        reader_ok = self.reader is None or self.reader.health().running
        held = self.ingest.frames_waiting_s()
        detector_ok = held is None or held < 30.0  # frames are not piling up unprocessed
        return reader_ok and detector_ok and self.scheduler.alive

    def health(self) -> dict[str, Any]:
        problems = self.problems()
        out: dict[str, Any] = {
            "status": "degraded" if problems else "ok",
            "problems": problems,
            "session": self.session_id,
            "uptime_s": time.monotonic() - self.started,
            "frames": self.ingest.frames,
            "windows": self.ingest.windows,
            "windows_spooled": self.ingest.spooled,
            "windows_dropped": self.ingest.windows_dropped,
            "slews": self.ingest.slews,
            "slews_dropped": dict(self.ingest.slews_dropped),
            "recalibrating": self.scheduler.busy,
            "scheduler": self.scheduler.health(),
            "detector": self.ingest.detector_health(),
            "publisher": {
                "path": str(self.publisher.path),
                "version": None
                if self.publisher.latest is None
                else self.publisher.latest.get("version"),
                "error": self.publisher.error,
            },
            "events_unstored": self.events.unstored,
        }
        if self.reader is not None:
            h = self.reader.health()
            out["reader"] = {
                "connected": h.connected,
                "running": h.running,
                "reconnect_count": h.reconnect_count,
                "seconds_since_last_frame": None
                if h.last_frame_time is None
                else time.monotonic() - h.last_frame_time,
                "last_error": h.last_error,
                "diagnosis": h.diagnosis,
                "counters": asdict(h.counters),
            }
        return out

    def tick(self) -> None:
        """Housekeeping, about once a second: detect held frames, retry spooled windows and
        failed publications, rerun a job whose result could not be stored."""
        self.last_tick = time.monotonic()
        self.ingest.poll()
        self.scheduler.tick()
        if self.publisher.error is not None or self._due_sync():
            self.sync_published()

    def _due_sync(self) -> bool:
        # the file is compared with the database every 10 s: an edited or deleted file returns
        return self.last_tick - self.last_sync >= SYNC_EVERY_S

    def sync_published(self) -> None:
        from service.db import StoreError

        try:
            current = self.store.current()
        except StoreError:
            return
        self.last_sync = time.monotonic()
        before = self.publisher.error
        if self.publisher.sync(current) and current is not None:
            self.events.emit("publish", f"version {current.version} written to "
                             f"{self.publisher.path}", {"version": current.version})  # fmt: skip
        elif self.publisher.error is not None and before is None:
            self.events.emit("publish", self.publisher.error, level=logging.ERROR)

    def close(self, wait_s: float | None = None) -> None:
        """Stop reading, store the open window, let a running job finish (up to
        ``scheduler.stop_wait_s``) or abandon it, and release everything."""
        self.publisher.close()  # ends open /events streams
        self.scheduler.stop_starting()  # the flush below may store windows: they start nothing
        if self.reader is not None:
            self.reader.stop()
        try:
            self.ingest.flush()
        except Exception:  # noqa: BLE001 - shutting down: keep going, the log has it
            log.exception("flushing the detector at shutdown failed")
        wait = self.settings.scheduler.stop_wait_s if wait_s is None else wait_s
        self.scheduler.shutdown(wait_s=wait)
        self.store.close()


def _safe_meta(settings: Settings) -> dict[str, Any]:
    """The settings as stored with the session: without secrets."""
    meta = settings.model_dump(mode="json")
    meta.get("api", {}).pop("token", None)
    return meta


def build_service(settings: Settings, with_reader: bool = True, runner: Any = None) -> Service:
    """Open the store, the publisher, the pipeline and (optionally) the serial reader."""
    from service.db import Store
    from service.publish import Publisher

    publisher = Publisher(settings.publish_path)  # checks the path first: nothing opened yet
    store = Store(settings.database_url)
    try:
        store.create_schema()
        events = Events(store)
        session_id = store.add_session(source=settings.device.url, meta=_safe_meta(settings))
        scheduler = Scheduler(store, settings, publisher, events, runner)
    except BaseException:
        store.close()
        raise
    config = detector_config(settings)
    d = settings.device
    device = f"{d.url} {d.format} {d.rate_hz:g} Hz"
    keeper = FloorKeeper(store, device, events, window_frames(config, d.rate_hz))
    ingest = Ingest(store, session_id, config, scheduler.notify, events, keeper,
                    settings.detector.learn_s)  # fmt: skip
    service = Service(settings, store, publisher, scheduler, ingest, session_id, events)
    if with_reader:
        from drivers import DecoderConfig, FrameReader

        d = settings.device
        config = DecoderConfig(gyro_output=d.gyro_output, gyro_units=d.gyro_units,
                               temperature_units=d.temperature_units, rate_hz=d.rate_hz)  # fmt: skip
        service.reader = FrameReader(d.url, d.format, config, on_batch=ingest.feed,
                                     baudrate=d.baudrate)  # fmt: skip
    events.emit("start", f"service started, reading {settings.device.url}",
                {"session": session_id})  # fmt: skip
    service.sync_published()  # the file follows the database from the first second
    return service


def make_server(service: Service) -> Any:
    """The uvicorn server for the service's HTTP API (not started).

    SIGINT and SIGTERM make it stop serving and return normally (uvicorn would re-raise them,
    and a re-raised SIGTERM kills the process before the pipeline is flushed and closed).
    """
    import uvicorn

    from service.api import create_app

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

    app = create_app(service.store, service.publisher, trigger=service.scheduler.trigger,
                     health=service.health, api=service.settings.api)  # fmt: skip
    api = service.settings.api
    # open /events streams would hold a graceful shutdown forever: give them a few seconds
    config = uvicorn.Config(app, host=api.host, port=api.port, log_level="warning",
                            timeout_graceful_shutdown=3)  # fmt: skip
    return Server(config)


def run_server(server: Any, api: Any) -> None:
    """``server.run()``; a bind failure (the port taken since the start-up check) becomes the
    one-line input error instead of uvicorn's ``sys.exit(1)``."""
    from recal.errors import RecalInputError

    try:
        server.run()
    except SystemExit as exc:
        if server.started:
            raise
        raise RecalInputError(
            f"[api] port {api.port} on {api.host} cannot be served (already in use?): change "
            "[api] port or stop the other program"
        ) from exc


def run_daemon(settings: Settings) -> int:
    """Serve until SIGINT/SIGTERM (at any moment, start-up included). Returns the exit code."""
    stop = threading.Event()
    holder: dict[str, Any] = {}

    def on_signal(*_: Any) -> None:
        # A stop asked for while the service is still starting is honoured once it has started
        # (uvicorn installs its own handlers while it serves, and restores this one after).
        stop.set()
        if "server" in holder:
            holder["server"].should_exit = True

    for sig in _STOP_SIGNALS:
        signal.signal(sig, on_signal)
    service = build_service(settings)
    server = holder["server"] = make_server(service)
    if stop.is_set():
        server.should_exit = True

    def housekeeping() -> None:
        while not server.started and not stop.is_set():  # READY=1 as soon as the API answers
            if stop.wait(0.1):
                return
        sd_notify("READY=1")
        service.events.emit("ready", f"serving on http://{settings.api.host}:{settings.api.port}")
        try:
            service.scheduler.resume()
        except Exception:  # noqa: BLE001 - e.g. the database is down: the next tick retries
            log.exception("resuming jobs at start failed")
        beat = 0
        while not stop.wait(1.0):
            try:
                service.tick()
            except Exception:  # noqa: BLE001 - one bad tick must not end housekeeping
                log.exception("housekeeping failed")
            beat += 1
            if beat % 5 == 0 and service.alive():
                sd_notify("WATCHDOG=1")  # only while every part is alive

    service.reader.start()
    threading.Thread(target=housekeeping, name="housekeeping", daemon=True).start()
    try:
        run_server(server, settings.api)
    finally:
        stop.set()
        sd_notify("STOPPING=1")
        service.events.emit("stop", "service stopping")
        service.close()
    return 0


_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
