"""`recal calibrate` time and peak memory against the number of positions (issue 7, item 5).

Run: python benchmarks/bench_scale.py [--positions 100,1000,10000] [--sensor both]. About half a
minute on 2 cores.

For each N, ``recal simulate --design random --positions N`` writes a positions file, then
``recal calibrate`` runs on it as a subprocess of a small wrapper that reports the child's wall
time and peak RSS (``resource.getrusage(RUSAGE_CHILDREN)``, so nothing of this script is
counted). The in-process CSV parse time of the same file is printed beside it. Targets: time and
memory linear in N (no R x R matrix: economy SVDs only), 10,000 positions under 10 s and 500 MB.
Every measurement is printed with its verdict, misses included.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from recal.model.positions import Positions  # noqa: E402

TARGET_S, TARGET_MB, TARGET_N = 10.0, 500.0, 10_000

#: Runs its argv as a child, then prints the child's wall time (s) and peak RSS (kB, Linux).
_WRAPPER = (
    "import resource, subprocess, sys, time\n"
    "t = time.perf_counter()\n"
    "rc = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL).returncode\n"
    "wall = time.perf_counter() - t\n"
    "print(wall, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, rc)\n"
)


def measure(argv: list[str]) -> tuple[float, float, int]:
    """(wall s, peak RSS MB, exit code) of ``argv`` run as a fresh process."""
    out = subprocess.run(
        [sys.executable, "-c", _WRAPPER, *argv], capture_output=True, text=True, check=True
    ).stdout.split()
    return float(out[0]), float(out[1]) / 1024.0, int(out[2])


def recal(*args: str) -> list[str]:
    return [sys.executable, "-m", "service.cli.main", *args]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--positions", default="100,1000,10000")
    ap.add_argument("--sensor", default="both", choices=("gyro", "accel", "both"))
    ap.add_argument("--repeat", type=int, default=3, help="runs per size; the fastest counts")
    args = ap.parse_args()
    sizes = sorted(int(n) for n in args.positions.split(","))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            path = Path(tmp) / f"pos{n}.csv"
            sim = recal("simulate", "--design", "random", "--positions", str(n), "--seed", "1",
                        "--sensor", args.sensor, "--latitude", "45", "-o", str(path))  # fmt: skip
            subprocess.run(sim, check=True, capture_output=True)
            t = time.perf_counter()
            Positions.from_csv_text(path.read_text(), str(path))
            parse_s = time.perf_counter() - t
            cmd = recal("calibrate", str(path), "--latitude", "45", "--json")
            runs = [measure(cmd) for _ in range(args.repeat)]
            wall, rc = min(r[0] for r in runs), max(r[2] for r in runs)
            mb = min(r[1] for r in runs)
            doc = json.loads(subprocess.run(cmd, capture_output=True, text=True).stdout or "{}")
            rows.append((n, wall, mb, rc, parse_s, doc.get("observability", {}).get("rank")))
    print(f"recal calibrate --sensor {args.sensor} (LM), random design, a subprocess each, "
          f"fastest of {args.repeat}:\n")  # fmt: skip
    print("| positions | wall time | peak RSS | CSV parse (in process) | rank | exit |")
    print("|---|---|---|---|---|---|")
    for n, wall, mb, rc, parse_s, rank in rows:
        print(f"| {n:,} | {wall:.2f} s | {mb:.0f} MB | {parse_s:.2f} s | {rank} | {rc} |")
    print()
    # linear: the cost of one more position does not grow with the number of positions
    marginal = [
        ((w1 - w0) / (n1 - n0) * 1e6, (m1 - m0) / (n1 - n0) * 1024)
        for (n0, w0, m0, *_), (n1, w1, m1, *_) in zip(rows, rows[1:])
    ]
    for ((n0, *_), (n1, *_)), (us, kb) in zip(zip(rows, rows[1:]), marginal):
        print(f"{n0:,} -> {n1:,} positions: {us:.0f} us and {kb:.1f} kB per added position")
    if len(marginal) >= 2:
        (us0, kb0), (us1, kb1) = marginal[-2], marginal[-1]
        ok = us1 <= 2.0 * max(us0, 50.0) and kb1 <= 2.0 * max(kb0, 5.0)
        print(f"per-position cost at the largest size vs the one before (x{us1 / max(us0, 1e-9):.1f} "
              f"time, x{kb1 / max(kb0, 1e-9):.1f} memory); target: linear (<= 2x, allowing for "
              f"timing noise on a shared machine): {'PASS' if ok else 'MISS'}")  # fmt: skip
    big = [r for r in rows if r[0] == TARGET_N]
    if big:
        _, wall, mb, rc, *_ = big[0]
        ok = wall < TARGET_S and mb < TARGET_MB and rc == 0
        print(f"{TARGET_N:,} positions: {wall:.2f} s, {mb:.0f} MB (target < {TARGET_S:g} s and "
              f"< {TARGET_MB:g} MB): {'PASS' if ok else 'MISS'}")  # fmt: skip


if __name__ == "__main__":
    main()
