"""Start-up cost of the command line: `recal calibrate` on 24 positions and `recal --help`.

Each command runs as a fresh process (``python -m service.cli.main``), so the time includes
the interpreter, every import and the work. For `recal calibrate` the script also reports the
share of that time spent importing (``python -X importtime``: the sum of the top-level imports,
each including its sub-imports) and the fit itself (the time calibrate prints).

    python benchmarks/bench_cli_startup.py [--runs 7]

Target: `recal --help` <= 0.3 s (a miss is printed as such). `recal calibrate` has no target of
its own: what is left after the CLI imports only what the command needs is the interpreter,
numpy and the engine (scipy.optimize for LM), and the fit.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CLI = [sys.executable, "-m", "service.cli.main"]
HELP_TARGET_S = 0.3
HEAVY = ("numpy", "scipy", "recal.solve.calibrate", "recal.detect.static_detector", "drivers")


def wall(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def import_profile(cmd: list[str]) -> tuple[float, float, float, str]:
    """(wall s, import s, fit s, heaviest top-level import) of one run under -X importtime."""
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-X", "importtime", *cmd[1:]],
        check=True,
        capture_output=True,
        text=True,
    )
    elapsed = time.perf_counter() - t0
    top: list[tuple[int, str]] = []
    for line in proc.stderr.splitlines():
        m = re.match(r"import time:\s+\d+ \|\s+(\d+) \| ( *)(\S+)$", line)
        if m and len(m.group(2)) <= 1:  # depth 0: one space after the bar
            top.append((int(m.group(1)), m.group(3)))
    fit = re.search(r", ([0-9.]+) s\n", proc.stdout)
    heaviest = max(top)[1] if top else "-"
    return elapsed, sum(us for us, _ in top) / 1e6, float(fit.group(1)) if fit else 0.0, heaviest


def parser_imports() -> list[str]:
    """Heavy modules imported by building the parser (should be none)."""
    code = (
        "import sys, service.cli.main as m; m.build_parser(); "
        f"print(' '.join(n for n in {HEAVY!r} if n in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    return out.stdout.split()


def verdict(value: float, target: float) -> str:
    return "PASS" if value <= target else "MISS"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7, help="runs per command (median reported)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        pos = Path(tmp) / "pos24.csv"
        subprocess.run(
            [*CLI, "simulate", "--design", "24", "--latitude", "45", "-o", str(pos)],
            check=True,
            stderr=subprocess.DEVNULL,
        )
        calibrate = [*CLI, "calibrate", str(pos), "--latitude", "45"]
        wall(calibrate)  # warm the file cache
        help_s = statistics.median(wall([*CLI, "--help"]) for _ in range(args.runs))
        cal_s = statistics.median(wall(calibrate) for _ in range(args.runs))
        profiles = [import_profile(calibrate) for _ in range(args.runs)]
    p_wall = statistics.median(p[0] for p in profiles)
    p_import = statistics.median(p[1] for p in profiles)
    p_fit = statistics.median(p[2] for p in profiles)
    heaviest = statistics.mode(p[3] for p in profiles)
    heavy = parser_imports()
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} cores, median of {args.runs} runs")
    print(f"{'measurement':58s} {'value':>9s} {'target':>8s} verdict")
    print(f"{'recal --help, process start to exit':58s} {help_s:8.3f}s {HELP_TARGET_S:7.2f}s "
          f"{verdict(help_s, HELP_TARGET_S)}")  # fmt: skip
    print(f"{'recal calibrate (24 positions, LM), process start to exit':58s} {cal_s:8.3f}s "
          f"{'-':>8s} -")  # fmt: skip
    print(f"{'  under -X importtime: wall':58s} {p_wall:8.3f}s")
    print(f"{'  imports (sum of top-level imports)':58s} {p_import:8.3f}s "
          f"({p_import / p_wall:.0%} of the wall time)")  # fmt: skip
    print(f"{'  the fit itself (as calibrate reports it)':58s} {p_fit:8.3f}s")
    print(f"{'  heaviest top-level import':58s} {heaviest:>9s}")
    print(f"heavy modules imported by building the parser: {', '.join(heavy) or 'none'}")


if __name__ == "__main__":
    main()
