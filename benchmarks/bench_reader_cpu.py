"""CPU cost of following a live 1 kHz stream: FrameReader and record() on a pty and on replay://.

Run: python benchmarks/bench_reader_cpu.py [--seconds 10] [--rate 1000]. Takes about 4 x the
duration. Each case runs in its own child process, which measures its own CPU time
(time.process_time: user + system, every thread) while it follows the stream; the device side
(a pty fed one Format A frame per 1/rate s by the parent, or replay://?speed=1) is not counted.
Target (issue 8): at most 5 % of one core at 1 kHz.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
import tty
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import drivers  # noqa: E402
from drivers.transport import replay_url  # noqa: E402

TARGET_PCT = 5.0


def make_capture(n: int) -> bytes:
    rng = np.random.default_rng(0)
    gyro = drivers.physical_to_raw_gyro(rng.normal(0, 10, (n, 3)))
    return drivers.encode_frames("kvh-a", gyro=gyro, accel_g=rng.normal(0, 0.5, (n, 3)), n=n)


def child(kind: str, url: str, seconds: float, rate: float, out: str) -> None:
    """Follow ``url`` for ``seconds``; print CPU seconds, frames and reads/chunks as JSON."""
    config = drivers.DecoderConfig(rate_hz=rate)
    drivers.decode_bulk(make_capture(10), "kvh-a", config)  # CRC tables: built once per process
    frames = [0]
    batches = [0]

    def on_batch(batch: drivers.FrameBatch) -> None:
        frames[0] += len(batch)
        batches[0] += 1

    if kind == "reader":
        reader = drivers.FrameReader(url, "kvh-a", config, on_batch=on_batch)
        c0, t0 = time.process_time(), time.monotonic()
        reader.start()
        time.sleep(seconds)
        reader.stop()
        cpu, wall = time.process_time() - c0, time.monotonic() - t0
        result = {"frames": frames[0], "deliveries": batches[0]}
    else:
        stop = threading.Event()
        threading.Timer(seconds, stop.set).start()
        c0, t0 = time.process_time(), time.monotonic()
        res = drivers.record(url, out, stop_event=stop, config=config)
        cpu, wall = time.process_time() - c0, time.monotonic() - t0
        result = {"frames": res.counters.frames, "deliveries": res.chunks}
    result.update(cpu_s=cpu, wall_s=wall)
    print(json.dumps(result))


def feed_pty(master: int, data: bytes, rate: float, seconds: float, stop: threading.Event) -> None:
    """One frame per 1/rate s on a fixed schedule (late writes catch up, never drift)."""
    t0 = time.monotonic()
    k = 0
    n = len(data) // 36
    while not stop.is_set() and k < n:
        due = t0 + k / rate
        now = time.monotonic()
        if due > now:
            time.sleep(due - now)
        try:
            os.write(master, data[36 * k : 36 * (k + 1)])
        except OSError:
            return
        k += 1


def run_case(kind: str, source: str, seconds: float, rate: float, tmp: Path) -> dict:
    data = make_capture(int(rate * (seconds + 3)))
    stop = threading.Event()
    feeder = None
    master = slave = -1
    if source == "pty":
        master, slave = os.openpty()
        tty.setraw(slave)
        url = os.ttyname(slave)
        feeder = threading.Thread(
            target=feed_pty, args=(master, data, rate, seconds + 3, stop), daemon=True
        )
    else:
        path = tmp / "cap.bin"
        path.write_bytes(data)
        url = replay_url(path, speed=1, rate=rate)
    cmd = [sys.executable, __file__, "--child", kind, url, str(seconds), str(rate)]
    cmd.append(str(tmp / f"{kind}-{source}.bin"))
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    if feeder is not None:
        time.sleep(0.5)  # let the child import and open the port before the device talks
        feeder.start()
    out, _ = proc.communicate(timeout=seconds + 60)
    stop.set()
    if master >= 0:
        os.close(master)
        os.close(slave)
    result = json.loads(out.strip().splitlines()[-1])
    result.update(kind=kind, source=source)
    return result


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        _, _, kind, url, seconds, rate, out = sys.argv
        child(kind, url, float(seconds), float(rate), out)
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    args = ap.parse_args()
    print(f"{args.rate:g} Hz Format A ({args.rate * 36:,.0f} bytes/s), {args.seconds:g} s per case")
    print()
    print("| path | CPU s | wall s | % of one core | frames | reads delivered/s | result |")
    print("|---|---:|---:|---:|---:|---:|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for kind, source in (
            ("reader", "pty"),
            ("reader", "replay"),
            ("record", "pty"),
            ("record", "replay"),
        ):
            r = run_case(kind, source, args.seconds, args.rate, Path(tmp))
            pct = 100.0 * r["cpu_s"] / r["wall_s"]
            label = {
                "reader": "FrameReader",
                "record": "record()",
            }[kind] + {"pty": " on a pty", "replay": " on replay://?speed=1"}[source]
            verdict = "PASS" if pct <= TARGET_PCT else "MISS"
            print(
                f"| {label} | {r['cpu_s']:.2f} | {r['wall_s']:.1f} | {pct:.1f} % "
                f"| {r['frames']:,} | {r['deliveries'] / r['wall_s']:,.0f} | {verdict} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
