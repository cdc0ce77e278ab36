"""A pseudo-terminal plays the device: frames at a rate, unplug, replug; the reader copes."""

from __future__ import annotations

import os
import sys
import time
import tty

import pytest
from drivers_testkit import make_frames

from drivers.reader import FrameReader

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux ptys")


class PtyDevice:
    """The device side of a pty, reachable through a symlink (a pty's name changes on replug)."""

    def __init__(self, link) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)  # no echo or line editing before the reader configures it
        tmp = f"{link}.new"
        os.symlink(os.ttyname(self.slave), tmp)
        os.replace(tmp, link)
        self.link = link

    def write_frames(self, seq0: int, n: int, rate_hz: float = 2000.0, batch: int = 10) -> None:
        data, _ = make_frames(n, seed=seq0, seq0=seq0)
        step = 36 * batch
        for i in range(0, len(data), step):
            os.write(self.master, data[i : i + step])
            time.sleep(batch / rate_hz)

    def unplug(self) -> None:
        os.unlink(self.link)
        os.close(self.master)
        os.close(self.slave)


def _wait_until(pred, timeout: float = 5.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.01)
    return pred()


def test_unplug_and_replug(tmp_path) -> None:
    link = tmp_path / "imu"
    device = PtyDevice(link)
    got = []
    reader = FrameReader(
        str(link), on_batch=got.append, timeout=0.02, backoff_initial=0.02, backoff_max=0.1
    ).start()
    try:
        assert _wait_until(lambda: reader.health().connected)
        device.write_frames(seq0=0, n=200)
        assert _wait_until(lambda: reader.health().counters.frames == 200)

        device.unplug()
        assert _wait_until(lambda: not reader.health().connected)
        time.sleep(0.1)  # a few failed re-opens while the device is away
        assert not reader.health().connected and reader.health().running

        device = PtyDevice(link)  # replug: a new pty behind the same path
        assert _wait_until(lambda: reader.health().connected)
        assert reader.health().reconnect_count == 1
        # 50 frames (seq 200..249) were sent while unplugged
        device.write_frames(seq0=250, n=200)
        assert _wait_until(lambda: reader.health().counters.frames == 400)
        h = reader.health()
        assert h.counters.sequence_gaps == 1 and h.counters.frames_lost == 50
        assert h.counters.crc_failures == 0 and h.last_frame_time is not None
        seqs = [int(s) for b in got for s in b.seq]
        assert seqs == [i % 128 for i in list(range(200)) + list(range(250, 450))]
    finally:
        assert reader.stop(timeout=2.0)
        device.unplug()
