"""The fleet prior (issue 28): recovered against true ageing rates, per coefficient, on
simulated fleets; the naive spread beside it; outliers found and false alarms.

Each fleet: ``--units`` units of one model over ``--years``, recalibrated every 1 to 6 months;
the versions' 1-sigma are the sigma model of recal.fleet.simulate (a real calibration of the
simulated 24-position design, times 0.7 to 1.5 per version); true rates 0.3 to 3 times that
1-sigma per sqrt-month (relative for scale factors), and ``--outliers`` units ageing five
times faster. Target: every rate within 20 % (a miss is printed as such).

    python benchmarks/bench_fleet_prior.py [--units 200] [--years 5] [--seeds 7 8 9]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from recal import CoefficientSet, calibrate, fleet_prior, simulate_fleet, simulate_positions
from recal.fleet.history import is_relative

TARGET = 0.20


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, default=200)
    ap.add_argument("--years", type=float, default=5.0)
    ap.add_argument("--outliers", type=int, default=4)
    ap.add_argument("--seeds", type=int, nargs="+", default=[7, 8, 9])
    args = ap.parse_args()
    result = calibrate(simulate_positions(CoefficientSet.seed_truth(), seed=1))
    names, theta = result.layout.names, result.theta
    sigma = np.sqrt(np.diag(result.covariance))
    rel = np.array([is_relative(n) for n in names])
    own = np.where(rel, sigma / np.abs(theta), sigma)
    worst_all = 0.0
    for seed in args.seeds:
        rates = own * np.random.default_rng(seed).uniform(0.3, 3.0, len(names))
        fleet = simulate_fleet(names, theta, rates, sigma, units=args.units, years=args.years,
                               outliers=args.outliers, seed=seed)  # fmt: skip
        t0 = time.perf_counter()
        prior = fleet_prior(fleet.versions, "sim", version=seed)
        took = time.perf_counter() - t0
        changes = fleet.versions.changes().without(fleet.outliers)
        naive = np.sqrt(np.nanmean(changes.delta**2 / changes.months[:, None], axis=0))
        got, _ = prior.rates(names)
        flagged = {o.unit for o in prior.outliers}
        found = len(flagged & set(fleet.outliers))
        print(f"\nseed {seed}: {args.units} units x {args.years:g} years, "
              f"{len(fleet.versions.unit)} versions, {len(changes)} changes (outliers aside); "
              f"fleet_prior {took * 1e3:.0f} ms")  # fmt: skip
        print(
            f"  outliers found {found} of {len(fleet.outliers)}; false alarms "
            f"{len(flagged) - found} of {args.units - len(fleet.outliers)} "
            f"(expected {prior.false_alarm * (args.units - len(fleet.outliers)):.1f})"
        )
        print(f"  {'coefficient':24s} {'true':>10s} {'recovered':>10s} {'+-':>9s} {'error':>7s}"
              f" {'naive':>7s}")  # fmt: skip
        for j, name in enumerate(names):
            err = got[j] / rates[j] - 1.0
            c = prior.coefficients[name]
            miss = "  MISS" if abs(err) > TARGET else ""
            print(f"  {name:24s} {rates[j]:10.3g} {got[j]:10.3g} {c.rate_sigma:9.2g} "
                  f"{err:+7.1%} {naive[j] / rates[j] - 1.0:+7.0%}{miss}")  # fmt: skip
        worst = float(np.max(np.abs(got / rates - 1.0)))
        worst_all = max(worst_all, worst)
        print(f"  worst {worst:.1%}, RMS {np.sqrt(np.mean((got / rates - 1.0) ** 2)):.1%}")
    verdict = "met" if worst_all <= TARGET else "MISSED"
    print(f"\nworst over all fleets {worst_all:.1%} (target {TARGET:.0%}: {verdict})")


if __name__ == "__main__":
    main()
