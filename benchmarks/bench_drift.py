"""Drift test (issue 20): false alarms over many steady sessions and detection delays after a step,
the GLR of ``recal.diagnose.drift`` beside a plain CUSUM that ignores the coefficients' covariance.

Run: python benchmarks/bench_drift.py [--seeds 40]. About 1 s per seed on 2 cores.

Each session: coefficients fitted (``recal.solve.calibrate``, LM) on 30 simulated windows of a random
design (seed 000's FOG, default noise: about 0.003 deg/h and 2 micro-g per window mean), then 30
new windows from the same truth (steady) or with a step before the first new window: gyro x
scale +600 ppm, or accel x bias +5 micro-g. Acceptance (issue 20): steady, at most one alarm in
20 sessions; gyro step found within 15 windows, accel step within 11; never before the step.

Columns: "GLR, with the covariance" (calibrate's full covariance: the daemon, and ``recal drift``
on a file ``calibrate -o`` wrote), "GLR, 1-sigma only" (a coefficients file without its
covariance: the 1-sigma values as a diagonal), "GLR, coefficients
exact" (covariance zero) and "plain CUSUM" (``benchmarks/drift_cusum.py``, ``plain_cusum``: the three invariants
whitened by each window's noise alone). "lambda" is the information a single test that knew the
change window and the coefficient would have by the acceptance window (noncentrality
Delta^2 I_jj, median over seeds): what any test at this false-alarm rate has to work with.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drift_cusum import plain_cusum  # noqa: E402

from recal.diagnose.drift import DriftConfig, drift_inputs, drift_test, whiten  # noqa: E402
from recal.diagnose.drift_glr import gain_parts  # noqa: E402
from recal.model.coefficients import CoefficientSet  # noqa: E402
from recal.sim.simulate import simulate_positions  # noqa: E402
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions  # noqa: E402

LAT = 45.0
STEPS = {
    "steady": None,
    "gyro x scale +600 ppm": ("gyro.scale", 0, 600e-6, 15),
    "accel x bias +5 micro-g": ("accel.bias", 0, 5e-6, 11),
}


def stepped(truth: CoefficientSet, step) -> CoefficientSet:
    out = truth.copy()
    name, axis, size, _ = step
    if name.endswith("scale"):
        out.values[name][axis] *= 1.0 + size
    else:
        out.values[name][axis] += size
    return out


def true_name(step) -> str:
    """The flat name of the stepped coefficient ("gyro.scale.Kx")."""
    name, axis = step[0], step[1]
    return f"{name}.{'K' if name.endswith('scale') else 'b'}{'xyz'[axis]}"


def oracle_lambda(inputs, step, fit) -> float:
    """Delta^2 I_jj of the true step (tau = 0, the stepped coefficient) by the acceptance window."""
    name, axis, size, within = step
    j = inputs.names.index(
        f"{name}.{'Kx Ky Kz bx by bz'.split()[axis + (3 if 'bias' in name else 0)]}"
    )
    delta = size * fit.coefficients.values[name][axis] if name.endswith("scale") else size
    _, C = whiten(inputs)
    D = C.shape[2]
    F = np.concatenate([np.zeros((1, D, D)), np.cumsum(np.einsum("mid,mie->mde", C, C), axis=0)])
    lam, V = np.linalg.eigh(inputs.coeff_cov)
    Lp = V * np.sqrt(np.clip(lam, 0.0, None))
    info = gain_parts(F, Lp, within - 1, np.array([0]))[1][0, j]
    return float(delta * delta * info)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--false-alarm-windows", type=float, default=720.0)
    args = ap.parse_args()
    cfg = DriftConfig(false_alarm_windows=args.false_alarm_windows)
    truth = CoefficientSet.seed_truth()
    t0 = time.perf_counter()
    fits = []
    for s in range(args.seeds):
        pos = simulate_positions(truth, "random", 30, latitude_deg=LAT, seed=1000 + s)
        fits.append(calibrate(pos, CalibrationOptions(latitude_deg=LAT)))
    kinds = ("GLR, with the covariance", "GLR, 1-sigma only (diagonal)", "GLR, coefficients exact",
             "plain CUSUM")  # fmt: skip
    print(f"{args.seeds} sessions: 30 windows fitted, 30 new; one false alarm per "
          f"{cfg.false_alarm_windows:g} windows configured")  # fmt: skip
    for label, step in STEPS.items():
        alarms: dict[str, list] = {k: [] for k in kinds}
        thresholds, lams, named = [], [], []
        for s, fit in enumerate(fits):
            t = truth if step is None else stepped(truth, step)
            new = simulate_positions(t, "random", 30, latitude_deg=LAT, seed=2000 + s)
            full = drift_inputs(new, fit.coefficients, fit.covariance, LAT)
            r = drift_test(full, cfg)
            thresholds.append(r.threshold)
            alarms[kinds[0]].append(r.alarm_window)
            if step is not None and r.alarm_window is not None:
                named.append(r.suspects[0]["coefficient"] == true_name(step))
            diag = drift_inputs(new, fit.coefficients, None, LAT)
            alarms[kinds[1]].append(drift_test(diag, cfg).alarm_window)
            exact = drift_inputs(new, fit.coefficients, 0 * fit.covariance, LAT)
            alarms[kinds[2]].append(drift_test(exact, cfg).alarm_window)
            alarms[kinds[3]].append(plain_cusum(full, cfg).alarm_window)
            if step is not None:
                lams.append(oracle_lambda(full, step, fit))
        print(f"\n{label} (threshold median {np.median(thresholds):.1f})")
        for k in kinds:
            a = alarms[k]
            found = [x for x in a if x is not None]
            if step is None:
                print(f"  {k:30s} false alarms {len(found)}/{len(a)} sessions")
                continue
            within = step[3]
            hit = sum(x < within for x in found)
            med = f"{np.median(found):.0f}" if found else "-"
            print(f"  {k:30s} within {within} windows {hit:2d}/{len(a)}; found {len(found):2d}, "
                  f"misses {len(a) - len(found):2d}; median alarm row {med}")  # fmt: skip
        if named:
            print(
                f"  named right (first suspect, GLR with the covariance): {sum(named)}/{len(named)}"
            )
        if lams:
            print(f"  lambda by window {step[3]} (one known test): median {np.median(lams):.1f}, "
                  f"10-90 % {np.quantile(lams, 0.1):.1f}-{np.quantile(lams, 0.9):.1f}")  # fmt: skip
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
