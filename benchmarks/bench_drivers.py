"""Drivers throughput: bulk and streaming decode of KVH Format A, and pyserial's read overhead.

Run: python benchmarks/bench_drivers.py [--frames N]. Takes well under a minute on 2 cores.
Targets (issue 3): bulk >= 1,000,000 frames/s; streaming with 4 KiB reads >= 200,000 frames/s.
pyserial reading is compared with the wire: 921600 baud carries 92,160 bytes/s (2,560 Format A
frames/s), so reading must be at least that fast to keep up.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import drivers  # noqa: E402
from drivers.transport import open_serial, replay_url  # noqa: E402

READ = 4096
WIRE_BYTES_S = 921600 / 10  # 8N1: 10 bits on the wire per byte


def make_capture(n: int) -> bytes:
    rng = np.random.default_rng(0)
    gyro = drivers.physical_to_raw_gyro(rng.normal(0, 10, (n, 3)))
    accel = rng.normal(0, 0.5, (n, 3))
    return drivers.encode_frames(
        "kvh-a", gyro=gyro, accel_g=accel, seq=np.arange(n), temperature_raw=np.full(n, 40)
    )


def best_of(fn, repeat: int = 3) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def bench_bulk(data: bytes, n: int) -> float:
    drivers.decode_bulk(data[: 36 * 1000])  # build the CRC tables outside the timing
    return n / best_of(lambda: drivers.decode_bulk(data))


def bench_stream(data: bytes, n: int) -> float:
    def run() -> None:
        dec = drivers.StreamDecoder("kvh-a")
        got = 0
        for i in range(0, len(data), READ):
            got += len(dec.feed(data[i : i + READ]))
        assert got == n, got

    return n / best_of(run)


def bench_replay_read(path: str, nbytes: int) -> float:
    def run() -> None:
        port = open_serial(replay_url(path, speed="max"), timeout=0)
        got = 0
        while got < nbytes:
            got += len(port.read(READ))
        port.close()

    return nbytes / best_of(run)


def bench_reader(path: str, n: int) -> float:
    """FrameReader end to end: replay://?speed=max -> pyserial -> StreamDecoder -> callback."""
    from drivers.reader import FrameReader

    done = threading.Event()
    count = [0]

    def on_batch(batch) -> None:
        count[0] += len(batch)
        if count[0] >= n:
            done.set()

    t0 = time.perf_counter()
    with FrameReader(replay_url(path, speed="max"), on_batch=on_batch, timeout=0.01):
        done.wait(60)
    return count[0] / (time.perf_counter() - t0)


def bench_pty_read(data: bytes) -> float:
    """pyserial's posix Serial reading 4 KiB at a time from a pty fed by a writer thread."""
    master, slave = os.openpty()
    import tty

    tty.setraw(slave)
    port = open_serial(os.ttyname(slave), timeout=0.5)

    def writer() -> None:
        view = memoryview(data)
        while view:
            k = os.write(master, view[:READ])
            view = view[k:]

    t = threading.Thread(target=writer, daemon=True)
    t0 = time.perf_counter()
    t.start()
    got = 0
    while got < len(data):
        chunk = port.read(min(READ, max(port.in_waiting, 1)))
        if not chunk:
            break
        got += len(chunk)
    dt = time.perf_counter() - t0
    t.join(1)
    port.close()
    os.close(master)
    os.close(slave)
    return got / dt


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1_000_000, help="bulk capture size")
    args = ap.parse_args()
    n_bulk = args.frames
    n_stream = min(300_000, n_bulk)
    t0 = time.perf_counter()
    data = make_capture(n_bulk)
    print(
        f"capture: {n_bulk} Format A frames, {len(data) / 1e6:.1f} MB "
        f"(encoded in {time.perf_counter() - t0:.2f} s)"
    )
    rows = []
    fps = bench_bulk(data, n_bulk)
    rows.append(("bulk decode (decode_bulk)", fps, fps * 36, 1_000_000, "frames/s"))
    sdata = data[: n_stream * 36]
    fps = bench_stream(sdata, n_stream)
    rows.append(("streaming decode, 4 KiB feeds", fps, fps * 36, 200_000, "frames/s"))
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "cap.bin")
        Path(path).write_bytes(sdata)
        bps = bench_replay_read(path, len(sdata))
        rps = bench_reader(path, n_stream)
    rows.append(
        ("pyserial replay://?speed=max read(4096)", bps / 36, bps, WIRE_BYTES_S / 36, "wire")
    )
    rows.append(("FrameReader thread over replay://?speed=max", rps, rps * 36, 200_000, "frames/s"))
    if sys.platform.startswith("linux"):
        bps = bench_pty_read(sdata[: 36 * 100_000])
        rows.append(
            ("pyserial posix Serial on a pty, 4 KiB", bps / 36, bps, WIRE_BYTES_S / 36, "wire")
        )
    print()
    print(f"| {'path':<44} | {'frames/s':>12} | {'MB/s':>8} | {'target frames/s':>15} | result |")
    print(f"|{'-' * 46}|{'-' * 14}|{'-' * 10}|{'-' * 17}|--------|")
    ok = True
    for name, fps, bps, target, _ in rows:
        passed = fps >= target
        ok &= passed
        print(
            f"| {name:<44} | {fps:>12,.0f} | {bps / 1e6:>8.1f} | {target:>15,.0f} | "
            f"{'PASS' if passed else 'MISS':<6} |"
        )
    print(f"\ntotal {time.perf_counter() - t0:.1f} s")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
