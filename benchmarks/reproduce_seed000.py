"""Seed 000 Tables 1-3 reproduced, and what they hide.

Run:  python benchmarks/reproduce_seed000.py [--mc 100]

Scenario A -- the paper's own setup: the FOG triad's truth *is* the Table 2 preset, the swarm
starts from that preset (Table 1 Visual, literal CF, category phases, 100 MC runs), seed 000
Table 4 noise (ARW 0.0005 deg/sqrt(h)), 24 positions of 100 s. We print the Table 3 layout
(preset, MCS-NAFSA mean, relative error, MC standard deviation) next to what the data can
actually support: the Gauss-Newton 1-sigma and the Cramer-Rao bound.

Scenario B -- the field: the unit has aged (scale +-300 ppm, bias +-0.01 deg/h, misalignment
+-2e-4), the prior is still Table 2. Same data noise. Errors are shown in units of the CRLB for
the paper's method, the project's default MCS-NAFSA and LM.
"""

from __future__ import annotations

import argparse

import numpy as np

from recal.model.coefficients import SEED_000_TABLE2, CoefficientSet
from recal.model.error_model import Model, ParameterLayout
from recal.sim.simulate import simulate_positions
from recal.solve.calibrate import calibrate
from recal.solve.observability import analyze, jacobian
from recal.solve.options import CalibrationOptions
from recal.solve.problem import Problem

#: Seed 000 Table 3 "Relative Error" column, as printed (units as in the paper).
PAPER_RELATIVE_ERROR = [0.00912194, 0.04054963, 0.03868713, 0.001633171, 0.001031810,
                        0.001222490, 0.00021812, 0.00121303, 0.00062088, 0.00092540,
                        0.00247501, 0.00067330]  # fmt: skip
#: Seed 000 Table 3 "Standard Deviation" column.
PAPER_STD = [0.01464, 0.01458, 0.01422, 0.001632, 0.001369, 0.001780, 2.792e-5, 3.155e-5,
             3.069e-5, 2.924e-5, 3.026e-5, 3.176e-5]  # fmt: skip


def crlb(problem: Problem, theta: np.ndarray) -> np.ndarray:
    """Per-parameter CRLB 1-sigma on the observable subspace (NaN where unobservable)."""
    typical = problem.layout.typical(theta)
    rep = analyze(problem, theta, typical)
    T = typical[:, None] * rep.basis
    J = jacobian(problem, theta, T.T)
    cov = T @ np.linalg.inv(J.T @ J) @ T.T
    return np.where(rep.estimated, np.sqrt(np.diag(cov)), np.nan)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mc", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    layout = ParameterLayout((Model.seed("gyro"),))
    names = [n.replace("gyro.", "") for n in layout.names]
    preset = CoefficientSet.seed_truth()
    theta_preset = preset.to_vector(layout)

    print("# Scenario A: the paper's setup (truth = prior = Table 2)\n")
    pos = simulate_positions(preset, "24", latitude_deg=45.75, seed=args.seed, sensors=("gyro",))
    paper = calibrate(pos, CalibrationOptions(sensor="gyro", method="nafsa", paper=True,
                                              mc_runs=args.mc, seed=args.seed, prior=preset,
                                              latitude_deg=45.75))  # fmt: skip
    problem = Problem.build(pos, layout.models, 45.75, 0.0, theta_preset)
    bound = crlb(problem, theta_preset)
    print(
        "| parameter | preset (Table 2) | MCS-NAFSA mean | rel. error | MC std | paper's rel. "
        "error (as printed) | paper's std | GN 1-sigma | CRLB 1-sigma | status |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for i, n in enumerate(names):
        rel = (paper.theta[i] - theta_preset[i]) / theta_preset[i]
        gn = paper.covariance[i, i] ** 0.5
        status = "estimated" if paper.observability.estimated[i] else "held"
        if paper.observability.share[i] < 0.99 and status == "estimated":
            status = "half (sum only)"
        print(
            f"| {n} | {theta_preset[i]:.8g} | {paper.theta[i]:.8g} | {rel:.2e} | "
            f"{paper.mcs.std[i]:.3g} | {PAPER_RELATIVE_ERROR[i]:.3g} | {PAPER_STD[i]:.3g} | "
            f"{gn:.3g} | {bound[i]:.3g} | {status} |"
        )
    k = slice(0, 3)
    rel_ppm = np.abs(paper.theta[k] / theta_preset[k] - 1) * 1e6
    crlb_ppm = bound[k] / theta_preset[k] * 1e6
    std_ratio = np.mean(paper.mcs.std[k] / np.sqrt(np.diag(paper.covariance))[k])
    print(
        f"\nScale factors: this run lands {rel_ppm.min():.0f}-{rel_ppm.max():.0f} ppm from the "
        f"preset, against a Cramer-Rao bound of {crlb_ppm.mean():.0f} ppm (1 sigma) for this "
        "noise and design; the paper's Table 3 reports 1e-2..1e-3 ppm, which no estimator can "
        "reach from these data. The MC standard deviation reproduces the paper's "
        f"(~0.015 counts per deg/h) but is {std_ratio:.2f} x the measurement 1-sigma: it measures "
        "how far the frozen swarm wanders, not how well the sensor is known. The antisymmetric "
        "misalignments moved although no norm can see them."
    )

    print("\n# Scenario B: an aged unit, prior = Table 2 (errors in CRLB units)\n")
    rng = np.random.default_rng(args.seed + 1)
    truth = preset.copy()
    truth.values["gyro.scale"] = SEED_000_TABLE2["gyro.scale"] * (1 + 300e-6 * rng.normal(size=3))
    truth.values["gyro.bias"] = SEED_000_TABLE2["gyro.bias"] + 0.01 * rng.normal(size=3)
    truth.values["gyro.misalignment"] = SEED_000_TABLE2["gyro.misalignment"] + 2e-4 * rng.normal(
        size=6
    )
    theta_true = truth.to_vector(layout)
    pos = simulate_positions(truth, "24", latitude_deg=45.75, seed=args.seed, sensors=("gyro",))
    problem = Problem.build(pos, layout.models, 45.75, 0.0, theta_true)
    bound = crlb(problem, theta_true)
    runs = {
        "paper MCS-NAFSA": CalibrationOptions(method="nafsa", paper=True, mc_runs=args.mc),
        "default MCS-NAFSA": CalibrationOptions(method="nafsa", mc_runs=args.mc),
        "LM": CalibrationOptions(method="lm"),
    }
    results = {
        label: calibrate(
            pos,
            CalibrationOptions(
                **{
                    **opt.__dict__,
                    "sensor": "gyro",
                    "prior": preset,
                    "seed": args.seed,
                    "latitude_deg": 45.75,
                }
            ),
        )  # fmt: skip
        for label, opt in runs.items()
    }
    print("| parameter | truth | " + " | ".join(results) + " |")
    print("|---|---|" + "---|" * len(results))
    for i, n in enumerate(names[:6]):
        cells = [f"{(r.theta[i] - theta_true[i]) / bound[i]:+.2f}" for r in results.values()]
        print(f"| {n} | {theta_true[i]:.8g} | " + " | ".join(cells) + " |")
    for a, b in (("Exz", "Eyz"), ("Exy", "Ezy"), ("Eyx", "Ezx")):
        ia, ib = names.index(f"misalignment.{a}"), names.index(f"misalignment.{b}")
        c = np.zeros(len(names))
        c[[ia, ib]] = 1
        cb = crlb_comb(problem, theta_true, c)
        cells = [f"{c @ (r.theta - theta_true) / cb:+.2f}" for r in results.values()]
        print(f"| {a}+{b} | {c @ theta_true:.3g} | " + " | ".join(cells) + " |")
    for a, b in (("Exz", "Eyz"), ("Exy", "Ezy"), ("Eyx", "Ezx")):
        ia, ib = names.index(f"misalignment.{a}"), names.index(f"misalignment.{b}")
        cells = [f"{(r.theta[ia] - r.theta[ib]) - (theta_true[ia] - theta_true[ib]):+.2e}"
                 for r in results.values()]  # fmt: skip
        print(
            f"| {a}-{b} (unobservable; absolute error) | "
            f"{theta_true[ia] - theta_true[ib]:.3g} | " + " | ".join(cells) + " |"
        )


def crlb_comb(problem: Problem, theta: np.ndarray, c: np.ndarray) -> float:
    typical = problem.layout.typical(theta)
    rep = analyze(problem, theta, typical)
    T = typical[:, None] * rep.basis
    J = jacobian(problem, theta, T.T)
    cov = T @ np.linalg.inv(J.T @ J) @ T.T
    return float(np.sqrt(c @ cov @ c))


if __name__ == "__main__":
    main()
