"""Bias wander in a calibration: the fit done again with the windows' bias wander in their
covariance (:func:`refit_with_wander`), "auto" estimating it from the fit's residuals where the
session is long enough, and the note that says so. The wander model and its test are in
:mod:`recal.solve.wander`; this is calibrate's glue to it."""

from __future__ import annotations

from typing import Any

import numpy as np

from recal.errors import RecalInputError
from recal.solve.convergence import fixed_point
from recal.solve.lm import solve_lm
from recal.solve.observability import ObservabilityReport, jacobian
from recal.solve.options import CalibrationOptions
from recal.solve.problem import Problem
from recal.solve.wander_estimate import WANDER_SIGNIFICANCE as WANDER_TEST
from recal.solve.wander_estimate import WanderFit, correlation_times, estimate_wander
from recal.solve.wander_model import TriadWander, WanderModel, window_sessions, window_times

#: "auto" looks for bias wander only where the windows span at least this long, s: over a
#: session of minutes an excess misfit is model error (a warming MEMS drifts, a hand-turned
#: unit flexes), which wander would only hide (imucal's Ferraris session: an accel "wander" of
#: 0.24 counts that tripled the bias sigma).
WANDER_MIN_SPAN_S = 3600.0


def carry_unproven(model: WanderModel, fits: list[WanderFit]) -> WanderModel:
    """``model`` plus every triad whose wander the test did not keep but whose restricted
    likelihood still rose with it (2 ln L gain > 0), at its estimate (sigma at the conservative
    tau; a kept triad is carried at its 84 % bound instead).

    A wander below the test's threshold is not claimed (the note says none is shown, diagnose
    looks only at kept ones), but the windows cannot rule it out, and a fit that leaves it out
    reports sigmas that miss it. Measured on bench_wander's in-sample units (0-9, 100-109,
    2600-2639, LM, 720 scale and bias coefficients), where both triads wander at 0.5-6 times
    the window noise:

    ============================  ===========  =====  =================================
    unproven wander               within 3 sd  RMS z  same units, no wander: units with
                                                      a sigma grown > 1.5x (of 60)
    ============================  ===========  =====  =================================
    left out (before)             99.2 %       0.91   0
    at its estimate (this)        99.6 %       0.85   29 (RMS z 1.01 -> 0.94)
    at its 84 % bound             99.7 %       0.82   43 (RMS z 0.88), one sigma 9.3x
    ============================  ===========  =====  =================================

    The misses left out were wanders at 1-1.3 times the window noise whose gains (0.8-10.7)
    stayed under the threshold. The estimate, not the bound: where the windows show no wander
    its estimate is mostly 0 and the sigmas stay as they were."""
    triads = dict(model.triads)
    carried = []
    for f in fits:
        if f.sensor in triads or f.significant or f.gain <= 0 or f.sigma <= 0:
            continue
        triads[f.sensor] = TriadWander(np.full(3, f.sigma), np.full(3, f.tau_s))
        carried.append(f.sensor)
    if not carried:
        return model
    note = (
        f"{' and '.join(carried)}: a wander below the test's threshold, not claimed, carried at "
        "its 84 % bound so that the 1-sigma covers what the windows cannot rule out"
    )
    return WanderModel(triads, model.source, (*model.notes, note), frozenset(carried))


def refit_with_wander(
    problem: Problem,
    theta: np.ndarray,
    theta0: np.ndarray,
    typical: np.ndarray,
    report: ObservabilityReport,
    opt: CalibrationOptions,
) -> tuple[Problem, np.ndarray, dict[str, Any], int]:
    """The fit again with the windows' bias wander in their covariance (recal.solve.wander):
    ``opt.wander`` "auto" estimates it from this fit's residuals (kept only when significant),
    a WanderModel is taken as given. Returns the problem, the estimate, the JSON noise model
    and the evaluations spent."""
    windows = problem.window_invariants
    t = window_times(problem.positions.columns, problem.M)
    out: dict[str, Any] = {
        "windows": "their own standard errors (sem or std columns)",
        "times": "start_s/end_s" if t is not None else None,
    }
    if isinstance(opt.wander, WanderModel):
        model = opt.wander
    elif opt.wander == "auto":
        sessions = window_sessions(problem.positions.columns, problem.M)
        span = 0.0 if t is None else _longest_session_span(t, sessions)
        if span < WANDER_MIN_SPAN_S:
            out["wander"] = None
            out["wander_test"] = (
                f"not estimated: the windows span {span / 3600:.2g} h (wander between windows "
                f"is looked for over {WANDER_MIN_SPAN_S / 3600:g} h or more; over a shorter "
                "session an excess is model error, recal diagnose)"
            )
            return problem, theta, out, 0
        raw = problem.raw_residuals(theta[None])
        sigma_w = problem.window_sigma()
        r_std = np.concatenate([raw[n][0] for n in windows]) / sigma_w
        T = typical[:, None] * report.basis
        J = jacobian(problem, theta, T.T)[: len(r_std)]
        taus = correlation_times(t, sessions, span)  # 0, then from the windows' spacing up
        model, fits = estimate_wander(
            r_std, sigma_w, problem.wander_sensitivity(theta), t, taus=taus, jacobian=J,
            sessions=sessions,
        )  # fmt: skip
        out["wander_test"] = [
            {"sensor": f.sensor, "gain_2lnL": round(float(f.gain), 3), "threshold": WANDER_TEST,
             "significant": bool(f.significant), "sigma": float(f.sigma),
             "tau_s": float(f.tau_s), "sigma_ml": float(f.sigma_ml), "tau_ml_s": float(f.tau_ml_s),
             "sigma_carried": float(f.sigma_carried), "sigma_upper": float(f.sigma_upper),
             **({} if f.joint_gain is None else {"joint_gain_2lnL": round(float(f.joint_gain), 3)})}
            for f in fits
        ]  # fmt: skip
        model = carry_unproven(model, fits)
    else:
        raise RecalInputError(f"wander must be None, 'auto' or a WanderModel, not {opt.wander!r}")
    if model.empty:
        out["wander"] = None
        return problem, theta, out, 0
    problem = problem.with_wander(model, theta)
    out["wander"] = model.to_json_dict()
    if opt.method == "lm" or opt.polish:
        fixed = fixed_point(problem, theta, theta0, typical, report.basis)
        return fixed.problem, fixed.theta, out, fixed.evaluations
    lm = solve_lm(problem, theta, typical[:, None] * report.basis)
    out["note"] = "the swarm's answer refined by LM on the covariance with the wander"
    return problem, lm.theta, out, lm.evaluations


def _longest_session_span(t: np.ndarray, sessions: np.ndarray | None) -> float:
    """The longest time the windows of one session span, s (sessions restart the clock)."""
    if sessions is None:
        return float(np.ptp(t))
    return max(float(np.ptp(t[sessions == k])) for k in np.unique(sessions))


def wander_note(wander: dict[str, Any]) -> str:
    parts, excess, unproven = [], [], []
    for s in ("gyro", "accel"):
        if s in wander and wander[s].get("significant") is False:
            unproven.append(f"{s} {max(wander[s]['sigma']):.3g} (output units)")
        elif s in wander:
            sig = max(wander[s]["sigma"])
            tau = max((v for v in wander[s]["tau_s"] if v is not None), default=None)
            if tau == 0.0:  # no correlation between windows: not a wander they can show
                excess.append(f"{s} {sig:.3g} (output units)")
                continue
            parts.append(
                f"{s} {sig:.3g} (output units)"
                + ("" if tau is None else f", correlation time {tau / 3600:.3g} h")
            )
    out = []
    if parts:
        out.append("the windows share a bias wander (" + "; ".join(parts)
                   + f", {wander.get('source', 'given')}): the fit and its 1-sigma carry it "
                   "(noise_model)")  # fmt: skip
    if excess:
        out.append(
            "the windows scatter more than their noise, independently of one another ("
            + "; ".join(excess)
            + "): not a wander the windows' spacing can show but model error or a wander "
            "faster than the spacing; the 1-sigma carries it, recal diagnose looks for the "
            "missing effect"
        )
    if unproven:
        out.append(
            "no significant wander, but the windows cannot rule one out ("
            + "; ".join(unproven)
            + ", its estimate): the 1-sigma carries it"
        )
    return "; ".join(out)
