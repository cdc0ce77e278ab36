"""Peak memory and speed of `recal positions` on 1 h and 4 h KVH Format-A captures at 1 kHz.

Each capture (129.6 MB and 518 MB) is written in pieces to a temporary folder and deleted
afterwards: holds of 20.48 s joined by 5.12 s slews through 8 poses, 20 deg/h gyro noise and
1e-4 g accel noise. The pattern is encoded once and repeated (its length is a whole number of
128-frame sequence periods, so the bytes repeat exactly). `recal positions` then runs as a
subprocess with only the flags docs/reference.md#cli shows (flag-free: two passes, the noise
floor and then the windows); its peak resident memory is the child's ru_maxrss. For
comparison the script also runs the old whole-file path (`decode_bulk` + `detect_static`) on
the 1 h capture, unless --no-bulk.

    python benchmarks/bench_positions_memory.py [--hours 1 4] [--no-bulk]

Targets: peak RSS under 300 MB and the same for 1 h and 4 h (within 10 %); at least 100x real
time (the static detector's target, decode included).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from drivers import encode_frames, physical_to_raw_gyro

RATE = 1000.0
HOLD_S, SLEW_S = 20.48, 5.12  # 25.6 s per pose = 200 sequence periods of 128 frames
POSES = np.array(
    [[0, 0, 1], [0, 1, 0], [1, 0, 0], [0, 0, -1], [0, -1, 0], [-1, 0, 0], [0.6, 0, 0.8],
     [0, 0.8, -0.6]],
    dtype=float,
)  # fmt: skip
RSS_TARGET_MB = 300.0
SPEED_TARGET = 100.0

_MAXRSS = (
    "import resource, subprocess, sys\n"
    "rc = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)\n"
    "sys.stderr.write(rc.stderr.decode()[-2000:]) if rc.returncode else None\n"
    "print(rc.returncode, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n"
)


def cycle_bytes(seed: int = 0) -> bytes:
    """One pass through the poses (8 x 25.6 s), as Format A bytes."""
    rng = np.random.default_rng(seed)
    n_hold, n_slew = round(HOLD_S * RATE), round(SLEW_S * RATE)
    per = n_hold + n_slew
    n = per * len(POSES)
    i = np.arange(n)
    k, j = np.divmod(i, per)
    u = np.clip((j - n_hold) / n_slew, 0.0, 1.0)
    s = (1 - np.cos(np.pi * u)) / 2
    a = (1 - s)[:, None] * POSES[k] + s[:, None] * POSES[(k + 1) % len(POSES)]
    accel = a / np.linalg.norm(a, axis=1, keepdims=True) + 1e-4 * rng.standard_normal((n, 3))
    gyro = np.tile([8.0, -3.0, 10.0], (n, 1)) + 20.0 * rng.standard_normal((n, 3))
    gyro[:, 0] += 90 * 3600 * np.pi / 2 * np.sin(np.pi * u) / SLEW_S  # deg/h while slewing
    return encode_frames("kvh-a", gyro=physical_to_raw_gyro(gyro), accel_g=accel, seq=i,
                         temperature_raw=np.full(n, 25.0))  # fmt: skip


def write_capture(path: Path, hours: float, cycle: bytes) -> int:
    frames = round(hours * 3600 * RATE)
    total = frames * 36
    with open(path, "wb") as fh:
        written = 0
        while written < total:
            piece = cycle[: total - written]
            fh.write(piece)
            written += len(piece)
    return frames


def run_child(argv: list[str]) -> tuple[float, float]:
    """(wall s, peak RSS MB) of one command in a fresh process."""
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", _MAXRSS, *argv], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    rc, kb = out.stdout.split()
    if rc != "0":
        raise SystemExit(f"command failed ({rc}): {' '.join(argv)}\n{out.stderr}")
    return wall, int(kb) / 1024.0


def positions(capture: Path, out: Path, *flags: str) -> list[str]:
    return [sys.executable, "-m", "service.cli.main", "positions", str(capture), "--format",
            "kvh-a", *flags, "-o", str(out)]  # fmt: skip


def bulk(capture: Path) -> list[str]:
    code = (
        "import sys, drivers\n"
        "from recal.detect.static_detector import detect_static\n"
        "b, c = drivers.decode_bulk(open(sys.argv[1], 'rb').read(), 'kvh-a')\n"
        "r = detect_static(b.time_s, b.gyro_dph, b.accel_g, b.temperature_c, b.valid, "
        "b.lost_before)\n"
        "print(len(r.windows))\n"
    )
    return [sys.executable, "-c", code, str(capture)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, nargs="+", default=[1.0, 4.0])
    ap.add_argument("--no-bulk", action="store_true", help="skip the whole-file comparison")
    ap.add_argument("--dir", help="folder for the temporary captures (default: system temp)")
    args = ap.parse_args()
    cycle = cycle_bytes()
    rows = []
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        folder = Path(tmp)
        for hours in args.hours:
            capture = folder / f"capture_{hours:g}h.bin"
            t0 = time.perf_counter()
            frames = write_capture(capture, hours, cycle)
            gen = time.perf_counter() - t0
            size = capture.stat().st_size
            print(f"{hours:g} h: {frames:,} frames, {size / 1e6:.1f} MB written in {gen:.1f} s",
                  file=sys.stderr)  # fmt: skip
            out = folder / "pos.csv"
            wall, rss = run_child(positions(capture, out))
            windows = out.read_text().count("\n") - 1
            rows.append((f"recal positions, flag-free (3 passes: floor, windows, slews), {hours:g} h", wall, rss,
                         hours * 3600 / wall, windows))  # fmt: skip
            if hours == args.hours[0]:
                wall, rss = run_child(positions(capture, out, "--init-still", "10"))
                windows = out.read_text().count("\n") - 1
                rows.append((f"recal positions --init-still 10 (1 pass), {hours:g} h", wall, rss,
                             hours * 3600 / wall, windows))  # fmt: skip
                if not args.no_bulk:
                    wall, rss = run_child(bulk(capture))
                    rows.append((f"whole file: decode_bulk + detect_static, {hours:g} h", wall,
                                 rss, hours * 3600 / wall, None))  # fmt: skip
            capture.unlink()
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} cores; KVH Format A at 1 kHz")
    print(f"{'run':58s} {'wall':>8s} {'peak RSS':>10s} {'x real time':>12s} {'windows':>8s}")
    for name, wall, rss, speed, windows in rows:
        w = "-" if windows is None else str(windows)
        print(f"{name:58s} {wall:7.1f}s {rss:8.0f}MB {speed:11.0f}x {w:>8s}")
    streamed = [r for r in rows if r[0].startswith("recal positions, flag-free")]
    peak = max(r[2] for r in streamed)
    spread = peak / min(r[2] for r in streamed) - 1
    slowest = min(r[3] for r in rows if r[0].startswith("recal positions"))
    print(f"peak RSS of recal positions: {peak:.0f} MB (target < {RSS_TARGET_MB:.0f} MB): "
          f"{'PASS' if peak < RSS_TARGET_MB else 'MISS'}")  # fmt: skip
    print(f"RSS growth from {args.hours[0]:g} h to {args.hours[-1]:g} h: {spread:+.1%} "
          f"(target within 10 %): {'PASS' if spread <= 0.10 else 'MISS'}")  # fmt: skip
    print(f"slowest recal positions run: {slowest:.0f}x real time (target >= "
          f"{SPEED_TARGET:.0f}x): {'PASS' if slowest >= SPEED_TARGET else 'MISS'}")  # fmt: skip


if __name__ == "__main__":
    main()
