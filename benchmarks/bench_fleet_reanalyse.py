"""The workbench across the fleet on Dask (issue 37, item 4): ``recal fleet reanalyse --effects``.

A simulated fleet of one model (recal.sim.simulate.simulate_positions: random orientations at
45 deg, the seed coefficients), of which ``carriers`` units carry a hidden gyro g-sensitivity
of one common value (:data:`G_SENSITIVITY`, about five times its typical size); every unit's
windows (and, with ``versions``, an accepted version before them) reach a SQLite shore
through its real ingest path (service.fleet.batch.read_batch, FleetStore.ingest), then
``reanalyse`` re-fits every unit with and without the effect.

    python benchmarks/bench_fleet_reanalyse.py                 # acceptance: 50 units, 30 carry it
    python benchmarks/bench_fleet_reanalyse.py --scaling       # 200 units on 1, then 2 workers

The acceptance prints how many carriers the effect is significant in (>= 27 of 30 wanted), how
many of the others (<= 1 of 20) and the model's verdict (systematic). The scaling run times the
same re-analysis on a local Dask cluster of 1 and of 2 worker processes, side by side in one run.
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import sys
import tempfile
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from stopping import stop_on_sigterm  # noqa: E402

from recal.model.coefficients import CoefficientSet  # noqa: E402
from recal.model.terms import catalogue_terms  # noqa: E402
from recal.sim.simulate import simulate_positions  # noqa: E402
from service.fleet.batch import read_batch  # noqa: E402
from service.fleet.store import FleetStore  # noqa: E402

EFFECT = "gyro.g_sensitivity"
#: The hidden g-sensitivity of the model's carriers, deg/h/g (typical change 0.01).
G_SENSITIVITY = [0.05, -0.03, 0.02, 0.01, 0.04, -0.02, 0.03, 0.02, -0.05]
MODEL = "KVH-1750"
START = datetime(2026, 1, 1, tzinfo=UTC)


def serial(i: int) -> str:
    return f"SN-{i:04d}"


def carriers_of(units: int, carriers: int) -> set[str]:
    """Which units carry the effect: spread over the serials, not the first ones."""
    picked = np.linspace(0, units - 1, carriers).round().astype(int) if carriers else []
    return {serial(int(i)) for i in picked}


def _send(store: FleetStore, unit: str, rows: list[dict]) -> None:
    body = gzip.compress(json.dumps({"format": 1, "unit": unit, "rows": rows}).encode())
    store.ingest(store.unit_by_serial(unit), read_batch(body, "gzip", 1 << 26), len(body))


def fill(
    url: str,
    units: int,
    carriers: int,
    windows: int = 24,
    seed: int = 0,
    versions: bool = True,
) -> set[str]:
    """A shore at ``url`` with ``units`` units of :data:`MODEL`, ``carriers`` of them with the
    hidden effect, each with ``windows`` windows (and an accepted version of the seed
    coefficients before them); the carriers' serials."""
    store = FleetStore(url)
    store.create_schema()
    carrying = carriers_of(units, carriers)
    seed_truth = CoefficientSet.seed_truth()
    hidden = catalogue_terms()[EFFECT]
    try:
        for i in range(units):
            unit = serial(i)
            store.add_unit(unit, MODEL)
            truth = seed_truth.copy()
            extra = []
            if unit in carrying:
                truth.values[EFFECT] = np.array(G_SENSITIVITY)
                extra = [hidden]
            pos = simulate_positions(truth, "random", windows, 45.0, seed=seed * 100003 + i,
                                     hidden=extra)  # fmt: skip
            rows: list[dict] = []
            if versions:
                at = START.isoformat().replace("+00:00", "Z")
                doc = {"version": 1, "accepted": True, "created_at": at,
                       "document": {"coefficients": seed_truth.to_json_dict(),
                                    "latitude_deg": 45.0, "height_m": 0.0}}  # fmt: skip
                rows.append({"kind": "version", "id": 1, "at": at, "data": doc})
            for k in range(windows):
                at = (START + timedelta(minutes=12 * (k + 1))).isoformat().replace("+00:00", "Z")
                data = {c: float(v[k]) for c, v in pos.columns.items()}
                rows.append({"kind": "window", "id": k + 1, "at": at,
                             "data": {**data, "session": 1}})  # fmt: skip
            _send(store, unit, rows)
    finally:
        store.close()
    return carrying


def counts(report: dict, carrying: set[str]) -> dict:
    """Significant among the carriers and among the others, and the model's verdict."""
    hit = {u["unit"]: bool(u["refit"]["effects"].get(EFFECT, {}).get("significant"))
           for u in report["units"]}  # fmt: skip
    return {
        "carriers": len(carrying),
        "found_in_carriers": sum(hit[u] for u in carrying),
        "others": len(hit) - len(carrying),
        "found_in_others": sum(v for u, v in hit.items() if u not in carrying),
        "verdict": report["refit"]["models"][MODEL][EFFECT]["verdict"],
        "homogeneity": report["refit"]["models"][MODEL][EFFECT]["homogeneity"],
    }


def main() -> int:
    from service.fleet.reanalysis import reanalyse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, default=None, help="default 50 (acceptance), 200")
    ap.add_argument("--carriers", type=int, default=None, help="default 3/5 of the units")
    ap.add_argument("--windows", type=int, default=24, help="windows per unit (default 24)")
    ap.add_argument("--workers", type=int, default=2, help="acceptance's workers (default 2)")
    ap.add_argument("--scaling", action="store_true", help="time 1 and 2 workers")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    stop_on_sigterm()  # a timeout's SIGTERM stops the local cluster's workers
    units = args.units or (200 if args.scaling else 50)
    carriers = args.carriers if args.carriers is not None else (3 * units) // 5
    with tempfile.TemporaryDirectory() as tmp:
        url = f"sqlite:///{Path(tmp) / 'fleet.db'}"
        t0 = time.perf_counter()
        carrying = fill(url, units, carriers, args.windows, args.seed)
        print(f"filled {units} units x {args.windows} windows ({carriers} carry {EFFECT}) in "
              f"{time.perf_counter() - t0:.1f} s; {os.cpu_count()} CPUs, load average "
              f"{os.getloadavg()[0]:.1f}", flush=True)  # fmt: skip
        for n in [1, 2] if args.scaling else [args.workers]:
            t0 = time.perf_counter()
            report = reanalyse(url, workers=n, effects=[EFFECT], windows=args.windows)
            took = time.perf_counter() - t0
            c = counts(report, carrying)
            same = c["homogeneity"] or {}
            print(f"{n} worker(s): {took:.1f} s ({took / units:.2f} s per unit, load average "
                  f"{os.getloadavg()[0]:.1f}); significant in {c['found_in_carriers']} of "
                  f"{c['carriers']} carriers, {c['found_in_others']} of {c['others']} others; "
                  f"verdict {c['verdict']} (homogeneity chi2 {same.get('chi2')} on "
                  f"{same.get('dof')} dof, p {same.get('p_value')})", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
