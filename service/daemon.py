"""The daemon: reader thread + pipeline + HTTP API in one process, with a clean shutdown.

``uvicorn.Server`` owns the main thread and the signals (SIGINT/SIGTERM end it gracefully);
the serial reader runs in its own thread and hands frames to the pipeline; calibrations run in
a supervised worker process. Under systemd (``Type=notify``) the daemon reports READY=1 once it
serves and pets the watchdog only while every part is alive: the reader thread, the detector
(frames that arrive are processed), the job supervisor, the publisher (not closed), the HTTP
server (its event loop runs), the fleet sync thread (with ``[sync]``) and the housekeeping loop
itself. A dead part stops the petting,
is named in ``/health`` (``problems`` and ``service.dead_parts``) and in a ``STATUS=`` line to
systemd, and systemd restarts the service once ``WatchdogSec`` has passed. A part that is alive
but failing (device unplugged, database down, publish file unwritable) makes ``/health`` say
``degraded`` with the reason but does not stop the petting: restarting would not mend those.
"""

from __future__ import annotations

import asyncio
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

from recal.errors import RecalInputError
from service.config import Settings
from service.events import Events
from service.ingest.floor_keeper import FloorKeeper
from service.ingest.setup import detector_config, rest_reference, window_frames
from service.ingest.thread import IngestThread
from service.pipeline import Ingest
from service.scheduler import Scheduler

log = logging.getLogger("recal.daemon")

#: How often the published file is compared with the database, s.
SYNC_EVERY_S = 10.0
#: How often the watchdog is petted when systemd gives no WatchdogSec, s (and the longest).
WATCHDOG_EVERY_S = 5.0
#: The HTTP server counts as hung when its event loop has not ticked for this long, s
#: (uvicorn ticks every 0.1 s).
API_STALL_S = 5.0
#: The detector counts as stuck when a frame has waited this long to be processed, s.
DETECTOR_STALL_S = 30.0


def sd_notify(message: str) -> bool:
    """Send a datagram to systemd's NOTIFY_SOCKET (no-op without it). Returns True if sent.

    Never blocks: a receiver whose queue is full (``net.unix.max_dgram_qlen`` datagrams) loses
    this one rather than stall housekeeping."""
    addr = os.environ.get("NOTIFY_SOCKET")
    if not addr:
        return False
    if addr.startswith("@"):  # abstract namespace
        addr = "\0" + addr[1:]
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
            sock.setblocking(False)
            sock.connect(addr)
            sock.sendall(message.encode())
        return True
    except OSError:
        return False


def watchdog_interval_s() -> float:
    """How often to pet the watchdog, s: half of systemd's ``WatchdogSec`` (``WATCHDOG_USEC``,
    when it is meant for this process: ``WATCHDOG_PID`` unset or ours), at most
    :data:`WATCHDOG_EVERY_S`."""
    usec = os.environ.get("WATCHDOG_USEC", "")
    pid = os.environ.get("WATCHDOG_PID", "")
    if not usec.isdigit() or int(usec) == 0 or (pid and pid != str(os.getpid())):
        return WATCHDOG_EVERY_S
    return min(WATCHDOG_EVERY_S, int(usec) / 2e6)


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
    #: The uvicorn server of the API (set by :func:`make_server`); None: no API to watch.
    server: Any = None
    #: The thread between the reader and :attr:`ingest` (None without a reader).
    feeder: Any = None
    #: The fleet sync thread (service.sync.SyncThread; None without a ``[sync]`` section).
    sync: Any = None
    #: The ship's sensors (service.nav.ShipSensors; None without ``[nav]``).
    nav: Any = None
    started: float = field(default_factory=time.monotonic)
    last_tick: float = field(default_factory=time.monotonic)
    last_sync: float = field(default_factory=time.monotonic)

    def dead_parts(self) -> dict[str, str]:
        """The parts that have stopped or hung, each with why (empty when all live). A restart
        mends these, so the watchdog is not petted while any is listed."""
        dead: dict[str, str] = {}
        if self.reader is not None and not self.reader.health().running:
            dead["reader"] = "the reader thread has stopped"
        if self.feeder is not None and not self.feeder.alive:
            dead["ingest"] = "the ingest thread has stopped"
        waits = [self.ingest.frames_waiting_s(), None if self.feeder is None else
                 self.feeder.waiting_s()]  # fmt: skip
        held = max((w for w in waits if w is not None), default=None)
        if held is not None and held >= DETECTOR_STALL_S:  # frames pile up unprocessed
            dead["detector"] = f"frames have waited {held:.0f} s to be processed"
        if not self.scheduler.alive:
            dead["scheduler"] = "the job supervisor is not running"
        if self.publisher.closed:  # every /events stream has ended and none can start
            dead["publisher"] = "closed: no /events stream receives new versions"
        if self.sync is not None and self.sync.started and not self.sync.alive:
            if not self.sync.stopping:
                dead["sync"] = "the fleet sync thread has stopped"
        if self.nav is not None and self.nav.started and not self.nav.alive:
            dead["nav"] = "the reader of the ship's sensors has stopped"
        api = self._api_dead()
        if api is not None:
            dead["api"] = api
        return dead

    def _api_dead(self) -> str | None:
        """Why the HTTP API no longer answers, or None (also before it starts and once it is
        asked to stop)."""
        server = self.server
        if server is None or not server.started or server.should_exit:
            return None  # not serving yet, or stopping as asked (STOPPING=1 follows)
        if server.loop is None or not server.loop.is_running():
            return "the HTTP server's event loop has ended"
        quiet = time.monotonic() - server.loop_tick
        if quiet >= API_STALL_S:
            return f"the HTTP server's event loop has not run for {quiet:.0f} s"
        return None

    def problems(self, dead: dict[str, str] | None = None) -> list[str]:
        """Why the service is degraded, in plain words (empty when all is well): the dead parts
        (``dead``, default :meth:`dead_parts`) first, then the parts that live but fail."""
        dead = self.dead_parts() if dead is None else dead
        out = [f"{part}: {why}" for part, why in dead.items()]
        if self.reader is not None and "reader" not in dead:
            h = self.reader.health()
            if getattr(h, "problem", None):  # disconnected, or connected but silent
                out.append(f"reader: {self.settings.device.url}: {h.problem}")
            elif not h.connected:
                out.append(f"reader: device {self.settings.device.url} is not connected"
                           + (f" ({h.last_error})" if h.last_error else ""))  # fmt: skip
        if self.nav is not None and "nav" not in dead and self.nav.started:
            problem = self.nav.health().get("problem")
            if problem:  # disconnected, or open but no fix: windows go without the ship's state
                out.append(f"nav: {problem}")
        if self.ingest.store_error is not None:
            out.append(f"database: {self.ingest.spooled} window(s) waiting to be stored "
                       f"({self.ingest.store_error})")  # fmt: skip
        if self.ingest.spool_error is not None:
            out.append(f"spool: {self.ingest.spool_error}")
        if self.publisher.error is not None:
            out.append(f"publisher: {self.publisher.error}")
        if self.sync is not None and self.sync.stats.state == "rejected":  # needs a person
            out.append(f"sync: {self.sync.stats.last_error}")
        return out

    def alive(self) -> bool:
        """Every part the service needs runs and makes progress (what the watchdog reports)."""
        return not self.dead_parts()

    def health(self) -> dict[str, Any]:
        dead = self.dead_parts()
        problems = self.problems(dead)
        out: dict[str, Any] = {
            "status": "degraded" if problems else "ok",
            "problems": problems,
            "dead_parts": list(dead),  # the watchdog is not petted while any is listed
            "session": self.session_id,
            "uptime_s": time.monotonic() - self.started,
            "frames": self.ingest.frames,
            "windows": self.ingest.windows,
            "windows_detected": self.ingest.detected,  # durable: in the spool or the database
            "windows_spooled": self.ingest.spooled,
            "windows_dropped": self.ingest.windows_dropped,
            "spool": self.ingest.spool_health(),
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
            "sync": self.sync_health(),
            "nav": None if self.nav is None else self.nav.health(),
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
                "state": h.state,  # ok, silent, disconnected, ended (a replay), stopped
                "diagnosis": h.diagnosis,
                "counters": asdict(h.counters),
            }
        return out

    def sync_health(self) -> dict[str, Any]:
        """The ``sync`` block of ``/health``: the link's state, backlog (outbox rows; None
        while the database does not answer) and traffic; ``state`` ``off`` without
        ``[sync]``."""
        from service.store.errors import StoreError
        from service.sync import off_block

        try:
            backlog: int | None = self.store.outbox_count()
        except StoreError:
            backlog = None
        return off_block(backlog) if self.sync is None else self.sync.health(backlog)

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
        from service.store.errors import StoreError

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

    def end_of_input(self, timeout_s: float = 60.0) -> None:
        """The stream has ended (a replayed capture read to its end): feed what the reader
        queued, then learn from the frames held, if any, and close the open window. The reader
        says so itself at the end of a ``replay://`` capture; a second call changes nothing."""
        if self.feeder is not None and not self.feeder.wait_idle(timeout_s):
            raise TimeoutError(f"the ingest thread did not catch up within {timeout_s:g} s")
        self.ingest.end_of_input()

    def close(self, wait_s: float | None = None) -> None:
        """Stop reading, store the open window, let a running job finish (up to
        ``scheduler.stop_wait_s``) or abandon it, and release everything."""
        if self.sync is not None:  # a request in flight is aborted: no wait for the link
            self.sync.stop()
        if self.nav is not None:
            self.nav.stop()
        self.publisher.close()  # ends open /events streams
        self.scheduler.stop_starting()  # the flush below may store windows: they start nothing
        if self.reader is not None:
            self.reader.stop()
        if self.feeder is not None:
            self.feeder.stop()  # what the reader queued goes in before the open window closes
        try:
            self.ingest.flush(why="stopping")
        except Exception:  # noqa: BLE001 - shutting down: keep going, the log has it
            log.exception("flushing the detector at shutdown failed")
        wait = self.settings.scheduler.stop_wait_s if wait_s is None else wait_s
        self.scheduler.shutdown(wait_s=wait)
        self.store.close()


def _safe_meta(settings: Settings) -> dict[str, Any]:
    """The settings as stored with the session: without secrets."""
    meta = settings.model_dump(mode="json")
    meta.get("api", {}).pop("token", None)
    meta.get("sync", {}).pop("token", None)
    return meta


def _starting_prior(store: Any, settings: Settings) -> Any:
    """The coefficients the service starts from: the accepted version, else ``prior_path``
    (None without either). The rest check converts the outputs to physics with them."""
    from service.startup import read_prior
    from service.store.errors import StoreError
    from service.triggers import accepted_coefficients

    try:
        current = store.current()
    except StoreError:
        current = None
    if current is not None:
        try:
            return accepted_coefficients(current)[0]
        except (RecalInputError, KeyError, TypeError, ValueError) as exc:
            log.warning("the accepted version %s cannot be read for the rest check: %s",
                        current.version, exc)  # fmt: skip
    return read_prior(settings.prior_path) if settings.prior_path else None


def build_service(settings: Settings, with_reader: bool = True, runner: Any = None) -> Service:
    """Open the store, the publisher, the pipeline and (optionally) the serial reader."""
    from service.publish import Publisher
    from service.spool import Spool
    from service.startup import prepare_state_dir, spool_folder
    from service.store.repository import Store

    prepare_state_dir(settings)  # the defaults' folder: never the working folder
    publisher = Publisher(settings.publish_path)  # checks the path first: nothing opened yet
    folder = spool_folder(settings)
    spool = None if folder is None else Spool(folder)
    store = Store(settings.database_url)
    try:
        store.create_schema()
        events = Events(store)
        session_id = store.add_session(source=settings.device.url, meta=_safe_meta(settings))
        scheduler = Scheduler(store, settings, publisher, events, runner)
        config = detector_config(settings)
        d = settings.device
        device = f"{d.url} {d.format} {d.rate_hz:g} Hz"
        keeper = FloorKeeper(store, device, events, window_frames(config, d.rate_hz))
        prior = _starting_prior(store, settings)
        rest = rest_reference(settings, prior)
        hull = settings.detector.hull_config() if settings.detector.motion == "hull" else None
        nav = None
        if settings.nav.enabled:  # the ship's sensors: started with the reader (run_daemon)
            from service.nav import ShipSensors

            nav = ShipSensors(settings.nav, reader=with_reader)
        ingest = Ingest(store, session_id, config, scheduler.notify, events, keeper,
                        settings.detector.learn_s, spool, rest=rest, hull=hull,
                        learn_quiet_s=settings.detector.learn_quiet_s, nav=nav,
                        rest_at=lambda lat: rest_reference(settings, prior, lat))  # fmt: skip
        if nav is not None:
            nav.on_latitude = ingest.nav_latitude
    except BaseException:
        store.close()
        raise
    ingest.replay()  # windows an earlier run made durable go in before any new one
    service = Service(settings, store, publisher, scheduler, ingest, session_id, events, nav=nav)
    if settings.sync.enabled:  # started with the reader (run_daemon); its own thread and link
        from service.sync import SyncThread

        service.sync = SyncThread.from_settings(
            store, settings.sync, events, prior_path=settings.fetched_fleet_prior()
        )
    if with_reader:
        from drivers import FrameReader

        # any registered format, with the [device] settings it takes (drivers.registry)
        # the reader only queues: the ingest thread runs the detector, spool and database
        service.feeder = IngestThread(ingest)
        # a replayed capture read to its end is the end of input: the frames held to learn
        # the noise floor and the open window are processed after the last frame
        service.reader = FrameReader(d.url, d.format, options=d.format_options(),
                                     on_batch=service.feeder.put, baudrate=d.baudrate,
                                     on_end=service.feeder.end)  # fmt: skip
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
        def __init__(self, config: uvicorn.Config) -> None:
            super().__init__(config)
            # for the watchdog: the event loop that serves, and its heartbeat (a hung loop
            # stops ticking)
            self.loop: asyncio.AbstractEventLoop | None = None
            self.loop_tick = time.monotonic()

        async def startup(self, sockets: Any = None) -> None:
            self.loop = asyncio.get_running_loop()
            await super().startup(sockets)
            self.loop_tick = time.monotonic()  # ``started`` is set: the ticks begin now

        async def on_tick(self, counter: int) -> bool:
            self.loop_tick = time.monotonic()
            return await super().on_tick(counter)

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
    service.server = server = Server(config)
    return server


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


class Housekeeping:
    """The daemon's housekeeping thread (:meth:`run`): READY=1 once the API serves, then
    :meth:`Service.tick` every ``tick_s`` and, every ``watchdog_s``, WATCHDOG=1 only while no part
    is dead (:meth:`Service.dead_parts`). When the dead parts change, systemd gets a ``STATUS=``
    line naming them (``systemctl status`` shows it) and a ``watchdog`` event says the same."""

    def __init__(self, service: Service, stop: threading.Event, tick_s: float = 1.0,
                 watchdog_s: float = WATCHDOG_EVERY_S) -> None:  # fmt: skip
        self.service = service
        self.stop = stop
        self.tick_s = tick_s
        self.watchdog_s = watchdog_s
        self.checks = 0  # liveness checks done (each ends with WATCHDOG=1 or with none)
        self.fed = 0  # WATCHDOG=1 sent (and received by the socket)
        self.dead: dict[str, str] = {}  # the dead parts at the last check

    def run(self) -> None:
        server = self.service.server
        while server is not None and not server.started:  # READY=1 as soon as the API answers
            if self.stop.wait(0.1):
                return
        sd_notify("READY=1")
        api = self.service.settings.api
        self.service.events.emit("ready", f"serving on http://{api.host}:{api.port}")
        try:
            self.service.scheduler.resume()
        except Exception:  # noqa: BLE001 - e.g. the database is down: the next tick retries
            log.exception("resuming jobs at start failed")
        due = time.monotonic() + self.watchdog_s
        while not self.stop.wait(self.tick_s):
            try:
                self.service.tick()
            except Exception:  # noqa: BLE001 - one bad tick must not end housekeeping
                log.exception("housekeeping failed")
            if time.monotonic() >= due:
                due = time.monotonic() + self.watchdog_s
                self.check()

    def check(self) -> bool:
        """Pet the watchdog if every part lives; returns whether it was petted."""
        dead = self.service.dead_parts()
        if dead.keys() != self.dead.keys():
            if dead:
                lines = "; ".join(f"{part}: {why}" for part, why in dead.items())
                self.service.events.emit("watchdog", f"not petted: {lines}",
                                         {"dead": ",".join(dead)}, level=logging.ERROR)  # fmt: skip
                sd_notify(f"STATUS=not petting the watchdog: {lines}")
            else:
                self.service.events.emit("watchdog", "every part lives again")
                sd_notify("STATUS=every part lives")
        self.dead = dead
        if not dead and sd_notify("WATCHDOG=1"):
            self.fed += 1
        self.checks += 1
        return not dead


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

    service.reader.start()
    if service.nav is not None:
        service.nav.start()
    if service.sync is not None:
        service.sync.start()
    keeper = Housekeeping(service, stop, watchdog_s=watchdog_interval_s())
    threading.Thread(target=keeper.run, name="housekeeping", daemon=True).start()
    try:
        run_server(server, settings.api)
    finally:
        stop.set()
        sd_notify("STOPPING=1")
        service.events.emit("stop", "service stopping")
        service.close()
    return 0


_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
