"""The daemon: reader thread + pipeline + HTTP API in one process, with a clean shutdown.

``uvicorn.Server`` owns the main thread and the signals (SIGINT/SIGTERM end it gracefully);
the serial reader runs in its own thread and hands frames to the pipeline; calibrations run in
a worker process. Under systemd (``Type=notify``) the daemon reports READY=1 once it serves and
pings the watchdog while the reader is healthy.
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
from service.pipeline import Ingest, Scheduler, detector_config

log = logging.getLogger("recal.daemon")


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
    reader: Any = None
    started: float = field(default_factory=time.monotonic)

    def health(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "session": self.session_id,
            "uptime_s": time.monotonic() - self.started,
            "frames": self.ingest.frames,
            "windows": self.ingest.windows,
            "recalibrating": self.scheduler.busy,
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

    def close(self) -> None:
        self.publisher.close()  # ends open /events streams
        if self.reader is not None:
            self.reader.stop()
        self.ingest.flush()
        self.scheduler.wait(timeout=120)
        self.scheduler.shutdown()


def build_service(settings: Settings, with_reader: bool = True, executor: Any = None) -> Service:
    """Open the store, the publisher, the pipeline and (optionally) the serial reader."""
    from service.db import Store
    from service.publish import Publisher

    store = Store(settings.database_url)
    store.create_schema()
    publisher = Publisher(settings.publish_path)
    session_id = store.add_session(source=settings.device.url, meta=settings.model_dump())
    scheduler = Scheduler(store, settings, publisher, executor)
    ingest = Ingest(store, session_id, detector_config(settings), scheduler.notify)
    service = Service(settings, store, publisher, scheduler, ingest, session_id)
    if with_reader:
        from drivers import DecoderConfig, FrameReader

        d = settings.device
        config = DecoderConfig(gyro_output=d.gyro_output, gyro_units=d.gyro_units,
                               temperature_units=d.temperature_units, rate_hz=d.rate_hz)  # fmt: skip
        service.reader = FrameReader(d.url, d.format, config, on_batch=ingest.feed,
                                     baudrate=d.baudrate)  # fmt: skip
    store.add_event("start", f"service started, reading {settings.device.url}")
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
                     health=service.health)  # fmt: skip
    api = service.settings.api
    # open /events streams would hold a graceful shutdown forever: give them a few seconds
    config = uvicorn.Config(app, host=api.host, port=api.port, log_level="warning",
                            timeout_graceful_shutdown=3)  # fmt: skip
    return Server(config)


def run_daemon(settings: Settings) -> int:
    """Serve until SIGINT/SIGTERM. Returns the process exit code."""
    service = build_service(settings)
    server = make_server(service)
    stop = threading.Event()

    def watchdog() -> None:
        while not server.started:  # READY=1 as soon as the API answers
            if stop.wait(0.1):
                return
        sd_notify("READY=1")
        beat = 0
        while not stop.wait(1.0):
            service.ingest.poll()  # frames held while the stream pauses still get detected
            beat += 1
            if beat % 5 == 0 and (service.reader is None or service.reader.health().running):
                sd_notify("WATCHDOG=1")  # pet the watchdog while the reader thread lives

    service.reader.start()
    threading.Thread(target=watchdog, name="watchdog", daemon=True).start()
    log.info("serving on http://%s:%d", settings.api.host, settings.api.port)
    try:
        server.run()
    finally:
        stop.set()
        sd_notify("STOPPING=1")
        service.store.add_event("stop", "service stopping")
        service.close()
    return 0
