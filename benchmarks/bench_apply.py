"""Time and peak memory of `recal apply` on a 1 h KVH Format-A capture at 1 kHz (issue 39).

The capture is bench_positions_memory.py's (holds joined by slews through 8 poses, 129.6 MB for
1 h), written to a temporary folder and deleted afterwards, with the coefficients below: the
seed model plus temperature and quadratic terms, so every sample takes the nonlinear inverse and
its refinement. `recal apply` runs as a subprocess with only the flags docs/apply.md shows; its
peak resident memory is the child's ru_maxrss. Run with --hours 1 4 to see that memory does not
grow with the recording's length.

    python benchmarks/bench_apply.py [--hours 1] [--keep DIR]

Targets: peak RSS under 300 MB and not growing with the hours (within 10 %).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from bench_positions_memory import cycle_bytes, run_child, write_capture

RSS_TARGET_MB = 300.0
#: A KVH unit (outputs already in deg/h and g) with the terms that cost the most to invert.
COEFFICIENTS = {
    "gyro": {
        "scale": [1.00012, 0.99995, 1.00003],
        "bias": [0.02, -0.01, 0.015],
        "misalignment": {"Exz": 1e-4, "Exy": -2e-4, "Eyz": 5e-5, "Eyx": 1e-4, "Ezy": -1e-4,
                         "Ezx": 2e-4},
    },
    "accel": {
        "scale": [1.0002, 0.9999, 1.0001],
        "bias": [2e-4, -1e-4, 3e-4],
        "misalignment": {"Exz": 4e-4, "Exy": -2.5e-4, "Eyz": 1.2e-4, "Eyx": 3.1e-4,
                         "Ezy": -1.8e-4, "Ezx": 2.2e-4},
        "quadratic": [1.5e-5, -1e-5, 2e-5],
    },
    "effects": {
        "gyro.bias_temperature": {"kTx": 0.002, "kTy": -0.001, "kTz": 0.003},
        "accel.scale_temperature": {"sTx": 1e-5, "sTy": -2e-5, "sTz": 1e-5},
    },
    "t0_c": 25.0,
    "schema": "recal.coefficients/1",
}  # fmt: skip


def main() -> None:
    import sys

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, nargs="+", default=[1.0])
    ap.add_argument("--keep", metavar="DIR", help="write the files here and keep them")
    args = ap.parse_args()
    folder = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="bench_apply_"))
    folder.mkdir(parents=True, exist_ok=True)
    coeffs = folder / "coefficients.json"
    coeffs.write_text(json.dumps(COEFFICIENTS))
    cycle = cycle_bytes()
    peaks = []
    for hours in args.hours:
        capture = folder / f"capture_{hours:g}h.bin"
        out = folder / f"calibrated_{hours:g}h.csv"
        frames = write_capture(capture, hours, cycle)
        argv = [sys.executable, "-m", "service.cli.main", "apply", str(coeffs), str(capture),
                "--format", "kvh-a", "-o", str(out)]  # fmt: skip
        wall, rss = run_child(argv)
        rows = sum(1 for _ in open(out)) - 1
        peaks.append(rss)
        print(
            f"{hours:g} h, {frames} frames ({capture.stat().st_size / 1e6:.1f} MB in, "
            f"{out.stat().st_size / 1e6:.0f} MB out, {rows} rows): {wall:.1f} s wall, "
            f"{hours * 3600 / wall:.0f}x real time, peak RSS {rss:.0f} MB "
            f"({'PASS' if rss < RSS_TARGET_MB else 'MISS'} < {RSS_TARGET_MB:g} MB)"
        )
        if not args.keep:
            capture.unlink()
            out.unlink()
    if len(peaks) > 1:
        growth = peaks[-1] / peaks[0] - 1
        print(f"peak RSS growth {growth:+.1%} ({'PASS' if abs(growth) <= 0.10 else 'MISS'})")


if __name__ == "__main__":
    main()
