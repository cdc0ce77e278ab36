"""The ship's NMEA link (drivers.nav_reader): UDP datagrams on 127.0.0.1, a TCP server that
drops the connection, a pseudo-terminal unplugged and replugged; the reader reads on."""

from __future__ import annotations

import datetime as dt
import os
import socket
import sys
import threading
import time
import tty

import pytest

from drivers.nav_reader import NavReader
from drivers.nmea import epoch_sentences
from drivers.transport import known_protocols, open_serial

START = dt.datetime(2026, 3, 1, 12, 0, 0, tzinfo=dt.UTC)


def _epoch(k: int, lat: float = 57.7) -> bytes:
    return epoch_sentences(START + dt.timedelta(seconds=k), lat, 11.9, 5.0, 0.2, 30.0, 31.0)


def _wait_until(pred, timeout: float = 10.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.01)
    return pred()


def _bound_port(reader: NavReader) -> int:
    assert _wait_until(lambda: reader.port is not None)
    return reader.port.local_port


def test_the_nav_schemes_are_known_ports() -> None:
    assert {"udp", "tcp"} <= set(known_protocols())
    with pytest.raises(Exception, match="udp://"):
        open_serial("udp://127.0.0.1")  # no port


def test_udp_datagrams_with_and_without_line_ends() -> None:
    """One sentence per datagram without its CR LF (as some talkers send), a whole epoch in
    one datagram, a garbled datagram: every good sentence is read, stamped on arrival."""
    fixes = []
    reader = NavReader("udp://127.0.0.1:0", on_fixes=fixes.extend, timeout=0.05).start()
    try:
        port = _bound_port(reader)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            before = time.monotonic()
            for line in _epoch(0).splitlines():
                tx.sendto(line, ("127.0.0.1", port))
            tx.sendto(_epoch(1), ("127.0.0.1", port))
            tx.sendto(b"$GPGGA,garbled*00", ("127.0.0.1", port))
            tx.sendto(_epoch(2, lat=57.8), ("127.0.0.1", port))
            assert _wait_until(lambda: len(fixes) == 12)
        after = time.monotonic()
        h = reader.health()
        assert h.state == "ok" and h.connected and h.fixes == 12 and h.latitude_deg == 57.8
        assert h.counters.bad_checksum == 1 and "garbled" in h.last_skipped
        assert all(before <= f.time_s <= after for f in fixes)  # the host's monotonic clock
        assert [f.sentence for f in fixes[:4]] == ["GGA", "RMC", "VTG", "HDT"]
        assert reader.track.window(before, after).latitude_deg == pytest.approx(57.7 + 0.1 / 3)
    finally:
        assert reader.stop()


def test_a_tcp_link_that_drops_is_reopened() -> None:
    """A multiplexer's TCP server sends an epoch and closes; the reader logs, backs off,
    connects again and reads the next one."""
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    served = []

    def serve() -> None:
        for k in range(2):
            conn, _ = server.accept()
            conn.sendall(_epoch(k, lat=10.0 + k))
            served.append(k)
            time.sleep(0.1)
            conn.close()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    reader = NavReader(f"tcp://127.0.0.1:{port}", timeout=0.05, backoff_initial=0.02).start()
    try:
        assert _wait_until(lambda: reader.health().fixes == 8)
        h = reader.health()
        assert h.reconnect_count >= 1 and h.latitude_deg == 11.0 and h.running
        assert served == [0, 1]
    finally:
        assert reader.stop()
        server.close()
        thread.join(2)


class NmeaPty:
    """A talker on a serial line: the device side of a pty behind a symlink (a replug is a new
    pty behind the same path)."""

    def __init__(self, link) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        tmp = f"{link}.new"
        os.symlink(os.ttyname(self.slave), tmp)
        os.replace(tmp, link)
        self.link = link

    def send(self, data: bytes) -> None:
        os.write(self.master, data)

    def unplug(self) -> None:
        os.unlink(self.link)
        os.close(self.master)
        os.close(self.slave)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux ptys")
def test_a_serial_talker_unplugged_and_replugged(tmp_path) -> None:
    link = tmp_path / "gps"
    talker = NmeaPty(link)
    reader = NavReader(str(link), timeout=0.02, backoff_initial=0.02, backoff_max=0.1,
                       silence_s=0.3).start()  # fmt: skip
    try:
        assert _wait_until(lambda: reader.health().connected)
        talker.send(_epoch(0)[:30])  # a sentence cut by the unplug
        talker.send(_epoch(0)[30:] + _epoch(1))
        assert _wait_until(lambda: reader.health().fixes == 8)
        assert _wait_until(lambda: reader.health().state == "silent")
        assert "no fix" in reader.health().problem
        talker.unplug()
        assert _wait_until(lambda: reader.health().state == "disconnected")
        h = reader.health()
        assert h.running and not h.connected and h.last_error in h.problem
        talker = NmeaPty(link)
        assert _wait_until(lambda: reader.health().connected)
        talker.send(b"1,A*3F\r\n" + _epoch(2, lat=-33.9))  # the tail of a line, then an epoch
        assert _wait_until(lambda: reader.health().fixes == 12)
        h = reader.health()
        assert h.reconnect_count == 1 and h.latitude_deg == -33.9 and h.state == "ok"
    finally:
        assert reader.stop()
        talker.unplug()
