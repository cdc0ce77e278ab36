"""Benchmark of ``recal diagnose``: is a hidden effect ranked first, how often does clean data
raise a false alarm, and what does an out-of-catalogue (magnetic) effect do to the scale factors.

    python benchmarks/bench_diagnose.py            # full: >= 10 seeds per cell, 240 clean sessions
    python benchmarks/bench_diagnose.py --quick    # a smoke run for CI (3 seeds, 40 sessions)

Three tables are printed (markdown):

1. per catalogue effect, design (the seeds' 24-position turntable scheme, 24 and 36 random
   orientations) and temperature profile (a 2 degC/h ramp; a ramp plus an 8 degC swing of
   0.7 h period): the share of runs where the hidden effect is ranked first, where it is among the
   suggested effects, refusals (exit 2) and the median final chi2_red. Effects a design cannot
   show (a temperature term on a ramp looks like a drift) count as misses and are printed.
2. the false-discovery rate: share of clean sessions (random 12-36 positions and the 24-position
   design, latitudes 0-70 deg, both profiles) where any candidate is significant.
3. the magnetic case: a FOG Faraday bias F B (B the Earth field in body axes per position) with
   no plugin, the suggested catalogue effect, and the right plugin; the largest gyro
   scale-factor error each leaves (ppm), its reported 1-sigma, whether the trade-off warning was
   given and whether the diagnosis was marked not confirmed (a core shift above 3 sigma).

Runs use 2 worker processes (the machine is shared). Effect sizes are a few times each effect's
typical change, so every effect is well above the window noise on a design that can show it.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

FARADAY = Path(__file__).resolve().parents[1] / "docs" / "examples" / "faraday_plugin.py"
F_TRUE = (0.04, -0.03, 0.05)  # deg/h per gauss
VALUES = {
    "gyro.bias_temperature": (0.02, -0.015, 0.01),
    "gyro.scale_temperature": (1e-4, -8e-5, 6e-5),
    "gyro.bias_temperature_rate": (0.05, -0.04, 0.03),
    "gyro.g_sensitivity": (0.1, -0.05, 0.03, 0.02, 0.08, -0.04, 0.05, 0.03, -0.1),
    "gyro.bias_drift": (0.03, 0.0, -0.02),
    "accel.bias_temperature": (1e-4, -8e-5, 6e-5),
    "accel.scale_temperature": (1e-4, -8e-5, 6e-5),
    "accel.scale_asymmetry": (2e-4, -1.5e-4, 1e-4),
}
DESIGNS = {"24-position": ("24", None), "random 24": ("random", 24), "random 36": ("random", 36)}


def _profiles():
    from recal.sim.simulate import TemperatureSpec

    return {"ramp": TemperatureSpec(20.0, 2.0), "swing": TemperatureSpec(15.0, 4.0, 8.0, 0.7)}


def _ranking_run(job: tuple[str, str, str, int]) -> dict:
    from recal.diagnose.effects import diagnose
    from recal.errors import RecalInputError
    from recal.model.coefficients import CoefficientSet
    from recal.model.terms import catalogue_terms
    from recal.sim.simulate import simulate_positions
    from recal.solve.options import CalibrationOptions

    effect, design, profile, seed = job
    kind, n = DESIGNS[design]
    truth = CoefficientSet.seed_truth()
    truth.values[effect] = np.array(VALUES[effect])
    lat = 45.0
    pos = simulate_positions(truth, kind, n, lat, seed=1000 + seed,
                             temperature=_profiles()[profile],
                             hidden=[catalogue_terms()[effect]])  # fmt: skip
    try:
        d = diagnose(pos, CalibrationOptions(latitude_deg=lat))
    except RecalInputError as exc:
        return {"job": job, "refused": str(exc)}
    top = d.candidates[0]
    return {
        "job": job,
        "first": top.effect == effect and top.significant,
        "top": top.effect,
        "found": effect in d.suggested_effects,
        "chi2": d.final_chi2_red,
        "fails": d.model_fails,
    }


def _clean_run(seed: int) -> dict:
    from recal.diagnose.effects import diagnose
    from recal.errors import RecalInputError
    from recal.model.coefficients import CoefficientSet
    from recal.sim.simulate import simulate_positions
    from recal.solve.options import CalibrationOptions

    rng = np.random.default_rng(seed)
    if seed % 4 == 0:
        kind, n = "24", None
    else:
        kind, n = "random", int(rng.integers(12, 37))
    lat = float(rng.choice([0.0, 20.0, 45.0, 60.0, 70.0]))
    profile = "swing" if seed % 2 else "ramp"
    sensors = ("gyro",) if seed % 5 == 3 else ("gyro", "accel")
    pos = simulate_positions(CoefficientSet.seed_truth(), kind, n, lat, seed=seed,
                             sensors=sensors, temperature=_profiles()[profile])  # fmt: skip
    size = 24 if n is None else n
    try:
        d = diagnose(pos, CalibrationOptions(latitude_deg=lat))
    except RecalInputError as exc:
        return {"seed": seed, "size": size, "refused": str(exc)}
    sig = [c.effect for c in d.candidates if c.significant]
    return {"seed": seed, "size": size, "design": kind, "false": sig, "lat": lat}


def _magnetic_run(job: tuple[str, int]) -> dict:
    from recal.diagnose.effects import diagnose
    from recal.model.coefficients import CoefficientSet
    from recal.model.plugins import hidden_plugin
    from recal.sim.simulate import design_orientations, simulate_positions
    from recal.solve.calibrate import calibrate
    from recal.solve.options import CalibrationOptions
    from service.cli.common import load_plugin

    design, seed = job
    kind, n = DESIGNS[design]
    (term,) = load_plugin(str(FARADAY))
    C = design_orientations(kind, n, np.random.default_rng(seed))  # the simulator's first draw
    truth = CoefficientSet.seed_truth()
    truth.values["gyro.faraday"] = np.array(F_TRUE)
    pos = simulate_positions(truth, kind, n, 45.0, seed=seed,
                             hidden=[hidden_plugin(term, C, 45.0)])  # fmt: skip
    K0 = truth.values["gyro.scale"]

    def scale_error(effects: list[str]) -> tuple[float, float]:
        r = calibrate(pos, CalibrationOptions(latitude_deg=45.0, plugin_terms=[term],
                                              effects=effects))  # fmt: skip
        K = r.theta[r.layout.term_slices()["gyro.scale"]]
        err = np.abs(K / K0 - 1) * 1e6
        i = int(np.argmax(err))
        return float(err[i]), float(r.uncertainty["gyro.scale"][i] / abs(K0[i]) * 1e6)

    plain = diagnose(pos, CalibrationOptions(latitude_deg=45.0))
    with_plugin = diagnose(pos, CalibrationOptions(latitude_deg=45.0, plugin_terms=[term]))
    out = {"job": job, "none": scale_error([])}
    out["suggested"] = plain.suggested_effects
    out["suggested_err"] = scale_error(plain.suggested_effects) if plain.suggested_effects else None
    out["warned"] = any(c.warning for c in plain.candidates if c.effect in plain.suggested_effects)
    out["unconfirmed"] = not plain.trustworthy
    out["plugin_first"] = with_plugin.candidates[0].effect == "gyro.faraday"
    out["plugin_suggested"] = with_plugin.suggested_effects
    out["plugin_err"] = scale_error(["gyro.faraday"])
    return out


def ranking_table(seeds: int, pool: ProcessPoolExecutor) -> list[str]:
    jobs = [(e, d, p, s) for e in VALUES for d in DESIGNS for p in ("ramp", "swing")
            for s in range(seeds)]  # fmt: skip
    res = list(pool.map(_ranking_run, jobs, chunksize=4))
    lines = ["| effect | design | profile | ranked first | suggested | refused | median final chi2_red | misses: top instead |",
             "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for e in VALUES:
        for d in DESIGNS:
            for p in ("ramp", "swing"):
                cell = [r for r in res if r["job"][:3] == (e, d, p)]
                ok = [r for r in cell if "refused" not in r]
                first = sum(r["first"] for r in ok)
                found = sum(r["found"] for r in ok)
                chi2 = np.median([r["chi2"] for r in ok]) if ok else float("nan")
                misses = sorted({r["top"] for r in ok if not r["first"]})
                lines.append(f"| {e} | {d} | {p} | {first}/{len(cell)} | {found}/{len(cell)} | "
                             f"{len(cell) - len(ok)} | {chi2:.2f} | {', '.join(misses)} |")  # fmt: skip
    return lines


def fdr_table(sessions: int, pool: ProcessPoolExecutor) -> list[str]:
    res = list(pool.map(_clean_run, range(sessions), chunksize=4))
    ok = [r for r in res if "refused" not in r]
    lines = ["| sessions | size | false alarms | rate | refused |", "|---|---|---|---|---|"]
    for label, keep in (("12-23 random", lambda r: r["design"] == "random" and r["size"] < 24),
                        ("24-36 random", lambda r: r["design"] == "random" and r["size"] >= 24),
                        ("24-position", lambda r: r["design"] == "24"),
                        ("all", lambda r: True)):  # fmt: skip
        cell = [r for r in ok if keep(r)]
        false = sum(bool(r["false"]) for r in cell)
        rate = false / max(len(cell), 1)
        refused = sum(1 for r in res if "refused" in r) if label == "all" else ""
        lines.append(f"| {len(cell)} | {label} | {false} | {100 * rate:.1f} % | {refused} |")
    alarms = [(r["seed"], r["size"], r["lat"], r["false"]) for r in ok if r["false"]]
    lines.append("")
    lines.append(f"false alarms (seed, positions, latitude, effects): {alarms or 'none'}")
    for r in res:
        if "refused" in r:
            lines.append(f"refused (seed {r['seed']}, {r['size']} positions): {r['refused']}")
    return lines


def magnetic_table(seeds: int, pool: ProcessPoolExecutor) -> list[str]:
    jobs = [(d, s) for d in DESIGNS for s in range(seeds)]
    res = list(pool.map(_magnetic_run, jobs))
    lines = ["| design | seed | no effect: scale err (1σ) ppm | suggested without plugin | its scale err (1σ) ppm | warned | not confirmed | plugin ranked first | with plugin: scale err (1σ) ppm |",
             "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip

    def fmt(e):
        return "-" if e is None else f"{e[0]:.0f} ({e[1]:.0f})"

    for r in res:
        d, s = r["job"]
        lines.append(f"| {d} | {s} | {fmt(r['none'])} | {', '.join(r['suggested']) or 'none'} | "
                     f"{fmt(r['suggested_err'])} | {'yes' if r['warned'] else 'no'} | "
                     f"{'yes' if r['unconfirmed'] else 'no'} | "
                     f"{'yes' if r['plugin_first'] else 'no'} | {fmt(r['plugin_err'])} |")  # fmt: skip
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="3 seeds per cell, 40 clean sessions")
    ap.add_argument("--seeds", type=int, default=None, help="seeds per cell (default 10)")
    ap.add_argument("--sessions", type=int, default=None, help="clean sessions (default 240)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--only", choices=("ranking", "fdr", "magnetic"), default=None)
    args = ap.parse_args(argv)
    seeds = args.seeds or (3 if args.quick else 10)
    sessions = args.sessions or (40 if args.quick else 240)
    with ProcessPoolExecutor(args.workers) as pool:
        for name, table, size in (("ranking", ranking_table, seeds), ("fdr", fdr_table, sessions),
                                  ("magnetic", magnetic_table, 2 if args.quick else 3)):  # fmt: skip
            if args.only not in (None, name):
                continue
            t = time.perf_counter()
            lines = table(size, pool)
            print(f"\n## {name} ({time.perf_counter() - t:.0f} s)\n")
            print("\n".join(lines), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
