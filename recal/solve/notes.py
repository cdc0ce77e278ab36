"""What a calibration tells its user besides the numbers: what the design held at the prior and
why, whether the fit can be checked, and why chi2_red exceeds 4 (a swarm that stopped short, or
an effect missing from the model). :func:`recal.solve.calibrate.calibrate` adds these notes."""

from __future__ import annotations

import numpy as np

from recal.solve.lm import covariance, solve_lm
from recal.solve.observability import COMMON_ROTATION_REASON, ROTATION_REASON, ObservabilityReport
from recal.solve.problem import Problem


def excess_note(
    problem: Problem, theta: np.ndarray, T: np.ndarray, chi2_red: float, method: str
) -> str:
    """Why chi2_red exceeds 4. A swarm (above all with --paper) may stop short of the minimum:
    LM from its solution tells a solver that stopped early from a model that lacks an effect."""
    if method != "lm" and T.shape[1]:
        lm = solve_lm(problem, theta, T)
        _, chi2_lm = covariance(problem, lm.theta, T)
        if chi2_lm <= 2.0:
            return (
                f"chi2_red = {chi2_red:.1f}: the {method} solution stopped short of the minimum; "
                f"LM from it fits these windows to the noise (chi2_red {chi2_lm:.2f}), so no "
                "effect is missing: use --method lm (or --polish) rather than recal diagnose"
            )
    return (
        f"chi2_red = {chi2_red:.1f}: residuals exceed the window noise; an effect may be "
        "missing from the model (try `recal diagnose`)"
    )


def observability_notes(report: ObservabilityReport, problem: Problem) -> list[str]:
    """What the user must know about what was held and whether the fit can be checked."""
    notes = []
    if report.verdict == "insufficient":
        notes.append(
            f"partial calibration: {report.message}; what the data do not show of them is "
            "held exactly at the prior with its uncertainty ('held'), the rest is estimated"
        )
    reasons: dict[str, list[str]] = {}
    for d, r in zip(report.held_directions, report.held_reasons, strict=True):
        reasons.setdefault(r, []).append(d)
    for r, dirs in reasons.items():
        if r == COMMON_ROTATION_REASON:
            # the relative frame is estimated only when none of its rotations is held as well
            weak = any(q.startswith("a rotation of the gyro frame") for q in reasons)
            head = (
                "with slews the gyro frame could be estimated relative to the accelerometer "
                "frame, but here the slews pin it down too weakly (below)"
                if weak
                else "with slews the gyro frame is estimated relative to the accelerometer frame"
            )
            notes.append(
                f"{head}; {r} ({len(dirs)} direction(s): {'; '.join(dirs)}); an outside "
                "reference of known rotations would show it"
            )
        elif r != ROTATION_REASON:  # the rotations are expected and listed in observability
            notes.append(f"held at the prior ({len(dirs)} direction(s): {'; '.join(dirs)}): {r}")
    if report.redundancy == 0:
        notes.append(
            f"exactly determined: {problem.n_residuals} invariant equations for {report.rank} "
            "observable directions, so the fit makes every residual zero and the residual "
            "cannot check it; add positions to check the fit"
        )
    return notes
