"""Bias wander between windows over days (issue 26): honest sigmas, drift steps, no false effects.

Run: python benchmarks/bench_wander.py [--units 40] [--first-seed 7000] [--seeds both|in-sample|
     held-out] [--method nafsa|lm] [--jobs 2]

Each simulated unit (seed 000's FOG and accelerometer, seed truth, default window noise) has 60
windows of 600 s in random orientations at a random latitude (-70..70 deg). Both triads' biases
follow a first-order Gauss-Markov process drawn per unit: correlation time log-uniform in 1-24 h,
steady-state 1-sigma uniform in 0.5-6 times each triad's window noise (its sem), windows
log-uniform 0.5-6 h apart.

Two sets of units, reported separately (issue 35, item 7):

* **in-sample**: the units the wander estimate's and diagnose's constants were chosen on: 0-9
  and 100-109 (the estimator's tuning), 2600-2639 (this benchmark's former default range: the
  84 % bound the fit carries, SIGMA_CARRIED_DELTA, was chosen on it, and diagnose's noise test
  was measured on it), among them 2613 (tests/recal/test_wander.py's joint-test unit) and 2638
  (tests/recal/test_diagnose_hours.py's wander unit). Their figures say what the tuning
  reached, not what to expect.
* **held-out**: ``--units`` units from ``--first-seed`` (default 7000-7039), on which no constant
  was chosen (benchmarks/bench_diagnose_hours.py's held-out wander units are the same range).
  These are the figures to quote.

1. **Coverage.** The first 30 windows are calibrated with the shipped method (MCS-NAFSA; ``--method
   lm`` for the faster stand-in) and ``wander="auto"`` (the command line's default), and beside it
   LM with ``--wander none`` (independent windows, the behaviour before issue 26). Over the 12
   scale and bias coefficients of each unit: the fraction within 3 sigma of the truth, the RMS of
   z = (estimate - truth) / sigma, and the median chi2_red. Acceptance: >= 99 %, 0.8-1.2, 0.7-1.5.
2. **Drift.** The drift test (``recal.diagnose.drift``, one false alarm per 30 days at the unit's
   window rate, with the accepted version's wander) runs on the next 30 windows: unchanged
   (a false alarm if it alarms), and with +600 ppm on one gyro scale (a random axis) from the
   first new window, or from the 10th (a later step, which the innovations filter approximates).
   Acceptance: the step found within 15 windows.
3. **Diagnose.** ``recal diagnose`` (``wander="auto"``) on the first 30 windows: a unit counts
   when it proposes an effect (there is none to find: wander alone). Acceptance: at most 1 of 40.

Every unit's figures are printed as it finishes; each set's summary marks each acceptance figure
met or MISSED.
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from recal.diagnose.drift import DriftConfig, drift_inputs, drift_test, whiten  # noqa: E402
from recal.diagnose.drift_glr import gain_parts  # noqa: E402
from recal.diagnose.effects import diagnose  # noqa: E402
from recal.model.coefficients import CoefficientSet  # noqa: E402
from recal.model.positions import Positions  # noqa: E402
from recal.sim.simulate import NoiseSpec, simulate_positions  # noqa: E402
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions  # noqa: E402
from recal.solve.wander_model import TriadWander, WanderModel, possible_wander  # noqa: E402

TRUTH = CoefficientSet.seed_truth()
WINDOW_S = 600.0
CAL, LATER = 30, 30
STEP_PPM = 600.0
WITHIN = 15


@dataclass(frozen=True)
class Unit:
    """One simulated unit's draw."""

    seed: int
    latitude_deg: float
    tau_h: float
    gap_h: float
    k_gyro: float  # wander sigma / window sem
    k_accel: float
    step_axis: int

    @classmethod
    def draw(cls, seed: int) -> Unit:
        rng = np.random.default_rng(seed)
        return cls(
            seed, float(rng.uniform(-70, 70)), float(np.exp(rng.uniform(np.log(1), np.log(24)))),
            float(np.exp(rng.uniform(np.log(0.5), np.log(6)))), float(rng.uniform(0.5, 6)),
            float(rng.uniform(0.5, 6)), int(rng.integers(3)),
        )  # fmt: skip

    def noise(self) -> NoiseSpec:
        base = NoiseSpec(window_s=WINDOW_S, rate_hz=100.0)
        n = WINDOW_S * base.rate_hz
        g_sem = base.per_sample_sigma("gyro") / np.sqrt(n)
        a_sem = base.per_sample_sigma("accel") / np.sqrt(n)
        return NoiseSpec(
            window_s=WINDOW_S, slew_s=self.gap_h * 3600.0 - WINDOW_S, rate_hz=100.0,
            gm_tau_s=self.tau_h * 3600.0, gm_gyro_dph=self.k_gyro * g_sem,
            gm_accel_ug=self.k_accel * a_sem * 1e6,
        )  # fmt: skip

    def positions(self, truth: CoefficientSet = TRUTH) -> Positions:
        return simulate_positions(
            truth, "random", CAL + LATER, self.latitude_deg, seed=self.seed, noise=self.noise()
        )


def _z(res) -> np.ndarray:
    """z of the estimated scale and bias coefficients."""
    names = res.layout.names
    core = np.array([".scale." in n or ".bias." in n for n in names]) & res.observability.estimated
    sd = np.sqrt(np.diag(res.covariance))
    return ((res.theta - TRUTH.to_vector(res.layout)) / sd)[core]


def _splice(a: Positions, b: Positions, start: int) -> Positions:
    """a's windows before ``start``, b's from it (same draws, b from the stepped truth)."""
    cols = {k: np.concatenate([a.columns[k][:start], b.columns[k][start:]]) for k in a.columns}
    return Positions.from_columns(cols)


def run_unit(seed: int, method: str) -> dict:
    u = Unit.draw(seed)
    t0 = time.perf_counter()
    pos = u.positions()
    cal_pos = pos.subset(np.arange(CAL))
    opt = CalibrationOptions(latitude_deg=u.latitude_deg, method=method, wander="auto", seed=seed)
    cal = calibrate(cal_pos, opt)
    plain = calibrate(cal_pos, CalibrationOptions(latitude_deg=u.latitude_deg, method="lm"))
    wander = cal.noise_model.get("wander")
    drift_wander = possible_wander(cal.noise_model)  # as the daemon's drift trigger
    # drift: the next 30 windows, unchanged and with a gyro scale step
    cfg = DriftConfig.per_days(30, 24.0 / u.gap_h)
    later = np.arange(CAL, CAL + LATER)

    def inputs(p: Positions, wander=drift_wander):
        return drift_inputs(
            p.subset(later), cal.coefficients, cal.covariance, u.latitude_deg, 0.0, wander=wander
        )

    def alarm(p: Positions) -> int | None:
        return drift_test(inputs(p), cfg).alarm_window

    vals = {k: np.array(v, float).copy() for k, v in TRUTH.values.items()}
    vals["gyro.scale"][u.step_axis] *= 1.0 + STEP_PPM * 1e-6
    stepped = u.positions(CoefficientSet(vals))
    null = inputs(pos)
    unchanged = drift_test(null, cfg)  # the unit unchanged: its alarm and the GLR's threshold
    steady, h = unchanged.alarm_window, unchanged.threshold
    # the same test given the simulated wander (output units): what a perfect estimate would do
    nz = u.noise()
    truth_model = WanderModel({
        s: TriadWander(np.full(3, nz.gauss_markov_sigma(s)) * np.abs(TRUTH.values[f"{s}.scale"]),
                       np.full(3, nz.gm_tau_s))
        for s in ("gyro", "accel")
    })  # fmt: skip
    steady_true = drift_test(inputs(pos, truth_model), cfg).alarm_window
    # one false alarm per 30 days at the unit's window rate: the chance of one in LATER windows
    expected = min(1.0, LATER / cfg.false_alarm_windows)
    # what any test has to work with: Delta^2 I_jj of the true step by window WITHIN (a test
    # that knew the coefficient and the change window)
    _, C = whiten(null)
    D = C.shape[2]
    F = np.concatenate([np.zeros((1, D, D)), np.cumsum(np.einsum("mid,mie->mde", C, C), axis=0)])
    ev, V = np.linalg.eigh(null.coeff_cov)
    j = null.names.index(f"gyro.scale.K{'xyz'[u.step_axis]}")
    info = gain_parts(F, V * np.sqrt(np.clip(ev, 0, None)), WITHIN - 1, np.array([0]))[1][0, j]
    delta = STEP_PPM * 1e-6 * cal.coefficients.values["gyro.scale"][u.step_axis]
    lam = float(delta**2 * info)
    delays = {}
    for at in (0, 10):
        a = alarm(_splice(pos, stepped, CAL + at))
        delays[at] = None if a is None else a - at  # negative: before the step
    diag = diagnose(cal_pos, CalibrationOptions(latitude_deg=u.latitude_deg, wander="auto"))
    return {
        "unit": u, "z": _z(cal), "z_none": _z(plain), "chi2": cal.chi2_red,
        "chi2_none": plain.chi2_red, "wander_found": [k for k in ("gyro", "accel") if wander and k in wander],
        "steady_alarm": steady, "steady_true": steady_true, "expected": expected, "delay": delays, "lambda": lam, "threshold": h, "effects": list(diag.suggested_effects),
        "seconds": time.perf_counter() - t0,
    }  # fmt: skip


def _fmt_delay(d: int | None) -> str:
    return "miss" if d is None else f"{d:+d}"


#: The units the constants were chosen on (module docstring): never quoted as held-out figures.
IN_SAMPLE = (*range(0, 10), *range(100, 110), *range(2600, 2640))


def summary(rows: list[dict], label: str, method: str) -> None:
    """The acceptance figures of one set of units."""
    z = np.abs(np.concatenate([r["z"] for r in rows]))
    zn = np.abs(np.concatenate([r["z_none"] for r in rows]))
    chi = np.array([r["chi2"] for r in rows])
    chin = np.array([r["chi2_none"] for r in rows])
    n = len(rows)

    def verdict(ok: bool) -> str:
        return "met" if ok else "MISSED"

    cover, rms, med = np.mean(z < 3), np.sqrt(np.mean(z**2)), np.median(chi)
    seeds = sorted(r["unit"].seed for r in rows)
    print(f"\n== {label}: {n} units ({_ranges(seeds)}) ==")
    print(f"coverage, {method} with wander auto: within 3 sigma {100 * cover:.1f} % of "
          f"{z.size} ({int(np.sum(z >= 3))} beyond; {verdict(cover >= 0.99)}: >= 99 %); RMS z "
          f"{rms:.2f} ({verdict(0.8 <= rms <= 1.2)}: 0.8-1.2); max |z| {z.max():.2f}; chi2_red "
          f"median {med:.2f} ({verdict(0.7 <= med <= 1.5)}: 0.7-1.5), "
          f"5-95 % {np.percentile(chi, 5):.2f}-{np.percentile(chi, 95):.2f}")  # fmt: skip
    print(f"contrast, LM with windows independent: within 3 sigma {100 * np.mean(zn < 3):.1f} %, "
          f"RMS z {np.sqrt(np.mean(zn**2)):.2f}, chi2_red median {np.median(chin):.2f}")  # fmt: skip
    false = sum(r["steady_alarm"] is not None for r in rows)
    false_true = sum(r["steady_true"] is not None for r in rows)
    expected = sum(r["expected"] for r in rows)
    print(
        f"drift, unit unchanged: {false} of {n} alarm (the test given the simulated wander: "
        f"{false_true}; at the configured rate, one per 30 days at each unit's window rate, "
        f"{expected:.1f} expected)"
    )
    # a step is "detectable" within WITHIN windows when a test that knew the coefficient and
    # the change window would find it 9 times in 10 at the GLR's threshold: lambda >=
    # (sqrt(h) + 1.28)^2; below that no test at this false-alarm rate can promise it
    detectable = [r["lambda"] >= (np.sqrt(r["threshold"]) + 1.28) ** 2 for r in rows]
    print(
        f"drift, step detectable within {WITHIN} windows (lambda >= (sqrt(h) + 1.28)^2) in "
        f"{sum(detectable)} of {n}; lambda median {np.median([r['lambda'] for r in rows]):.1f}"
    )
    for at in (0, 10):
        d = [r["delay"][at] for r in rows]
        dd = [x for x, ok in zip(d, detectable, strict=True) if ok]
        found_d = sum(x is not None and 0 <= x <= WITHIN for x in dd)
        print(
            f"  step from new window {at}, where detectable: found within {WITHIN} windows "
            f"in {found_d} of {len(dd)} ({verdict(found_d == len(dd))})"
        )
        found = sum(x is not None and 0 <= x <= WITHIN for x in d)
        early = sum(x is not None and x < 0 for x in d)
        late = [x for x in d if x is not None and x >= 0]
        print(f"drift, +{STEP_PPM:.0f} ppm gyro scale from new window {at}: found within {WITHIN} "
              f"windows in {found} of {n} ({verdict(found == n)}), before the step {early}, "
              f"missed {sum(x is None for x in d)}, median delay "
              f"{np.median(late) if late else float('nan'):.0f}")  # fmt: skip
    eff = sum(bool(r["effects"]) for r in rows)
    limit = max(1, round(n / 40))
    print(
        f"diagnose on wander alone: an effect proposed in {eff} of {n} "
        f"({verdict(eff <= limit)}: <= {limit})"
    )


def _ranges(seeds: list[int]) -> str:
    """'0-9, 100-109, 2600-2639' of a sorted seed list."""
    out, start = [], seeds[0]
    for a, b in zip(seeds, [*seeds[1:], None], strict=True):
        if b != a + 1:
            out.append(f"{start}-{a}" if a > start else f"{start}")
            start = b
    return ", ".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--units", type=int, default=40, help="held-out units")
    ap.add_argument("--first-seed", type=int, default=7000, help="the first held-out unit")
    ap.add_argument("--seeds", choices=("both", "in-sample", "held-out"), default="both")
    ap.add_argument("--method", default="nafsa", help="calibration method (default: shipped)")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    held = list(range(args.first_seed, args.first_seed + args.units))
    if set(held) & set(IN_SAMPLE):
        ap.error("the held-out range overlaps the in-sample units")
    sets = {"in-sample": list(IN_SAMPLE), "held-out": held}
    if args.seeds != "both":
        sets = {args.seeds: sets[args.seeds]}
    seeds = [s for v in sets.values() for s in v]
    print(f"{len(seeds)} units ({'; '.join(f'{k} {_ranges(v)}' for k, v in sets.items())}), "
          f"method {args.method}, {CAL} windows calibrated + {LATER} tested, {WINDOW_S:.0f} s "
          "windows", flush=True)  # fmt: skip
    print("unit  lat   tau_h gap_h kG   kA  | wander   chi2  |z|max  none:chi2 |z|max | "
          "steady  step@0 step@10 lambda | diagnose effects   s")  # fmt: skip
    rows = []
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as ex:
        for r in ex.map(run_unit, seeds, [args.method] * len(seeds)):
            u = r["unit"]
            rows.append(r)
            print(f"{u.seed} {u.latitude_deg:5.1f} {u.tau_h:5.1f} {u.gap_h:5.2f} {u.k_gyro:4.1f} "
                  f"{u.k_accel:4.1f} | {'+'.join(r['wander_found']) or '-':8s} {r['chi2']:5.2f} "
                  f"{np.abs(r['z']).max():5.2f}  {r['chi2_none']:6.2f} {np.abs(r['z_none']).max():5.2f} | "
                  f"{'ALARM' if r['steady_alarm'] is not None else 'ok':6s} "
                  f"{_fmt_delay(r['delay'][0]):>6s} {_fmt_delay(r['delay'][10]):>7s} {r['lambda']:6.1f} | "
                  f"{','.join(r['effects']) or '-':24s} {r['seconds']:.0f}", flush=True)  # fmt: skip
    print(f"\n{len(rows)} units in {time.perf_counter() - t0:.0f} s")
    for label, group in sets.items():
        mine = set(group)
        summary([r for r in rows if r["unit"].seed in mine], label, args.method)


if __name__ == "__main__":
    main()
