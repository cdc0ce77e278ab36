"""`recal calibrate` on a voyage's many short windows: wall time against the window count (issue 25,
item 5).

Run: python benchmarks/bench_many_windows.py [--windows 100,500,2000,5000] [--repeat 1]. A few
minutes on 2 cores.

For each N a hull-fixed FOG (KVH 1750 class: ARW 0.012 deg/sqrt(h), 20 ug/sqrt(Hz)) is simulated
sample by sample (``recal.sim.session``, design "vessel": z up, random headings, tilts within
1.5 deg) with N holds of 5 s joined by 1 s turns at 50 Hz -- the short windows a moored hull's
lulls give -- and written as ``recal positions`` would: the positions CSV (with std columns) and
its slews side file ``.slews.npz``. Then, side by side, each as a fresh process
(``python -m service.cli.main``, stdout discarded):

* LM on the windows alone: ``recal calibrate POS --latitude 45 --json --no-slews``;
* the default: ``recal calibrate POS --latitude 45 --json`` (LM with the slews side file, as
  after ``recal positions``).

Target: 2,000 windows in under 10 s for both. The exit code is printed too (0: a partial
calibration, as the heading-only design allows). Every figure is printed with its verdict,
misses included.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from recal.model.coefficients import CoefficientSet  # noqa: E402
from recal.sim.session import session_positions, session_slews, simulate_session  # noqa: E402
from recal.sim.simulate import NoiseSpec  # noqa: E402
from service.cli.positions import slews_path  # noqa: E402

TARGET_S, TARGET_N = 10.0, 2000


def write_voyage(path: Path, n: int, seed: int) -> None:
    """N short holds of a hull-fixed FOG, as ``recal positions`` writes them."""
    s = simulate_session(
        CoefficientSet.seed_truth(), "vessel", n, 45.0, seed=seed, rate_hz=50.0, window_s=5.0,
        slew_s=1.0, noise=NoiseSpec(arw_deg_rt_h=0.012, vrw_ug_rt_hz=20.0),
    )  # fmt: skip
    path.write_text(session_positions(s).to_csv_text())
    slews_path(path).write_bytes(session_slews(s).to_npz_bytes())


def measure(argv: list[str]) -> tuple[float, int]:
    """(wall s, exit code) of ``argv`` as a fresh process."""
    t = time.perf_counter()
    rc = subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode
    return time.perf_counter() - t, rc


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--windows", default="100,500,2000,5000")
    ap.add_argument("--repeat", type=int, default=1, help="runs per case; the fastest counts")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    sizes = sorted(int(n) for n in args.windows.split(","))
    recal = [sys.executable, "-m", "service.cli.main", "calibrate"]
    cases = {"LM, windows alone": ["--no-slews"], "default (LM with slews)": []}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            path = Path(tmp) / f"voyage{n}.csv"
            write_voyage(path, n, args.seed)
            row = [n]
            for extra in cases.values():
                cmd = [*recal, str(path), "--latitude", "45", "--json", *extra]
                runs = [measure(cmd) for _ in range(args.repeat)]
                row.append((min(r[0] for r in runs), max(r[1] for r in runs)))
            rows.append(row)
            print(f"{n:,} windows: " + ", ".join(
                f"{name} {wall:.2f} s (exit {rc})"
                for name, (wall, rc) in zip(cases, row[1:], strict=True)
            ), flush=True)  # fmt: skip
    print(f"\nrecal calibrate, hull-fixed FOG, 5 s holds and 1 s turns at 50 Hz, a fresh process "
          f"each, fastest of {args.repeat}:\n")  # fmt: skip
    print("| windows | " + " | ".join(cases) + " |")
    print("|---|" + "---|" * len(cases))
    for n, *cells in rows:
        print(f"| {n:,} | " + " | ".join(f"{wall:.2f} s" for wall, _ in cells) + " |")
    print()
    for n, *cells in rows:
        if n != TARGET_N:
            continue
        for name, (wall, rc) in zip(cases, cells, strict=True):
            ok = wall < TARGET_S and rc == 0
            print(f"{TARGET_N:,} windows, {name}: {wall:.2f} s, exit {rc} (target < "
                  f"{TARGET_S:g} s, exit 0): {'PASS' if ok else 'MISS'}")  # fmt: skip


if __name__ == "__main__":
    main()
