"""A TCP proxy that behaves like a bad satellite link, for the fleet sync's tests and benchmarks
(a tool of the source tree, not of the installed package: run it from a checkout).

``FaultProxy`` listens on 127.0.0.1 (a free port unless told) in front of a target host:port,
forwards bytes both ways and injects the faults a vessel's link has, settable while it runs::

    with FaultProxy(("127.0.0.1", shore_port), seed=7) as proxy:
        client = httpx.Client(base_url=proxy.url, timeout=2.0)
        proxy.set(drop_response=1.0)        # the shore commits, the vessel never hears
        ...
        proxy.stats.cuts["response"]

Faults (``Faults``; ``proxy.set(**changes)`` changes some, ``proxy.clear()`` removes all):

* ``down``: the link is down. The listening socket is closed, so a new connection is refused
  (the client's connect fails at once), and every open connection is cut. Back up, the proxy
  listens on the same port again (``set`` raises ``OSError`` and the link stays down if
  another program took the port meanwhile).
* ``drop_request``, ``drop_response``: probabilities per exchange (a request and its answer;
  a connection with keep-alive carries several). A dropped request is cut after a uniformly
  random number of its bytes: the server receives its head, part of the body or nothing, never
  all of it (the length is read from the request's ``Content-Length``; a request the proxy
  cannot frame is cut within its first chunk). A dropped response is cut after the server has
  sent its first bytes, so it has handled the request and answered, but the client receives a
  part of the answer or none: the lost acknowledgement. Both sides of a cut connection see it
  closed.
* ``delay_s``: one-way latency added to every chunk, both ways (a chunk read at ``t`` is
  written at ``t + delay_s``; chunks are pipelined, so the delay does not lower throughput).
* ``bytes_per_s``: bandwidth of each direction of each connection (``None``: unlimited).
* ``blackhole``: a new connection is accepted and never forwarded nor answered (what the
  client sends is read and discarded, so only its own timeout ends it); open connections stall
  both ways until the blackhole is lifted, then go on.

Exchanges are told apart by the direction of the traffic: client bytes after server bytes
start a new one. Every random draw comes from a generator seeded by ``(seed, connection
number)``, four per exchange, so a client that makes the same requests in the same order meets
the same faults in the same exchanges, a request cut at the same byte (``proxy.cuts``; an
answer is cut within the first chunk the proxy reads of it, whose size the sockets decide);
``outage_schedule(seed, ...)`` and ``outages`` make a reproducible timetable of outages that
``proxy.play`` applies while a benchmark runs.

Everything runs on one event-loop thread; ``close()`` (the end of the ``with``) cuts every
connection, closes every socket and joins the thread. ``proxy.stats`` is a snapshot readable
from any thread.

Command line (docs/fleet.md, "Rehearsing a bad link")::

    python benchmarks/fault_proxy.py --listen 127.0.0.1:9000 --target shore:8443 \\
        --drop-request 0.1 --drop-response 0.1 --delay 0.5
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import os
import random
import re
import signal
import sys
import threading
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from types import TracebackType
from typing import Any, NoReturn

#: Largest chunk read at once from either side.
CHUNK = 65536
#: How long the proxy waits for the target to accept a connection.
CONNECT_TIMEOUT_S = 10.0
#: How long ``set``, ``start`` and ``close`` wait for the event-loop thread.
CONTROL_TIMEOUT_S = 10.0
#: Chunks held per direction before the proxy stops reading (TCP back-pressure to the sender).
QUEUE_CHUNKS = 16
#: Kinds of cut counted in ``Stats.cuts``.
CUT_KINDS = ("down", "request", "response")

_CONTENT_LENGTH = re.compile(rb"\r\ncontent-length:[ \t]*(\d+)[ \t]*\r\n", re.IGNORECASE)
_CHUNKED = re.compile(rb"\r\ntransfer-encoding:[^\r\n]*chunked", re.IGNORECASE)


@dataclass(frozen=True)
class Faults:
    """The link's faults; the default is a perfect link."""

    down: bool = False
    drop_request: float = 0.0
    drop_response: float = 0.0
    delay_s: float = 0.0
    bytes_per_s: float | None = None
    blackhole: bool = False

    def __post_init__(self) -> None:
        for name in ("drop_request", "drop_response"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} is a probability, within [0, 1], not {value}")
        if not self.delay_s >= 0.0:
            raise ValueError(f"delay_s must be >= 0, not {self.delay_s}")
        if self.bytes_per_s is not None and not self.bytes_per_s > 0:
            raise ValueError(
                f"bytes_per_s must be > 0 (or None: unlimited), not {self.bytes_per_s}"
            )


@dataclass(frozen=True)
class Cut:
    """One connection cut by the proxy: ``offset`` bytes of the exchange's request (``request``)
    or of the server's first chunk of its answer (``response``) got through; ``down`` cuts
    record the exchange under way and offset 0."""

    connection: int
    exchange: int
    kind: str
    offset: int


@dataclass(frozen=True)
class Stats:
    """A snapshot of the proxy's counters (``FaultProxy.stats``)."""

    #: Connections accepted (blackholed ones included; refused ones never reach the proxy).
    connections: int
    #: Connections open now.
    active: int
    #: Connections accepted while the link was a blackhole (never forwarded).
    blackholed: int
    #: Connections the target refused or did not accept in time (closed at once).
    upstream_failed: int
    #: Bytes delivered to the server (client to server) and to the client (server to client).
    bytes_up: int
    bytes_down: int
    #: Cuts by kind (``CUT_KINDS``).
    cuts: Mapping[str, int]


Step = tuple[float, Mapping[str, Any]]
"""A schedule step: seconds from ``play``, and the changes to pass to ``set`` then."""


def outages(seed: int, mean_up_s: float, mean_down_s: float, fault: str = "down") -> Iterator[Step]:
    """An endless, reproducible timetable of outages: exponential times up and down of the given
    means, ``fault`` (``down`` or ``blackhole``) set at the start of each and cleared at its end."""
    if fault not in ("down", "blackhole"):
        raise ValueError(f"fault must be down or blackhole, not {fault!r}")
    if not (mean_up_s > 0 and mean_down_s > 0):
        raise ValueError("mean_up_s and mean_down_s must be > 0")
    rng = random.Random(seed)
    t = 0.0
    while True:
        t += rng.expovariate(1.0 / mean_up_s)
        yield round(t, 6), {fault: True}
        t += rng.expovariate(1.0 / mean_down_s)
        yield round(t, 6), {fault: False}


def outage_schedule(
    seed: int, duration_s: float, mean_up_s: float, mean_down_s: float, fault: str = "down"
) -> list[Step]:
    """``outages`` over ``duration_s`` as a list; the link is up at the end."""
    steps: list[Step] = []
    for at, changes in outages(seed, mean_up_s, mean_down_s, fault):
        if at >= duration_s:
            if changes[fault] is False:  # an outage under way ends with the run
                steps.append((duration_s, changes))
            return steps
        steps.append((at, changes))
    raise AssertionError("unreachable")


def _request_length(chunk: bytes) -> int | None:
    """Length of the HTTP/1.x request starting ``chunk`` when its head is complete and says it
    (``Content-Length``, or no body at all); ``None`` otherwise."""
    end = chunk.find(b"\r\n\r\n")
    if end < 0 or not re.match(rb"[A-Z]+ \S+ HTTP/1\.[01]\r\n", chunk):
        return None
    head = chunk[: end + 2]
    if _CHUNKED.search(head):
        return None
    match = _CONTENT_LENGTH.search(head)
    return end + 4 + (int(match.group(1)) if match else 0)


class _Counters:
    """The mutable counters behind ``Stats``, guarded for readers on other threads."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.connections = self.active = self.blackholed = self.upstream_failed = 0
        self.bytes_up = self.bytes_down = 0
        self.cuts = dict.fromkeys(CUT_KINDS, 0)
        self.cut_log: list[Cut] = []

    def add(self, name: str, n: int = 1) -> None:
        with self.lock:
            setattr(self, name, getattr(self, name) + n)

    def cut(self, cut: Cut) -> None:
        with self.lock:
            self.cuts[cut.kind] += 1
            self.cut_log.append(cut)

    def snapshot(self) -> Stats:
        with self.lock:
            return Stats(self.connections, self.active, self.blackholed, self.upstream_failed,
                         self.bytes_up, self.bytes_down, dict(self.cuts))  # fmt: skip


class _Direction:
    """One direction of a connection: a reader that stamps chunks with their delivery time and
    a writer that delivers them, cutting the connection at ``cut_at`` bytes when set."""

    def __init__(self, name: str, reader: asyncio.StreamReader, writer: asyncio.StreamWriter):
        self.name = name  # "up" (client to server) or "down"
        self.reader = reader
        self.writer = writer
        self.queue: asyncio.Queue[tuple[float, bytes] | None] = asyncio.Queue(QUEUE_CHUNKS)
        self.read = 0  # bytes read from the source
        self.written = 0  # bytes delivered to the destination
        self.free_at = 0.0  # when the link has sent what it holds (bandwidth limit)
        self.cut_at: int | None = None  # cut after this many bytes delivered
        self.cut_kind = ""
        self.cut_exchange = 0
        self.cut_base = 0  # ``read`` where the cut's count of bytes starts


class _Link:
    """One proxied connection."""

    def __init__(self, proxy: FaultProxy, number: int, client: asyncio.StreamWriter) -> None:
        self.proxy = proxy
        self.number = number
        self.client = client
        self.server: asyncio.StreamWriter | None = None
        self.rng = random.Random(f"{proxy.seed}:{number}")
        self.exchange = -1
        # direction of the last chunk read: client bytes after server bytes start an exchange
        self.last = "down"
        self.arm_response: float | None = None  # fraction of the next answer's first chunk
        self.tasks: list[asyncio.Task[None]] = []
        self.handler: asyncio.Task[Any] | None = None  # the task serving the connection
        self.closed = False

    async def run(self, client_reader: asyncio.StreamReader) -> None:
        host, port = self.proxy.target
        try:
            async with asyncio.timeout(CONNECT_TIMEOUT_S):
                server_reader, self.server = await asyncio.open_connection(host, port)
        except (OSError, TimeoutError):
            self.proxy._counters.add("upstream_failed")
            return
        if self.closed:  # cut (link down, shutdown) while connecting
            self.server.transport.abort()
            return
        for writer in (self.client, self.server):  # drain() then means "in the kernel"
            writer.transport.set_write_buffer_limits(high=0)
        up = _Direction("up", client_reader, self.server)
        down = _Direction("down", server_reader, self.client)
        self.tasks = [asyncio.create_task(c) for c in (self._read(up), self._write(up),
                                                       self._read(down), self._write(down))]  # fmt: skip
        await asyncio.gather(*self.tasks, return_exceptions=True)

    def close(self) -> None:
        """Close both sockets at once and stop the pumps."""
        if self.closed:
            return
        self.closed = True
        for writer in (self.client, self.server):
            if writer is not None:
                writer.transport.abort()
        current = asyncio.current_task()
        for task in self.tasks:
            if task is not current:
                task.cancel()

    def cut(self, kind: str, exchange: int, offset: int) -> None:
        if not self.closed:
            self.proxy._counters.cut(Cut(self.number, exchange, kind, offset))
        self.close()

    def _start_exchange(self, direction: _Direction, chunk: bytes) -> None:
        """Client bytes after server bytes: a new request. Draw its fate (always four draws)."""
        self.exchange += 1
        faults = self.proxy.faults
        drop_request = self.rng.random() < faults.drop_request
        drop_response = self.rng.random() < faults.drop_response
        u, v = self.rng.random(), self.rng.random()
        if drop_request:
            length = _request_length(chunk) or len(chunk)
            direction.cut_at = direction.read + int(u * length)
            direction.cut_kind, direction.cut_exchange = "request", self.exchange
            direction.cut_base = direction.read
        elif drop_response:
            self.arm_response = v

    async def _read(self, d: _Direction) -> None:
        proxy = self.proxy
        try:
            while True:
                await proxy._clear.wait()  # a blackhole stalls the link
                faults = proxy.faults
                size = CHUNK if faults.bytes_per_s is None else int(max(256, min(CHUNK, faults.bytes_per_s / 20)))  # fmt: skip
                chunk = await d.reader.read(size)
                if not chunk:
                    await d.queue.put(None)
                    return
                if d.name == "up" and self.last == "down":
                    self._start_exchange(d, chunk)
                elif d.name == "down" and self.arm_response is not None:
                    d.cut_at = d.read + int(self.arm_response * len(chunk))
                    d.cut_kind, d.cut_exchange, d.cut_base = "response", self.exchange, d.read
                    self.arm_response = None
                self.last = d.name
                d.read += len(chunk)
                now = time.monotonic()
                start = max(now, d.free_at)
                d.free_at = start + (len(chunk) / faults.bytes_per_s if faults.bytes_per_s else 0.0)  # fmt: skip
                await d.queue.put((d.free_at + faults.delay_s, chunk))
        except OSError:
            self.close()

    async def _write(self, d: _Direction) -> None:
        proxy = self.proxy
        try:
            while True:
                item = await d.queue.get()
                if item is None:
                    if d.writer.can_write_eof():
                        d.writer.write_eof()
                    return
                deliver_at, chunk = item
                wait = deliver_at - time.monotonic()
                if wait > 0:
                    await asyncio.sleep(wait)
                await proxy._clear.wait()
                if d.cut_at is not None and d.written + len(chunk) > d.cut_at:
                    chunk = chunk[: d.cut_at - d.written]
                    await self._deliver(d, chunk)
                    self.cut(d.cut_kind, d.cut_exchange, d.cut_at - d.cut_base)
                    return
                await self._deliver(d, chunk)
        except OSError:
            self.close()

    async def _deliver(self, d: _Direction, chunk: bytes) -> None:
        if not chunk:
            return
        d.writer.write(chunk)
        await d.writer.drain()
        d.written += len(chunk)
        self.proxy._counters.add("bytes_up" if d.name == "up" else "bytes_down", len(chunk))


class FaultProxy:
    """A TCP proxy in front of ``target`` with the faults of a bad link (module docstring).

    ``listen`` defaults to a free port on 127.0.0.1. Use it as a context manager, or call
    ``start()`` and ``close()``. ``seed`` fixes every random draw.
    """

    def __init__(
        self,
        target: tuple[str, int],
        seed: int = 0,
        listen: tuple[str, int] = ("127.0.0.1", 0),
        faults: Faults | None = None,
    ) -> None:
        self.target = target
        self.seed = seed
        self._listen = listen
        self._faults = faults or Faults()
        self._counters = _Counters()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._server: asyncio.Server | None = None
        self._address: tuple[str, int] | None = None
        self._links: set[_Link] = set()
        self._handlers: set[asyncio.Task[Any]] = set()
        self._schedule: asyncio.Task[None] | None = None
        self._next = 0
        self._clear = asyncio.Event()  # set while there is no blackhole
        self._stopping = asyncio.Event()

    # -- life cycle -------------------------------------------------------------------------

    def start(self) -> FaultProxy:
        """Start the event-loop thread and listen; raises ``OSError`` if the address is taken."""
        if self._thread is not None:
            raise RuntimeError("the proxy is already started")
        ready: list[BaseException | None] = []
        started = threading.Event()
        self._thread = threading.Thread(
            target=lambda: asyncio.run(self._main(ready, started)), name="fault-proxy", daemon=True
        )
        self._thread.start()
        if not started.wait(CONTROL_TIMEOUT_S):
            raise RuntimeError("the fault proxy did not start")
        if ready and ready[0] is not None:
            self._thread.join(CONTROL_TIMEOUT_S)
            self._thread = None
            raise ready[0]
        return self

    def close(self) -> None:
        """Cut every connection, close every socket and join the thread (idempotent)."""
        thread, loop = self._thread, self._loop
        if thread is None or loop is None:
            return
        with contextlib.suppress(RuntimeError):  # the loop has already ended
            loop.call_soon_threadsafe(self._stopping.set)
        thread.join(CONTROL_TIMEOUT_S)
        self._thread = None

    def __enter__(self) -> FaultProxy:
        return self.start()

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    async def _main(self, ready: list[BaseException | None], started: threading.Event) -> None:
        self._loop = asyncio.get_running_loop()
        self._clear.set()
        try:
            await self._listen_now(self._listen)
            if self._faults.down:
                await self._apply(self._faults, force=True)
            elif self._faults.blackhole:
                self._clear.clear()
        except OSError as exc:
            ready.append(exc)
            started.set()
            return
        ready.append(None)
        started.set()
        try:
            await self._stopping.wait()
        finally:
            if self._schedule is not None:
                self._schedule.cancel()
            await self._unlisten()
            for link in list(self._links):
                link.close()
            for task in list(self._handlers):
                task.cancel()
            await asyncio.gather(*self._handlers, return_exceptions=True)

    async def _listen_now(self, address: tuple[str, int]) -> None:
        self._server = await asyncio.start_server(
            self._handle, address[0], address[1], reuse_address=True
        )
        sockname = self._server.sockets[0].getsockname()
        self._address = (sockname[0], sockname[1])

    async def _unlisten(self) -> None:
        if self._server is not None:
            self._server.close()
            self._server = None

    # -- the address, the faults, the counters -------------------------------------------------

    @property
    def address(self) -> tuple[str, int]:
        """(host, port) the proxy listens on."""
        if self._address is None:
            raise RuntimeError("the proxy is not started")
        return self._address

    @property
    def url(self) -> str:
        """``http://host:port`` of the proxy, for an HTTP client's base URL."""
        host, port = self.address
        return f"http://{host}:{port}"

    @property
    def faults(self) -> Faults:
        """The faults in force."""
        return self._faults

    @property
    def stats(self) -> Stats:
        """A snapshot of the counters."""
        return self._counters.snapshot()

    @property
    def cuts(self) -> list[Cut]:
        """Every cut so far, in order (the same with the same seed and the same traffic)."""
        with self._counters.lock:
            return list(self._counters.cut_log)

    def set(self, **changes: Any) -> Faults:
        """Change some faults (``Faults``' fields) and return the faults now in force. In force
        when it returns: going down has cut the open connections, coming up listens again."""
        faults = dataclasses.replace(self._faults, **changes)
        self._call(self._apply(faults))
        return faults

    def clear(self) -> Faults:
        """Remove every fault: a perfect link again."""
        return self.set(**dataclasses.asdict(Faults()))

    def play(self, schedule: Iterable[Step]) -> None:
        """Apply ``schedule`` (seconds from now, changes to ``set``; in time order) in the
        background, replacing a schedule still playing. An iterator is read as it plays, so
        an endless one (``outages``) is fine; a sequence's steps are checked first."""
        if isinstance(schedule, Sequence):
            for _, changes in schedule:
                dataclasses.replace(self._faults, **changes)  # a bad step fails here, not later
        self._call(self._start_schedule(iter(schedule)))

    def _call(self, coro: Any) -> None:
        loop = self._loop
        if loop is None or self._thread is None:
            coro.close()
            raise RuntimeError("the proxy is not started")
        asyncio.run_coroutine_threadsafe(coro, loop).result(CONTROL_TIMEOUT_S)

    async def _start_schedule(self, steps: Iterator[Step]) -> None:
        if self._schedule is not None:
            self._schedule.cancel()
        self._schedule = asyncio.create_task(self._run_schedule(steps))

    async def _run_schedule(self, steps: Iterator[Step]) -> None:
        t0 = time.monotonic()
        for at, changes in steps:
            wait = t0 + at - time.monotonic()
            if wait > 0:
                await asyncio.sleep(wait)
            await self._apply(dataclasses.replace(self._faults, **changes))

    async def _apply(self, faults: Faults, force: bool = False) -> None:
        old, self._faults = self._faults, faults
        if faults.down and (force or not old.down):
            await self._unlisten()
            links = list(self._links)
            for link in links:
                link.cut("down", max(link.exchange, 0), 0)
            ended = [link.handler for link in links if link.handler is not None]
            await asyncio.gather(*ended, return_exceptions=True)  # counted as ended on return
        elif not faults.down and self._server is None and not self._stopping.is_set():
            try:
                await self._listen_now(self.address)
            except OSError:  # the port was taken meanwhile: still down, and the caller hears it
                self._faults = dataclasses.replace(faults, down=True)
                raise
        if faults.blackhole:
            self._clear.clear()
        else:
            self._clear.set()

    # -- connections --------------------------------------------------------------------------

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._handlers.add(task)
        number, self._next = self._next, self._next + 1
        counters = self._counters
        counters.add("connections")
        counters.add("active")
        link = _Link(self, number, writer)
        link.handler = task
        self._links.add(link)
        try:
            if self._faults.down or self._stopping.is_set():
                link.close()
            elif self._faults.blackhole:
                counters.add("blackholed")
                while await reader.read(CHUNK):  # swallow until the client gives up
                    pass
            else:
                await link.run(reader)
        except (OSError, asyncio.CancelledError):
            pass  # the end of this connection's task: nothing to tell
        finally:
            link.close()
            self._links.discard(link)
            self._handlers.discard(task)
            counters.add("active", -1)


# -- command line ------------------------------------------------------------------------------


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: {message} (--help for usage)\n")


def _host_port(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} is not HOST:PORT")
    return host.strip("[]"), int(port)


def _probability(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"{text!r} is not a probability within [0, 1]")
    return value


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not value >= 0.0:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number >= 0")
    return value


def _outages(text: str) -> tuple[float, float]:
    up, sep, down = text.partition(":")
    try:
        pair = (float(up), float(down))
    except ValueError:
        pair = (0.0, 0.0)
    if not sep or not (pair[0] > 0 and pair[1] > 0):
        raise argparse.ArgumentTypeError(f"{text!r} is not UP_S:DOWN_S (two numbers > 0)")
    return pair


def _format_stats(stats: Stats) -> str:
    cuts = " ".join(f"{k}={v}" for k, v in stats.cuts.items())
    return (f"connections={stats.connections} active={stats.active} up={stats.bytes_up}B "
            f"down={stats.bytes_down}B blackholed={stats.blackholed} "
            f"target_failed={stats.upstream_failed} cuts: {cuts}")  # fmt: skip


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def main(argv: Sequence[str] | None = None) -> int:
    """``python benchmarks/fault_proxy.py``: a bad link in front of a shore service, until Ctrl-C."""
    parser = _Parser(
        prog="python benchmarks/fault_proxy.py",
        description="A TCP proxy that behaves like a bad satellite link (docs/fleet.md).",
    )
    parser.add_argument(
        "--listen",
        type=_host_port,
        default=("127.0.0.1", 9000),
        metavar="HOST:PORT",
        help="where to listen (default 127.0.0.1:9000)",
    )
    parser.add_argument(
        "--target", type=_host_port, required=True, metavar="HOST:PORT", help="the shore service"
    )
    parser.add_argument(
        "--drop-request",
        type=_probability,
        default=0.0,
        metavar="P",
        help="probability a request is cut part-way (the shore gets part of it)",
    )
    parser.add_argument(
        "--drop-response",
        type=_probability,
        default=0.0,
        metavar="P",
        help="probability an answer is cut (the shore committed, the vessel never hears)",
    )
    parser.add_argument(
        "--delay",
        type=_positive,
        default=0.0,
        metavar="S",
        help="one-way latency added to every chunk, seconds",
    )
    parser.add_argument(
        "--bandwidth",
        type=_positive,
        default=None,
        metavar="BYTES_PER_S",
        help="bandwidth of each direction of each connection",
    )
    parser.add_argument(
        "--outages",
        type=_outages,
        default=None,
        metavar="UP_S:DOWN_S",
        help="random outages (link down): mean seconds up, mean seconds down",
    )
    parser.add_argument(
        "--blackhole-outages",
        action="store_true",
        help="outages swallow traffic (the vessel times out) instead of refusing it",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of every random draw (default 0)")
    parser.add_argument(
        "--stats-every",
        type=_positive,
        default=10.0,
        metavar="S",
        help="print the counters every S seconds (0: only at the end)",
    )
    args = parser.parse_args(argv)
    if args.bandwidth == 0:
        parser.error("--bandwidth must be > 0")
    faults = Faults(drop_request=args.drop_request, drop_response=args.drop_response,
                    delay_s=args.delay, bytes_per_s=args.bandwidth)  # fmt: skip
    proxy = FaultProxy(tuple(args.target), seed=args.seed, listen=tuple(args.listen), faults=faults)
    try:
        proxy.start()
    except OSError as exc:
        host, port = args.listen
        why = os.strerror(exc.errno).lower() if exc.errno else str(exc)
        print(f"{parser.prog}: cannot listen on {host}:{port}: {why}", file=sys.stderr)
        return 1
    if threading.current_thread() is threading.main_thread():  # kill: as Ctrl-C, counters printed
        signal.signal(signal.SIGTERM, _interrupt)
    host, port = proxy.address
    print(f"listening on {host}:{port} -> {args.target[0]}:{args.target[1]}; {faults}", flush=True)
    try:
        if args.outages is not None:
            fault = "blackhole" if args.blackhole_outages else "down"
            proxy.play(outages(args.seed, *args.outages, fault=fault))
        while True:
            time.sleep(args.stats_every or 3600.0)
            if args.stats_every:
                print(_format_stats(proxy.stats), flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        proxy.close()
        print(_format_stats(proxy.stats), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
