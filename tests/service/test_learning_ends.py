"""Learning the first noise floor ends (issue 27): on a stream that goes quiet, after ``learn_s``
of wall time without ``learn_s`` of device time, and at the end of a replayed capture, the daemon
learns from the frames it holds, says so in ``/health`` and the events, and stores the windows.

The acceptance test replays imucal's 102 s hand-held Ferraris session (../shared/data/imucal) as
a CSV line stream into the daemon: it stores as many windows as ``recal positions`` finds on the
same file (at the end of a ``replay://`` capture), or all but the open one (a stream left open
and quiet).
"""

from __future__ import annotations

import csv
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from drivers import DecoderConfig, decode_bulk
from drivers.transport import replay_url
from recal.sim.session import simulate_session
from service.capture_sim import kvh_like_truth, session_to_kvh
from service.config import DetectorSettings, DeviceSettings, SchedulerSettings, Settings
from service.daemon import Housekeeping
from service.events import Events
from service.ingest.setup import detector_config
from service.pipeline import Ingest

FERRARIS = Path("imucal") / "example_ferraris_session.csv"
FERRARIS_RATE = 102.4
COLUMNS = "gyro_x=gyr_x,gyro_y=gyr_y,gyro_z=gyr_z,accel_x=acc_x,accel_y=acc_y,accel_z=acc_z"
RATE = 100.0


@pytest.fixture(scope="module")
def positions_found(shared_data: Path, tmp_path_factory: pytest.TempPathFactory) -> int:
    """Windows ``recal positions`` finds in the Ferraris session (the number to match)."""
    from service.cli.main import main

    out = tmp_path_factory.mktemp("positions") / "positions.csv"
    args = ["positions", str(shared_data / FERRARIS), "--format", "csv", "--rate",
            f"{FERRARIS_RATE:g}", "--columns", COLUMNS, "-o", str(out)]  # fmt: skip
    assert main(args) == 0
    with out.open(newline="") as f:
        return sum(1 for _ in csv.DictReader(f))


def _settings(tmp_path: Path, url: str, **detector: float) -> Settings:
    """The daemon's defaults for a CSV unit at 102.4 Hz; only the scheduler is kept from
    starting a calibration (not what is tested, and seconds of CPU)."""
    return Settings(
        database_url=f"sqlite:///{tmp_path / 'recal.db'}",
        publish_path=str(tmp_path / "coefficients.json"),
        device=DeviceSettings(url=url, format="csv", rate_hz=FERRARIS_RATE, columns=COLUMNS),
        detector=DetectorSettings(**detector),
        scheduler=SchedulerSettings(min_positions=1000, min_new_positions=1000),
        api={"port": 0},
    )


def _wait(condition, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)


def _events(http: httpx.Client, kind: str) -> list[str]:
    return [e["message"] for e in http.get("/log", params={"limit": 100}).json() if
            e["kind"] == kind]  # fmt: skip


def test_a_replayed_csv_stream_ends_learning_and_stores_every_window(
    tmp_path, shared_data, positions_found, serve
) -> None:
    """The issue's 102 s hand-held recording, as a CSV line stream through replay:// with the
    default detector (learn_s 120 s): the end of the capture is the end of input, learning ends
    from the 101.3 s held and every window is stored, the last one closed too."""
    url = replay_url(shared_data / FERRARIS, speed="max")
    with serve(_settings(tmp_path, url)) as (base, service), httpx.Client(base_url=base) as http:
        service.reader.start()  # nobody calls end_of_input: the reader says the capture ended
        _wait(lambda: service.ingest.input_ended and service.feeder.waiting_s() is None)
        health = http.get("/health").json()
        learning = health["service"]["detector"]["learning"]
        assert learning["state"] == "learned" and learning["ended_by"] == "end_of_input"
        assert 100.0 < learning["learned_s"] < 102.0 and learning["learn_s"] == 120.0
        assert "the input has ended" in learning["message"]
        assert health["service"]["reader"]["state"] == "ended"
        assert health["positions"] == health["service"]["windows"] == positions_found >= 10
        assert len(_events(http, "input")) == 1
        (ended,) = [m for m in _events(http, "noise_floor") if "learning ended early" in m]
        assert "the input has ended" in ended and "10376 frames go to the detector" in ended


@pytest.fixture
def open_stream(shared_data: Path) -> Iterator[str]:
    """socket://: a TCP server that sends the Ferraris CSV once, then keeps the connection open
    and sends nothing (the issue's stream that "stayed open and went quiet")."""
    data = (shared_data / FERRARIS).read_bytes()
    server = socket.create_server(("127.0.0.1", 0))
    done = threading.Event()

    def talk() -> None:
        conn, _ = server.accept()
        with conn:
            time.sleep(0.3)  # pyserial's socket:// drops what came before its open() returned
            conn.sendall(data)
            done.wait(120)

    thread = threading.Thread(target=talk, daemon=True)
    thread.start()
    try:
        yield f"socket://127.0.0.1:{server.getsockname()[1]}"
    finally:
        done.set()
        thread.join(10)
        server.close()


def test_a_stream_left_open_and_quiet_ends_learning(
    tmp_path, positions_found, open_stream, serve
) -> None:
    """The same CSV over a socket that stays open: after learn_quiet_s (2 s here, 10 s by
    default) without a frame, learning ends from what is held and every window but the open one
    (the stream may resume) is stored."""
    settings = _settings(tmp_path, open_stream, learn_quiet_s=2.0)
    with serve(settings) as (base, service), httpx.Client(base_url=base) as http:
        stop = threading.Event()
        keeper = threading.Thread(target=Housekeeping(service, stop, tick_s=0.2).run, daemon=True)
        keeper.start()  # its tick polls the pipeline, as in the daemon
        try:
            service.reader.start()
            _wait(lambda: not service.ingest.learning)
            _wait(lambda: service.ingest.windows >= positions_found - 1)
            health = http.get("/health").json()
        finally:
            stop.set()
            keeper.join(10)
        learning = health["service"]["detector"]["learning"]
        assert learning["state"] == "learned" and learning["ended_by"] == "quiet", learning
        assert learning["waited_s"] >= 2.0 and "sent no frame" in learning["message"]
        assert health["service"]["frames"] == 10376
        assert positions_found - 1 <= health["positions"] <= positions_found
        assert any("learning ended early: the stream has sent no frame" in m
                   for m in _events(http, "noise_floor"))  # fmt: skip
        assert _events(http, "input") == []  # a quiet stream has not ended


# ---- the rules, on Ingest with a clock of its own ------------------------------------------


class Clock:
    """Host time a test moves by hand."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture(scope="module")
def frames():
    """A 24-position session at 100 Hz (holds of 4 s, slews of 2 s): 147 s of device time."""
    session = simulate_session(kvh_like_truth(3), "24", latitude_deg=45.0, seed=3, rate_hz=RATE,
                               window_s=4.0, slew_s=2.0, first_hold_s=5.0)  # fmt: skip
    batch, _ = decode_bulk(session_to_kvh(session, rng=3)[0], "kvh-a", DecoderConfig(rate_hz=RATE))
    return session, batch


def _ingest(store, clock: Clock, **kw) -> tuple[Ingest, int]:
    settings = Settings(device=DeviceSettings(rate_hz=RATE))
    sid = store.add_session("test")
    return Ingest(store, sid, detector_config(settings), events=Events(store), clock=clock,
                  **kw), sid  # fmt: skip


def _feed(ingest: Ingest, batch, clock: Clock, seconds: float, wall_per_s: float = 1.0) -> None:
    """Feed ``seconds`` of frames in 1 s batches, the clock moving ``wall_per_s`` per batch."""
    step = int(RATE)
    for lo in range(0, int(seconds * RATE), step):
        ingest.feed(batch[lo : lo + step])
        clock.now += wall_per_s


def test_a_quiet_stream_ends_learning_at_learn_quiet_s(sqlite_store, frames) -> None:
    session, batch = frames
    clock = Clock()
    ingest, _ = _ingest(sqlite_store, clock, learn_quiet_s=10.0)
    _feed(ingest, batch, clock, 60.0)  # 60 s of 120: still learning
    assert ingest.learning and ingest.learning_health()["state"] == "learning"
    clock.now += 9.0 - 1.0  # 9 s since the last frame
    assert ingest.poll() == [] and ingest.learning
    clock.now += 1.0
    stored = ingest.poll()
    assert not ingest.learning and len(stored) == ingest.windows > 0
    h = ingest.learning_health()
    assert (h["state"], h["ended_by"], h["learned_s"]) == ("learned", "quiet", 60.0)
    assert h["waited_s"] == 69.0  # from the first frame held to the decision, host time
    messages = [e["message"] for e in sqlite_store.events(20) if e["kind"] == "noise_floor"]
    assert any(m.startswith("learning ended early: the stream has sent no frame for 10 s")
               for m in messages)  # fmt: skip
    # the held frames went to the detector: the holds they cover are stored but the open one
    holds = int((session.hold_last < 60.0 * RATE).sum())
    assert holds - 1 <= ingest.windows <= holds


def test_a_slow_stream_ends_learning_after_learn_s_of_wall_time(sqlite_store, frames) -> None:
    _, batch = frames
    clock = Clock()
    ingest, _ = _ingest(sqlite_store, clock, learn_s=40.0)
    _feed(ingest, batch, clock, 19.0, wall_per_s=2.0)  # 19 s of device time in 38 s of wall
    assert ingest.learning
    _feed(ingest, batch[1900:], clock, 2.0, wall_per_s=2.0)  # 40 s of wall passed at 20 s
    ingest.poll()  # the last batch is held a second before the detector's turn
    assert not ingest.learning and ingest.windows > 0
    h = ingest.learning_health()
    assert h["ended_by"] == "wall_time" and "40 s of wall time have passed" in h["message"]


def test_device_time_ends_learning_as_before_and_counts_every_frame_step(
    sqlite_store, frames
) -> None:
    """At the device's own pace the device time wins (learned_s counts the steps between
    batches: 1 s batches add 1 s each, not 0.99 s)."""
    _, batch = frames
    clock = Clock()
    ingest, _ = _ingest(sqlite_store, clock, learn_s=30.0)
    _feed(ingest, batch, clock, 29.0)
    ingest.poll()  # the last batch is held a second before the detector's turn
    assert ingest.learning and ingest.learner.learned_s == pytest.approx(28.99)
    _feed(ingest, batch[2900:], clock, 2.0)
    h = ingest.learning_health()
    assert h["ended_by"] == "device_time" and h["message"].startswith("learned from the first")
    assert not [e for e in sqlite_store.events(20) if "learning ended early" in e["message"]]


def test_too_few_frames_stay_held_then_the_end_of_input_says_why(sqlite_store, frames) -> None:
    _, batch = frames
    clock = Clock()
    ingest, _ = _ingest(sqlite_store, clock)
    ingest.feed(batch[:50])  # half a second: not enough to learn a floor from
    clock.now += 30.0
    for _ in range(3):  # said once, not at every poll
        assert ingest.poll() == []
    assert ingest.learning and ingest.learning_health()["state"] == "learning"
    said = [e["message"] for e in sqlite_store.events(20) if e["kind"] == "noise_floor"]
    assert len(said) == 1 and said[0].startswith("cannot learn the noise floor yet")
    ingest.end_of_input()
    ingest.end_of_input()  # once only
    h = ingest.learning_health()
    assert h["state"] == "failed" and h["ended_by"] == "end_of_input"
    assert [e["kind"] for e in sqlite_store.events(20)].count("input") == 1
