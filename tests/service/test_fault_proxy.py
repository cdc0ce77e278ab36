"""benchmarks/fault_proxy.py between a real HTTP client (httpx) and a real HTTP server (http.server in a
thread): traffic unchanged without faults, each fault as the sync client will meet it, the
seeded schedule reproducible, and nothing left running after close."""

from __future__ import annotations

import hashlib
import json
import socket
import threading
import time
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import httpx
import pytest
from fault_proxy import FaultProxy, Faults, main, outage_schedule, outages


class _Shore(ThreadingHTTPServer):
    """Counts the batches it received whole (and answered) and the partial bodies it saw."""

    daemon_threads = True

    def __init__(self) -> None:
        super().__init__(("127.0.0.1", 0), _Handler)
        self.lock = threading.Lock()
        self.handled = 0
        self.partial: list[tuple[int, int]] = []  # (bytes received, Content-Length)


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"  # keep-alive: several exchanges per connection
    server: _Shore

    def log_message(self, format: str, *args: object) -> None:
        pass

    def _answer(self, document: dict[str, object]) -> None:
        body = json.dumps(document).encode()
        self.send_response(200)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def do_GET(self) -> None:
        self._answer({"pong": True})

    def do_POST(self) -> None:
        length = int(self.headers["Content-Length"])
        try:
            body = self.rfile.read(length)
        except OSError:
            body = b""
        if len(body) < length:
            with self.server.lock:
                self.server.partial.append((len(body), length))
            self.close_connection = True
            return
        with self.server.lock:
            self.server.handled += 1  # "committed" before answering, like the shore
        self._answer({"bytes": len(body), "sha256": hashlib.sha256(body).hexdigest()})


@pytest.fixture(scope="module")
def shore() -> Iterator[_Shore]:
    server = _Shore()
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05})
    thread.start()
    try:
        yield server
    finally:
        server.shutdown()
        server.server_close()
        thread.join(5)


@pytest.fixture
def proxy(shore: _Shore) -> Iterator[FaultProxy]:
    with FaultProxy(shore.server_address[:2], seed=1) as p:  # type: ignore[arg-type]
        yield p


def _body(n: int, salt: int = 0) -> bytes:
    return bytes((i * 31 + salt) % 251 for i in range(n))


def test_traffic_passes_unchanged_without_faults(shore: _Shore, proxy: FaultProxy) -> None:
    before = shore.handled
    with httpx.Client(base_url=proxy.url, timeout=5.0) as client:
        assert client.get("/ping").json() == {"pong": True}
        sizes = [0, 1, 100, 65535, 65536, 300_000]
        for i, n in enumerate(sizes):
            body = _body(n, i)
            answer = client.post("/fleet/ingest", content=body).json()
            assert answer == {"bytes": n, "sha256": hashlib.sha256(body).hexdigest()}
    stats = proxy.stats
    assert shore.handled == before + len(sizes)
    assert stats.connections == 1  # one keep-alive connection carried every exchange
    assert stats.bytes_up > sum(sizes) and stats.bytes_down > 0
    assert stats.cuts == {"down": 0, "request": 0, "response": 0}
    assert proxy.cuts == []


def test_a_dropped_request_reaches_the_server_in_part_and_fails_the_client(
    shore: _Shore, proxy: FaultProxy
) -> None:
    before, partial = shore.handled, len(shore.partial)
    proxy.set(drop_request=1.0)
    with httpx.Client(base_url=proxy.url, timeout=5.0) as client:
        with pytest.raises(httpx.TransportError):
            client.post("/fleet/ingest", content=_body(200_000))
    deadline = time.monotonic() + 2.0
    while len(shore.partial) == partial and time.monotonic() < deadline:
        time.sleep(0.01)
    assert shore.handled == before  # nothing of the batch was handled
    received, length = shore.partial[-1]
    assert length == 200_000 and 0 < received < length  # seed 1: the cut falls mid-body
    (cut,) = proxy.cuts
    assert (cut.connection, cut.exchange, cut.kind) == (0, 0, "request")
    assert proxy.stats.cuts["request"] == 1
    assert proxy.stats.bytes_up == cut.offset >= received  # exactly that much got through


def test_a_dropped_response_is_a_lost_acknowledgement(shore: _Shore, proxy: FaultProxy) -> None:
    before = shore.handled
    proxy.set(drop_response=1.0)
    with httpx.Client(base_url=proxy.url, timeout=5.0) as client:
        with pytest.raises(httpx.TransportError):
            client.post("/fleet/ingest", content=_body(5000))
    assert shore.handled == before + 1  # the server committed and answered
    assert [c.kind for c in proxy.cuts] == ["response"]
    proxy.clear()
    with httpx.Client(base_url=proxy.url, timeout=5.0) as client:  # the retry goes through
        assert client.post("/fleet/ingest", content=_body(5000)).json()["bytes"] == 5000
    assert shore.handled == before + 2


def test_a_blackhole_makes_the_client_time_out(shore: _Shore, proxy: FaultProxy) -> None:
    before = shore.handled
    proxy.set(blackhole=True)
    t0 = time.monotonic()
    with httpx.Client(base_url=proxy.url, timeout=0.3) as client:
        with pytest.raises(httpx.TimeoutException):
            client.post("/fleet/ingest", content=_body(1000))
    assert 0.3 <= time.monotonic() - t0 < 2.0
    assert shore.handled == before and proxy.stats.blackholed == 1
    proxy.set(blackhole=False)
    with httpx.Client(base_url=proxy.url, timeout=5.0) as client:
        assert client.get("/ping").status_code == 200


def test_an_open_connection_stalls_in_a_blackhole_and_resumes(proxy: FaultProxy) -> None:
    with httpx.Client(base_url=proxy.url, timeout=2.0) as client:
        assert client.get("/ping").status_code == 200
        proxy.set(blackhole=True)
        timer = threading.Timer(0.2, proxy.set, kwargs={"blackhole": False})
        timer.start()
        t0 = time.monotonic()
        assert client.get("/ping").status_code == 200  # same connection, held 0.2 s
        assert time.monotonic() - t0 >= 0.15
        timer.join()
    assert proxy.stats.connections == 1


def test_a_link_down_refuses_and_cuts_then_comes_back(shore: _Shore, proxy: FaultProxy) -> None:
    with httpx.Client(base_url=proxy.url, timeout=2.0) as client:
        assert client.get("/ping").status_code == 200  # an open keep-alive connection
        proxy.set(down=True)
        assert proxy.stats.cuts["down"] == 1 and proxy.stats.active == 0
        with pytest.raises(httpx.ConnectError):
            client.get("/ping")
        with pytest.raises(httpx.ConnectError):
            httpx.get(proxy.url + "/ping", timeout=2.0)
        proxy.set(down=False)  # listening again on the same port
        assert client.get("/ping").status_code == 200


def test_coming_up_on_a_port_taken_meanwhile_stays_down(proxy: FaultProxy) -> None:
    proxy.set(down=True)
    with socket.create_server(proxy.address):  # another program took the port
        with pytest.raises(OSError):
            proxy.set(down=False)
        assert proxy.faults.down
    proxy.set(down=False)
    assert httpx.get(proxy.url + "/ping", timeout=2.0).status_code == 200


def test_delay_and_bandwidth_are_added(proxy: FaultProxy) -> None:
    def timed(content: bytes) -> float:
        with httpx.Client(base_url=proxy.url, timeout=5.0) as client:
            client.get("/ping")  # connect first: time one exchange
            t0 = time.monotonic()
            client.post("/fleet/ingest", content=content)
            return time.monotonic() - t0

    plain = timed(b"x")
    proxy.set(delay_s=0.1)
    delayed = timed(b"x")
    assert 0.2 <= delayed < plain + 0.6  # 0.1 s each way
    proxy.set(delay_s=0.0, bytes_per_s=200_000)
    assert 0.2 <= timed(_body(50_000)) < 1.5  # 50 kB at 200 kB/s: 0.25 s


def _rehearse(shore: _Shore, seed: int) -> tuple[list[str], list[tuple[int, int, object]]]:
    outcomes = []
    with FaultProxy(shore.server_address[:2], seed=seed) as proxy:  # type: ignore[arg-type]
        proxy.set(drop_request=0.3, drop_response=0.3)
        with httpx.Client(base_url=proxy.url, timeout=5.0) as client:
            for i in range(24):
                try:
                    client.post("/fleet/ingest", content=_body(3000 + 100 * i))
                    outcomes.append("ok")
                except httpx.TransportError:
                    outcomes.append("error")
        cuts = [(c.connection, c.exchange, c.kind) for c in proxy.cuts]
        # a request is cut at the same byte; an answer within its first chunk, as read
        cuts += [(c.connection, c.exchange, c.offset) for c in proxy.cuts if c.kind == "request"]
    assert len(proxy.cuts) == outcomes.count("error")
    return outcomes, cuts


def test_the_seeded_schedule_is_reproducible(shore: _Shore) -> None:
    first, again, other = (_rehearse(shore, s) for s in (3, 3, 4))
    assert first == again
    assert first != other
    assert 0 < first[0].count("error") < 24
    assert outage_schedule(5, 60.0, 5.0, 1.0) == outage_schedule(5, 60.0, 5.0, 1.0)
    steps = outage_schedule(5, 60.0, 5.0, 1.0)
    assert [c for _, c in steps[:2]] == [{"down": True}, {"down": False}]
    assert steps[-1][1] == {"down": False} and steps[-1][0] <= 60.0
    assert [t for t, _ in steps] == sorted(t for t, _ in steps)
    assert next(iter(outages(5, 5.0, 1.0))) == steps[0]


def test_a_schedule_plays_while_traffic_runs(proxy: FaultProxy) -> None:
    proxy.play([(0.0, {"down": True}), (0.3, {"down": False, "delay_s": 0.05})])
    time.sleep(0.05)
    with pytest.raises(httpx.ConnectError):
        httpx.get(proxy.url + "/ping", timeout=1.0)
    time.sleep(0.4)
    assert httpx.get(proxy.url + "/ping", timeout=1.0).status_code == 200
    assert proxy.faults == Faults(delay_s=0.05)
    with pytest.raises(TypeError):
        proxy.play([(0.0, {"no_such_fault": True})])
    with pytest.raises(ValueError, match="probability"):
        proxy.set(drop_request=1.5)


def test_close_is_prompt_and_leaves_no_thread(shore: _Shore) -> None:
    # the threads this test found (another test's may end meanwhile: compare sets, not counts)
    threads = set(threading.enumerate())
    proxy = FaultProxy(shore.server_address[:2]).start()  # type: ignore[arg-type]
    busy = httpx.Client(base_url=proxy.url, timeout=5.0)
    assert busy.get("/ping").status_code == 200  # an open connection
    proxy.set(blackhole=True)
    stuck = httpx.Client(base_url=proxy.url, timeout=5.0)
    waiting = threading.Thread(target=lambda: pytest.raises(httpx.TransportError, stuck.get, "/"))
    waiting.start()  # a blackholed connection, waiting for an answer
    while proxy.stats.blackholed == 0:
        time.sleep(0.01)
    t0 = time.monotonic()
    proxy.close()
    assert time.monotonic() - t0 < 1.0
    waiting.join(2.0)  # the proxy closed its socket: the client fails at once
    busy.close()
    stuck.close()
    assert not [t for t in threading.enumerate() if t.name == "fault-proxy"]
    deadline = time.monotonic() + 2.0
    while set(threading.enumerate()) - threads and time.monotonic() < deadline:
        time.sleep(0.01)  # the server's handler threads see their connections end
    assert not set(threading.enumerate()) - threads
    proxy.close()  # again: nothing to do


def test_the_command_line_says_what_is_wrong_in_one_line(
    capsys: pytest.CaptureFixture[str], proxy: FaultProxy
) -> None:
    for argv, wrong in [
        (["--target", "shore"], "'shore' is not HOST:PORT"),
        (["--target", "shore:1", "--drop-request", "2"], "'2' is not a probability"),
        (["--target", "shore:1", "--outages", "5"], "'5' is not UP_S:DOWN_S"),
        ([], "required: --target"),
    ]:
        with pytest.raises(SystemExit) as exit_:
            main(argv)
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and wrong in err and err.count("\n") == 1, err
    host, port = proxy.address  # taken
    assert main(["--listen", f"{host}:{port}", "--target", "shore:1"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"python benchmarks/fault_proxy.py: cannot listen on {host}:{port}: ")
    assert err.count("\n") == 1
