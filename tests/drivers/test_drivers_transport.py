"""replay:// end to end, the reader thread, and bad ports/URLs."""

from __future__ import annotations

import math
import queue
import time

import numpy as np
import pytest
from drivers_testkit import assert_batches_equal, make_frames

import drivers
from drivers.protocol_replay import parse_replay_url
from drivers.reader import FrameReader
from drivers.transport import open_port, replay_url


def _wait_until(pred, timeout: float = 5.0, step: float = 0.01) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(step)
    return pred()


@pytest.fixture
def capture(tmp_path):
    data, _ = make_frames(3000, seed=21)
    # some damage so the counters have something to say
    buf = bytearray(data)
    buf[36 * 100 + 7] ^= 0xFF
    path = tmp_path / "cap.bin"
    path.write_bytes(b"\x00\x13" + bytes(buf))
    return path


def test_replay_url_options(tmp_path) -> None:
    url = replay_url(tmp_path / "a b.bin", speed="max", chunk="random", seed=4)
    opts = parse_replay_url(url)
    assert opts.path == str(tmp_path / "a b.bin") and opts.speed is None
    assert opts.chunk == "random" and opts.seed == 4
    assert parse_replay_url("replay://rel.bin?speed=2&rate=400&fmt=kvh-b").byte_rate == 2 * 400 * 40
    with pytest.raises(ValueError, match="unknown replay:// option 'sped'"):
        parse_replay_url("replay:///x.bin?sped=2")
    with pytest.raises(ValueError, match="names no capture file"):
        parse_replay_url("replay://")


def test_replay_random_chunks_through_pyserial(capture) -> None:
    port = open_port(replay_url(capture, speed="max", chunk="random", seed=7), timeout=0.01)
    dec = drivers.StreamDecoder()
    parts, sizes = [], []
    while not (port.at_eof and port.in_waiting == 0):
        data = port.read(4096)
        sizes.append(len(data))
        # no host time: a replay at full speed has none, and a read stalled by a busy machine
        # would count sequence wraps (frames lost) the bulk decode cannot see
        parts.append(dec.feed(data, host_time=math.nan))
    parts.append(dec.flush())
    port.close()
    assert len(set(sizes)) > 10 and max(sizes) <= 512
    streamed = drivers.FrameBatch.concat(parts)
    bulk, counters = drivers.decode_bulk(capture.read_bytes())
    assert_batches_equal(bulk, streamed)
    assert counters == dec.counters
    assert counters.frames == 2999 and counters.crc_failures == 1 and counters.resyncs == 2


def test_replay_real_time_pacing(tmp_path) -> None:
    data, _ = make_frames(200, seed=3)
    path = tmp_path / "c.bin"
    path.write_bytes(data)
    port = open_port(replay_url(path, speed=2.0, rate=1000), timeout=0.02)
    t0 = time.monotonic()
    got = bytearray()
    while len(got) < len(data) and time.monotonic() - t0 < 5:
        got += port.read(4096)
    elapsed = time.monotonic() - t0
    assert bytes(got) == data
    # 200 frames at 1000 Hz, twice real time: 0.1 s. Pacing means never sooner; later is only a
    # busy machine (the loop's own 5 s cap ends a stall).
    assert 0.08 <= elapsed < 5.0


def test_reader_over_replay_end_to_end(capture) -> None:
    q: queue.Queue = queue.Queue()
    url = replay_url(capture, speed=20, chunk="random", chunk_max=300, seed=1)
    with FrameReader(url, queue=q) as reader:
        assert _wait_until(lambda: reader.health().counters.frames == 2999)
        health = reader.health()
    assert not reader.health().running
    assert health.connected and health.reconnect_count == 0 and health.last_frame_time
    got = drivers.FrameBatch.concat([q.get_nowait() for _ in range(q.qsize())])
    bulk, _ = drivers.decode_bulk(capture.read_bytes())
    assert_batches_equal(bulk, got)
    assert np.all(np.diff(got.host_time_s) >= 0) and not np.isnan(got.host_time_s).any()


def test_a_held_up_reader_loses_no_frames(capture) -> None:
    """A reader held up for 300 ms (a loaded machine; 300 frame periods at 1 kHz) drains the
    backlog afterwards: dated when read, the stall looked like lost frames, and 64 periods or
    more like a whole wrap of the 7-bit sequence number (128 frames counted lost and time_s
    shifted by 0.128 s: seen under load). Bytes are dated when they were due."""
    q: queue.Queue = queue.Queue()
    held = []

    def slow(batch) -> None:
        if not held:
            held.append(True)
            time.sleep(0.3)

    url = replay_url(capture, speed=2, chunk="random", chunk_max=300, seed=3)
    with FrameReader(url, queue=q, on_batch=slow) as reader:
        assert _wait_until(lambda: reader.health().counters.frames == 2999, timeout=15.0)
        health = reader.health()
    assert health.counters.frames_lost == 1  # the damaged frame only
    got = drivers.FrameBatch.concat([q.get_nowait() for _ in range(q.qsize())])
    bulk, _ = drivers.decode_bulk(capture.read_bytes())
    assert_batches_equal(bulk, got)
    assert np.all(np.diff(got.host_time_s) >= 0)


def test_reader_reconnects_after_replay_error_eof(capture) -> None:
    # eof=error behaves like an unplug at the end of the file: the reader re-opens and the
    # capture plays again; the sequence jump back shows as a gap.
    url = replay_url(capture, speed="max", eof="error")
    with FrameReader(url, backoff_initial=0.01, backoff_max=0.05) as reader:
        assert _wait_until(lambda: reader.health().reconnect_count >= 2)
    h = reader.health()
    assert h.counters.frames >= 2 * 2999 and h.counters.sequence_gaps >= 2
    assert "end of capture" in h.last_error


def test_nonexistent_port_is_a_clear_error() -> None:
    with pytest.raises(drivers.DriverInputError) as err:
        open_port("/dev/ttyDOESNOTEXIST0")
    msg = str(err.value)
    assert msg == "serial port /dev/ttyDOESNOTEXIST0 does not exist (is the device plugged in?)"


@pytest.mark.parametrize(
    ("url", "fragment"),
    [
        ("bogus://x", "unknown scheme 'bogus'://"),
        ("replay:///nope/missing.bin", "replay capture file /nope/missing.bin does not exist"),
        ("replay:///tmp/x.bin?speed=fast", "bad replay:// option value"),
        ("replay:///tmp/x.bin?fmt=kvh-q", "unknown frame format 'kvh-q'"),
        ("loop://?what", "bad port URL"),
        ("", "no serial port given"),
    ],
)
def test_bad_urls_are_clear_one_line_errors(url: str, fragment: str) -> None:
    with pytest.raises(drivers.DriverInputError) as err:
        open_port(url)
    assert fragment in str(err.value)
    assert "\n" not in str(err.value)


def test_reader_rejects_unknown_scheme_and_reports_bad_options() -> None:
    with pytest.raises(drivers.DriverInputError, match="unknown scheme"):
        FrameReader("nope://x")
    reader = FrameReader("replay:///tmp/x.bin?chunk=0").start()
    assert _wait_until(lambda: not reader.health().running)
    assert "bad port URL" in reader.health().last_error
    assert reader.stop()


def test_reader_retries_a_missing_device(tmp_path) -> None:
    reader = FrameReader(str(tmp_path / "ttyMISSING"), backoff_initial=0.01, backoff_max=0.02)
    reader.start()
    # a few failed opens, however busy the machine (a fixed sleep raced the first attempt)
    assert _wait_until(
        lambda: (h := reader.health()).last_error is not None and h.disconnected_s >= 0.09
    )
    h = reader.health()
    assert h.running and not h.connected and "cannot open" in h.last_error
    # what a service needs to say it is degraded, without interpreting the fields itself
    assert h.state == "disconnected" and h.disconnected_s >= 0.09
    assert "ttyMISSING is disconnected" in h.problem and "cannot open" in h.problem
    assert h.last_byte_time is None and h.seconds_since_last_byte is None
    assert h.last_error_time is not None
    assert reader.stop(timeout=1.0)
    assert reader.health().state == "stopped" and "not running" in reader.health().problem


def test_reader_backs_off_when_the_port_opens_but_fails_at_once(monkeypatch) -> None:
    # A flapping device (or a server that accepts and hangs up): the open succeeds, the first
    # read fails. The back-off must still double, not restart at backoff_initial on every open.
    import serial

    import drivers.reader as reader_mod

    opens = []

    class Broken:
        in_waiting = 0

        def read(self, size: int) -> bytes:
            raise serial.SerialException("device reports readiness to read but returned no data")

        def close(self) -> None:
            pass

        def cancel_read(self) -> None:
            pass

    def fake_open(url, **kwargs):
        opens.append(time.monotonic())
        return Broken()

    monkeypatch.setattr(reader_mod, "open_serial", fake_open)
    reader = FrameReader("loop://", backoff_initial=0.01, backoff_max=0.16).start()
    assert _wait_until(lambda: len(opens) >= 7, timeout=20.0)
    assert reader.stop(timeout=5.0)
    # The waits between opens double up to the cap: 0.01, 0.02, 0.04, 0.08, 0.16, 0.16 s. A
    # busy machine only lengthens a wait, so each gap is checked from below: an open that
    # restarted the back-off would show a gap near 0.01 s where 0.16 s is due.
    gaps = np.diff(opens[:7])
    due = np.minimum(0.01 * 2.0 ** np.arange(6), 0.16)
    assert np.all(gaps >= 0.8 * due), (gaps, due)


def test_stop_from_the_callback_ends_the_reader_cleanly(capture) -> None:
    got = []
    reader = FrameReader(replay_url(capture, speed="max", chunk=360))

    def on_batch(batch) -> None:
        got.append(batch)
        reader.stop()  # called on the reader thread itself

    reader._on_batch = on_batch
    reader.start()
    assert _wait_until(lambda: not reader.health().running, timeout=2.0)
    assert len(got) == 1 and reader.health().last_error is None
    assert reader.stop()


def test_replay_at_real_speed_sleeps_instead_of_spinning(tmp_path) -> None:
    # 1 kHz Format A (36,000 bytes/s) read in ~50 ms pieces: the handler must sleep until the
    # bytes are due, not poll every 1/36,000 s.
    data, _ = make_frames(700, seed=5)
    path = tmp_path / "rt.bin"
    path.write_bytes(data)
    port = open_port(replay_url(path, speed=1, rate=1000), timeout=0.1)
    got = bytearray()
    reads = 0
    c0, t0 = time.thread_time(), time.monotonic()
    while len(got) < len(data) and time.monotonic() - t0 < 5:
        got += port.read(1800)
        reads += 1
    cpu, wall = time.thread_time() - c0, time.monotonic() - t0
    port.close()
    assert bytes(got) == data
    # 0.7 s of frames: never sooner (pacing); later only on a busy machine, when each read then
    # finds more bytes due, so a stall does not add reads
    assert 0.6 <= wall < 5.0 and reads <= 20
    assert cpu < 0.05 * wall, (cpu, wall)


def test_read_chunk_waits_for_a_useful_size() -> None:
    from drivers.transport import read_chunk

    class Port:
        timeout = 0.05

        def __init__(self) -> None:
            self.waiting = 10
            self.pauses: list[float] = []
            self.sizes: list[int] = []

        @property
        def in_waiting(self) -> int:
            return self.waiting

        def read(self, size: int) -> bytes:
            self.sizes.append(size)
            return b"x" * min(size, self.waiting)

    port = Port()

    def pause(s: float) -> None:
        port.pauses.append(s)
        port.waiting = 1800

    assert len(read_chunk(port, 1800, 4096, 36_000.0, pause)) == 1800
    assert port.pauses == [pytest.approx((1800 - 10) / 36_000)] and port.sizes == [1800]
    port.waiting = 9000  # a backlog is taken at once, no pause, up to the maximum
    assert len(read_chunk(port, 1800, 4096, 36_000.0, pause)) == 4096
    assert len(port.pauses) == 1
    port.waiting = 0  # without a byte rate: one blocking read of the minimum size
    read_chunk(port, 1800, 4096)
    assert port.sizes[-1] == 1800


def test_the_end_of_a_replayed_capture_is_the_end_of_input(tmp_path, capture) -> None:
    """eof=idle (the default): at the end of the capture the reader delivers a last line that
    has no newline, calls on_end once and says "ended"; a port that keeps going never does."""
    rows = [f"{k / 100:.2f},0.1,0.2,0.3,0.01,0.02,1.0" for k in range(200)]
    path = tmp_path / "log.csv"
    path.write_text("time_s,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z\n" + "\n".join(rows))
    q: queue.Queue = queue.Queue()
    ends: list[int] = []
    url = replay_url(path, speed="max")
    with FrameReader(url, "csv", queue=q, on_end=lambda: ends.append(q.qsize())) as reader:
        assert _wait_until(lambda: reader.health().state == "ended")
        time.sleep(0.2)  # the reader keeps running, idle: on_end is not called again
        health = reader.health()
    got = drivers.FrameBatch.concat([q.get_nowait() for _ in range(q.qsize())])
    assert len(got) == 200 and got.time_s[-1] == pytest.approx(1.99)  # the last line too
    assert len(ends) == 1 and ends[0] >= 1  # after the last frame was delivered
    assert health.running and "replayed to its end" in health.problem and health.ended_s > 0
    looped = replay_url(capture, speed="max", eof="loop")
    with FrameReader(looped, on_end=lambda: ends.append(-1)) as reader:
        assert _wait_until(lambda: reader.health().counters.frames > 2 * 2999)
        assert reader.health().state == "ok"
    assert ends[1:] == []


def test_socket_ports_are_read_in_chunks_not_bytes() -> None:
    """pyserial's socket:// says 1 in in_waiting however much has come: read_chunk used to
    take one byte per pause (8 kB/s for a CSV stream); it now takes what has come."""
    import socket
    import threading

    from drivers.transport import read_chunk

    data = bytes(range(256)) * 200  # 51 kB
    server = socket.create_server(("127.0.0.1", 0))

    def send() -> None:
        conn, _ = server.accept()
        with conn:
            time.sleep(0.3)  # after pyserial's open() has flushed its input
            conn.sendall(data)
            time.sleep(1.0)

    thread = threading.Thread(target=send, daemon=True)
    thread.start()
    port = open_port(f"socket://127.0.0.1:{server.getsockname()[1]}", timeout=0.05)
    got, reads = b"", 0
    deadline = time.monotonic() + 5
    while len(got) < len(data) and time.monotonic() < deadline:
        got += read_chunk(port, 409, 4096, 8192.0)
        reads += 1
    port.close()
    thread.join(5)
    server.close()
    assert got == data and reads < 40, reads
