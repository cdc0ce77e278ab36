"""Service test fixtures: Store URLs (SQLite file and a throwaway PostgreSQL database) and real
calibration documents.

The PostgreSQL fixtures (``postgres_url``, ``pg_database``, ``block_database``) are in
tests/conftest.py, shared with tests/fleet.
"""

from __future__ import annotations

import contextlib
import socket
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import create_engine, text

from drivers import DecoderConfig, decode_bulk
from recal.model.coefficients import CoefficientSet
from recal.sim.session import simulate_session
from recal.sim.simulate import simulate_positions
from recal.solve.calibrate import calibrate
from recal.solve.result import CalibrationResult
from service.capture_sim import kvh_like_truth, session_to_kvh
from service.store.records import CalibrationRecord
from service.store.repository import Store
from service.store.rows import Base


@pytest.fixture(params=["sqlite", "postgresql"])
def store_url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """Each Store test runs on a SQLite file and on PostgreSQL (tables dropped afterwards)."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'recal.db'}"
        return
    url = request.getfixturevalue("postgres_url")
    yield url
    engine = create_engine(url)
    Base.metadata.drop_all(engine)
    with engine.begin() as conn:  # the migrations' bookkeeping, or the next test finds it
        conn.execute(text("DROP TABLE IF EXISTS alembic_version"))
    engine.dispose()


@pytest.fixture
def store(store_url: str) -> Iterator[Store]:
    st = Store(store_url)
    st.create_schema()
    yield st
    st.close()


@pytest.fixture
def sqlite_store(tmp_path: Path) -> Iterator[Store]:
    st = Store(f"sqlite:///{tmp_path / 'api.db'}")
    st.create_schema()
    yield st
    st.close()


@pytest.fixture(scope="session")
def calibration_result() -> CalibrationResult:
    """A real LM calibration of the simulated 24-position design (both triads)."""
    return calibrate(simulate_positions(CoefficientSet.seed_truth(), seed=1))


@pytest.fixture(scope="session")
def document(calibration_result: CalibrationResult) -> dict[str, Any]:
    """The ``recal calibrate --json`` object of :func:`calibration_result`."""
    return calibration_result.to_json_dict()


@pytest.fixture
def make_record(document: dict[str, Any]) -> Callable[..., CalibrationRecord]:
    """Factory of CalibrationRecords around the real document (keywords override fields)."""

    def make(**fields: Any) -> CalibrationRecord:
        base: dict[str, Any] = {
            "trigger": "auto",
            "method": "lm",
            "accepted": True,
            "document": document,
        }
        return CalibrationRecord(**(base | fields))

    return make


@contextmanager
def _serving(settings: Any) -> Iterator[tuple[str, Any]]:
    """A real daemon (uvicorn on ``settings.api.port``, 0 for a free one): (base URL, service).
    Reading is not started: call :func:`replay_all` when the test is ready for the frames."""
    from service.daemon import build_service, make_server

    service = build_service(settings)
    server = make_server(service)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 60
        while not server.started:
            assert time.monotonic() < deadline, "server did not start"
            time.sleep(0.02)
        yield f"http://127.0.0.1:{server.servers[0].sockets[0].getsockname()[1]}", service
    finally:
        server.should_exit = True
        thread.join(10)
        service.close()


@pytest.fixture
def serve() -> Callable[[Any], AbstractContextManager[tuple[str, Any]]]:
    """``with serve(settings) as (base_url, service):`` a real daemon over HTTP."""
    return _serving


def replay_all(service: Any, size: int, timeout_s: float = 60.0) -> None:
    """Start the replay reader, wait until it has read ``size`` bytes, store the open window."""
    deadline = time.monotonic() + timeout_s
    service.reader.start()
    while service.reader.health().counters.bytes_in < size:
        assert time.monotonic() < deadline, "replay did not finish"
        time.sleep(0.05)
    service.end_of_input(max(1.0, deadline - time.monotonic()))


@pytest.fixture
def replay() -> Callable[..., None]:
    return replay_all


class Systemd:
    """The receiving end of NOTIFY_SOCKET: a bound Unix datagram socket read at once by a
    thread, as systemd reads it (an unread socket queues only ``net.unix.max_dgram_qlen``
    datagrams, 10 by default, and the daemon's notifications never wait for room)."""

    #: Longest wait for a notification, s (it only bounds a hang: nothing is timed).
    DEADLINE_S = 60.0

    def __init__(self, path: str) -> None:
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self._sock.bind(path)
        self._lock = threading.Lock()
        self._messages: list[bytes] = []
        self._thread = threading.Thread(target=self._read, name="systemd", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while True:
            try:
                message = self._sock.recv(4096)
            except OSError:  # closed
                return
            if not message:  # shut down
                return
            with self._lock:
                self._messages.append(message)

    @property
    def messages(self) -> list[bytes]:
        """Every notification received so far, in order."""
        with self._lock:
            return list(self._messages)

    def since(self, mark: int) -> list[bytes]:
        """The notifications after the first ``mark``."""
        return self.messages[mark:]

    def wait_for(self, wanted: bytes, mark: int = 0) -> list[bytes]:
        """The notifications after ``mark`` up to the first ``wanted`` included."""
        deadline = time.monotonic() + self.DEADLINE_S
        while wanted not in (got := self.since(mark)):
            assert time.monotonic() < deadline, f"no {wanted!r} from the daemon; got {got}"
            time.sleep(0.02)
        return got[: got.index(wanted) + 1]

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._sock.shutdown(socket.SHUT_RDWR)
        self._sock.close()
        self._thread.join(self.DEADLINE_S)


@pytest.fixture
def systemd(monkeypatch: pytest.MonkeyPatch) -> Iterator[Systemd]:
    """A notify socket that NOTIFY_SOCKET names, in a short folder (an AF_UNIX path holds 107
    bytes, fewer than pytest's tmp_path may need); no WATCHDOG_USEC unless a test sets one."""
    with tempfile.TemporaryDirectory(prefix="wd") as folder:
        path = str(Path(folder) / "notify")
        receiver = Systemd(path)
        monkeypatch.setenv("NOTIFY_SOCKET", path)
        monkeypatch.delenv("WATCHDOG_USEC", raising=False)
        monkeypatch.delenv("WATCHDOG_PID", raising=False)
        try:
            yield receiver
        finally:
            receiver.close()


# ---- a shore for fleet sync (docs/fleet.md) ---------------------------------------------------


class Shore:
    """A tiny ``POST /fleet/ingest`` on ``http.server``: docs/fleet.md's contract (bearer token of
    one unit, gzip JSON format 1, 401/403/413/422, 200 ``{"stored", "duplicates"}`` after the
    commit) with rows in SQLite, inserted or ignored by (unit, kind, id). ``mode`` plays the
    link's troubles: ``ok``; ``fail`` (500); ``lose_ack`` (commits, then drops the connection
    unanswered, once); ``hang`` (accepts the request and never answers). ``bad_rows``: (kind, id)
    keys answered 422 naming the row. The real shore service is service/fleet/."""

    KINDS = ("session", "window", "slew", "version", "event")

    def __init__(self, unit: str = "KVH-1750-SN0042", token: str = "unit-token-0123456789"):
        import http.server
        import sqlite3

        self.unit, self.token = unit, token
        self.mode = "ok"
        self.bad_rows: set[tuple[str, int]] = set()
        self.max_json_bytes: int | None = None
        self.requests: list[dict[str, Any]] = []  # status and rows of each request, in order
        self.release = threading.Event()  # ends the hanging requests
        self._lock = threading.Lock()
        self._db = sqlite3.connect(":memory:", check_same_thread=False, isolation_level=None)
        self._db.execute("CREATE TABLE rows (unit TEXT, kind TEXT, id INTEGER, at TEXT, "
                         "data TEXT, PRIMARY KEY (unit, kind, id))")  # fmt: skip
        shore = self

        class Handler(http.server.BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args: Any) -> None:
                pass

            def do_POST(self) -> None:  # noqa: N802 - http.server's name
                shore._handle(self)

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.server.daemon_threads = True
        self._thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.server.server_address[1]}"

    def rows(self, kind: str | None = None) -> list[tuple[str, int, Any]]:
        """What the shore stored: (kind, id, data), by kind then id."""
        import json

        query = "SELECT kind, id, data FROM rows" + (" WHERE kind = ?" if kind else "")
        with self._lock:
            got = self._db.execute(query + " ORDER BY kind, id", (kind,) if kind else ()).fetchall()
        return [(k, i, json.loads(d)) for k, i, d in got]

    def close(self) -> None:
        self.release.set()
        self.server.shutdown()
        self.server.server_close()

    def _answer(self, h: Any, status: int, body: dict[str, Any], rows: int = 0,
                size: int = 0) -> None:  # fmt: skip
        import json

        data = json.dumps(body).encode()
        self.requests.append({"status": status, "rows": rows, "body": body, "json_bytes": size})
        h.send_response(status)
        h.send_header("Content-Type", "application/json")
        h.send_header("Content-Length", str(len(data)))
        h.end_headers()
        h.wfile.write(data)

    def _handle(self, h: Any) -> None:
        import gzip
        import json

        body = h.rfile.read(int(h.headers.get("Content-Length", 0)))
        if h.path != "/fleet/ingest":
            return self._answer(h, 404, {"detail": "not found"})
        if h.headers.get("Authorization") != f"Bearer {self.token}":
            return self._answer(h, 401, {"detail": "unknown token"})
        if self.mode == "hang":
            self.requests.append({"status": None, "rows": 0})
            self.release.wait(60)
            return None
        if self.mode == "fail":
            return self._answer(h, 500, {"detail": "database unavailable"})
        try:
            assert h.headers.get("Content-Encoding") == "gzip", "not gzip"
            raw = gzip.decompress(body)
            batch = json.loads(raw)
            assert batch["format"] == 1, "format"
        except (AssertionError, OSError, ValueError, KeyError) as exc:
            return self._answer(h, 422, {"detail": f"malformed batch: {exc}"})
        if self.max_json_bytes is not None and len(raw) > self.max_json_bytes:
            return self._answer(h, 413, {"detail": "batch too large"})
        if batch["unit"] != self.unit:
            return self._answer(h, 403, {"detail": f"token is not for {batch['unit']}"})
        for i, row in enumerate(batch["rows"]):
            ok = (row.get("kind") in self.KINDS and isinstance(row.get("id"), int)
                  and isinstance(row.get("at"), str) and isinstance(row.get("data"), dict))  # fmt: skip
            if not ok or (row["kind"], row["id"]) in self.bad_rows:
                name = f"{row.get('kind')} {row.get('id')}"
                return self._answer(h, 422, {"detail": f"rows[{i}] ({name}): not storable"})
        stored = 0
        with self._lock:  # one transaction, answered after the commit
            self._db.execute("BEGIN")
            for row in batch["rows"]:
                cur = self._db.execute(
                    "INSERT OR IGNORE INTO rows VALUES (?, ?, ?, ?, ?)",
                    (batch["unit"], row["kind"], row["id"], row["at"], json.dumps(row["data"])),
                )
                stored += cur.rowcount
            self._db.execute("COMMIT")
        n = len(batch["rows"])
        if self.mode == "lose_ack":  # committed; the answer never arrives
            self.mode = "ok"
            self.requests.append({"status": "lost", "rows": n})
            h.close_connection = True
            h.connection.shutdown(socket.SHUT_RDWR)
            return None
        return self._answer(h, 200, {"stored": stored, "duplicates": n - stored}, n, len(raw))


@pytest.fixture
def shore() -> Iterator[Shore]:
    """``shore.url`` answers ``POST /fleet/ingest`` for unit ``shore.unit`` / ``shore.token``."""
    s = Shore()
    try:
        yield s
    finally:
        s.close()


#: The frame rate of the :func:`frames` session, Hz.
FRAMES_RATE_HZ = 100.0


@pytest.fixture(scope="module")
def frames():
    """A 24-position session at 100 Hz as the daemon decodes it (a KVH-like unit, seed 4)."""
    session = simulate_session(kvh_like_truth(4), "24", latitude_deg=45.0, seed=4,
                               rate_hz=FRAMES_RATE_HZ, window_s=12.0, slew_s=3.0,
                               first_hold_s=12.0)  # fmt: skip
    config = DecoderConfig(rate_hz=FRAMES_RATE_HZ)
    batch, _ = decode_bulk(session_to_kvh(session, rng=4)[0], "kvh-a", config)
    return batch
