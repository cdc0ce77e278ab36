"""The slews in a calibration: which slews it uses (:func:`usable_slews`), a gyro blind to Earth
rate (a MEMS gyro) calibrated from them (its typical changes, :func:`blind_gyro_models`, and its
start, :func:`slew_prior`), whether Earth's turn over a slew is taken out
(:func:`slews_see_earth_rate`), the slews' unmodelled error (:func:`slew_excess`), and what the
still windows and the motion each tell about the gyro scale factors (:func:`information_shares`).
The slews themselves are integrated in :mod:`recal.detect.slew_collect`; :func:`recal.solve.calibrate`
puts them in its set-up."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from recal.detect.closed_turns import CHECKED
from recal.detect.slew_data import Slews
from recal.detect.slew_rotation import DEG_H_TO_RAD_S
from recal.model.error_model import Model, ParameterLayout
from recal.model.positions import Positions
from recal.model.reference import OMEGA_IE_DEG_H
from recal.solve.lm import solve_lm
from recal.solve.observability import ObservabilityReport, analyze, jacobian
from recal.solve.options import CalibrationOptions
from recal.solve.problem import Problem

#: Typical change of the bias of a gyro that cannot see Earth rate (a MEMS gyro calibrated from
#: slews), deg/h: ten times Earth rate. Its turn-on bias changes by tens to thousands of deg/h,
#: so the FOG's 0.05 deg/h would call every bias such a gyro's windows can give "not seen".
SLEW_GYRO_BIAS_TYPICAL_DPH = 10.0 * OMEGA_IE_DEG_H


#: Typical relative change of the scale factors of a gyro that cannot see Earth rate: a MEMS
#: gyro's datasheet scale tolerance is 1-3 % (131 counts/(deg/s) +- 2 %, say).
SLEW_GYRO_SCALE_TYPICAL = 1e-2


#: Typical misalignment of such a gyro, rad: a MEMS datasheet's cross-axis sensitivity of 1-2 %
#: (a FOG's 1 mrad would hold what the slews pin to a few mrad).
SLEW_GYRO_MISALIGNMENT_TYPICAL = 1e-2


#: Typical g-sensitivity of such a gyro, deg/h per g: MEMS datasheets give 0.01-0.1 deg/s/g
#: (36-360 deg/h/g); a FOG's 0.01 deg/h/g would call what the windows show "not seen".
SLEW_GYRO_G_SENSITIVITY_TYPICAL_DPH_PER_G = 0.01 * 3600.0


def usable_slews(positions: Positions, opt: CalibrationOptions, notes: list[str]) -> Slews | None:
    """The slews of ``opt`` when they belong to these positions, else None (with a note)."""
    slews = opt.slews
    if slews is None:
        return None
    if slews.n_dropped:
        reasons = ", ".join(f"{k} {v}" for k, v in slews.dropped.items() if v)
        notes.append(
            f"{slews.n_dropped} slew(s) dropped: they cannot be integrated ({reasons}); their "
            "windows still serve as positions"
        )
    cols = positions.columns
    why = (
        "the positions have no start_s/end_s columns"
        if "start_s" not in cols or "end_s" not in cols
        else slews.mismatch(cols["start_s"], cols["end_s"])
    )
    if why:
        notes.append(f"slews not used: {why}")
        return None
    return slews if len(slews) else None


#: The common-scale search of :func:`slew_prior` uses at most this many slews, evenly spread
#: (it tries 600 scale factors: on every slew of a long voyage that alone took seconds).
SLEW_PRIOR_SLEWS = 256


def slew_prior(problem: Problem, theta0: np.ndarray) -> np.ndarray:
    """A gyro prior from the slews for a gyro that cannot see Earth rate: a common scale factor
    by a batched search on the slew residuals (a coarse log grid over a decade either side of
    the ratio of raw integrated output to the gravity-direction change, both signs, then a fine
    one; on at most :data:`SLEW_PRIOR_SLEWS` slews), the bias the mean window output over that
    scale, misalignment zero."""
    assert problem.slews is not None and problem.slew_basis is not None
    if len(problem.slews) > SLEW_PRIOR_SLEWS:
        keep = np.unique(
            np.linspace(0, len(problem.slews) - 1, SLEW_PRIOR_SLEWS).round().astype(int)
        )
        problem = replace(problem, slews=problem.slews.subset(keep),
                          slew_basis=problem.slew_basis[keep], known_rotations=None,
                          closed_turns=None)  # fmt: skip
    slews = problem.slews
    assert slews is not None
    sl = problem.layout.term_slices()
    theta = np.array(theta0, float)
    theta[sl["gyro.misalignment"]] = 0.0
    n0 = problem.positions.gyro.mean(axis=0)  # zero-rate output: Earth rate is below the noise
    f = problem.physical(theta[None])["accel"][0]
    u = f / np.linalg.norm(f, axis=1, keepdims=True)
    seen = np.arccos(np.clip(np.sum(u[slews.first] * u[slews.second], axis=1), -1, 1))
    raw = np.linalg.norm(slews.sums.sum(axis=1), axis=1)  # output units x s
    big = seen > 0.2
    ratio = raw[big] * DEG_H_TO_RAD_S / seen[big] if big.any() else raw * DEG_H_TO_RAD_S
    centre = float(np.median(ratio)) if ratio.size and np.median(ratio) > 0 else 1.0

    def best(scales: np.ndarray) -> float:
        cand = np.repeat(theta[None], scales.size, axis=0)
        cand[:, sl["gyro.scale"]] = scales[:, None]
        cand[:, sl["gyro.bias"]] = n0[None] / scales[:, None]
        r = problem.raw_residuals(cand)["slew"]
        cost = np.where(np.isfinite(r).all(axis=1), np.sum(r * r, axis=1), np.inf)
        return float(scales[int(np.argmin(cost))])

    coarse = centre * np.exp(np.linspace(-np.log(10.0), np.log(10.0), 241))
    k = best(np.concatenate([coarse, -coarse]))
    k = best(k * np.exp(np.linspace(-0.03, 0.03, 121)))
    theta[sl["gyro.scale"]] = k
    theta[sl["gyro.bias"]] = n0 / k
    return theta


def blind_gyro_models(
    models: tuple[Model, ...], layout: ParameterLayout, theta: np.ndarray
) -> tuple[Model, ...]:
    """The models with the gyro's typical changes set for a gyro blind to Earth rate (a MEMS
    gyro calibrated from slews): the scale's at least :data:`SLEW_GYRO_SCALE_TYPICAL` (its
    datasheet tolerance: a scale the data pin to 0.5 % is worth estimating although a FOG's
    1000 ppm would call it unseen), the bias's max(10 x Earth rate, the scale's typical relative
    change x |b|). The second term because such a gyro's zero-rate output is large against
    Earth rate: a relative scale change moves the input-referred bias b by as much of it, and
    the two must be judged on one footing. The misalignment and a g-sensitivity in the model
    get a MEMS's typical sizes too (:data:`SLEW_GYRO_MISALIGNMENT_TYPICAL`,
    :data:`SLEW_GYRO_G_SENSITIVITY_TYPICAL_DPH_PER_G`)."""
    sl = layout.term_slices()
    scale = next(t for m in models for t in m.terms if t.name == "gyro.scale")
    rel = np.maximum(np.asarray(scale.typical, float), SLEW_GYRO_SCALE_TYPICAL)
    typ = np.maximum(SLEW_GYRO_BIAS_TYPICAL_DPH, rel * np.abs(theta[sl["gyro.bias"]]))
    mis = next(t for m in models for t in m.terms if t.name == "gyro.misalignment")
    new = {"gyro.bias": typ, "gyro.scale": rel,
           "gyro.misalignment": np.maximum(mis.typical, SLEW_GYRO_MISALIGNMENT_TYPICAL)}  # fmt: skip
    if "gyro.g_sensitivity" in sl:
        g = next(t for m in models for t in m.terms if t.name == "gyro.g_sensitivity")
        new["gyro.g_sensitivity"] = np.maximum(g.typical, SLEW_GYRO_G_SENSITIVITY_TYPICAL_DPH_PER_G)
    return tuple(
        Model(m.sensor, tuple(
            replace(t, typical=tuple(float(v) for v in new[t.name])) if t.name in new else t
            for t in m.terms))
        for m in models
    )  # fmt: skip


def blind_gyro(models: Sequence[Model]) -> bool:
    """Whether these models were sized for a gyro blind to Earth rate (:func:`blind_gyro_models`)."""
    bias = next((t for m in models for t in m.terms if t.name == "gyro.bias"), None)
    return bias is not None and min(bias.typical) >= SLEW_GYRO_BIAS_TYPICAL_DPH


def slews_see_earth_rate(positions: Positions, scale: np.ndarray | None, lat: float) -> bool:
    """Whether Earth's turn over a slew is better taken out with the calibrated rest rate of its
    first window than left in the slew's noise budget: the window-mean gyro noise (deg/h, at the
    prior scale ``scale`` output/(deg/h), else the output noise over the median output norm in
    units of Earth rate) against the horizontal Earth rate it would remove (variances per
    component: sem^2 against (Omega cos(lat))^2 / 2, :func:`recal.detect.slew_gravity.slew_sigma`). Decided
    by the two error budgets, not by a contrast threshold; without noise columns the rest rate
    is used (a gyro without noise columns is judged on its residuals later)."""
    noise = positions.std_of_mean("gyro")
    if noise is None:
        return True
    sem = np.median(noise, axis=0)
    if scale is not None:
        sem_dph = sem / np.maximum(np.abs(np.asarray(scale, float)), 1e-300)
    else:  # output units: the prior's common scale is the median norm over Earth rate
        gain = np.median(np.linalg.norm(positions.gyro, axis=1)) / OMEGA_IE_DEG_H
        sem_dph = sem / max(gain, 1e-300)
    horizontal = OMEGA_IE_DEG_H * np.cos(np.radians(lat))
    return bool(np.mean(sem_dph**2) < horizontal**2 / 2.0)


#: Slews whose reduced chi2 exceeds 1 by this many of its standard errors (sqrt(2 / n)) carry an
#: unmodelled per-slew error, estimated from their misfit (:func:`slew_excess`).
SLEW_EXCESS_SIGNIFICANCE = 3.0


class SlewExcess(NamedTuple):
    """:func:`slew_excess`: the excess and the slews' chi2_red before it; without an excess the
    observability at the prior and the LM fit on it, which calibrate then reuses."""

    excess: float
    chi2_first: float
    report: ObservabilityReport | None = None
    theta: np.ndarray | None = None


def slew_excess(
    problem: Problem,
    theta0: np.ndarray,
    typical: np.ndarray,
    weights: np.ndarray | None = None,
    bar: np.ndarray | None = None,
) -> SlewExcess:
    """(excess, chi2_red of the slews before it): the unmodelled error per slew residual, rad,
    that makes the slews' chi2_red 1 at the fit, by the method of moments, iterated with the fit
    (3 rounds at most), or 0 when the slews fit to their window noise within
    :data:`SLEW_EXCESS_SIGNIFICANCE` standard errors. ``weights``, ``bar``: as for
    :func:`recal.solve.observability.analyze`.

    Why: on a real hand-turned MEMS session (imucal's Ferraris example) the face flips misfit by
    3-30 mrad against a noise floor of 0.3 mrad whatever the linear gyro model, while the closed
    turns fit; weighted by the window noise alone the flips would decide the scale factors and
    outweigh the turns 10:1. The excess gives each slew the weight its scatter allows."""
    if problem.slews is None or not problem.noise_known_for("slew"):
        return SlewExcess(0.0, float("nan"))
    n = problem.n_of("slew")
    base = problem.sigma["slew"]
    theta, excess, chi2_first = theta0, 0.0, float("nan")
    prob = problem
    # the directions the window noise lets the slews see, kept through the rounds (judged
    # again on the inflated noise, fewer are seen, the misfit grows and the excess runs away)
    report = analyze(prob, theta0, typical, weights=weights, bar=bar)
    T = typical[:, None] * report.basis
    for _ in range(4):
        lm = solve_lm(prob, theta0, T)
        theta = lm.theta
        r = prob.raw_residuals(theta[None])["slew"][0]
        chi2 = float(np.mean((r / np.sqrt(base**2 + excess**2)) ** 2))
        if np.isnan(chi2_first):
            chi2_first = chi2
            if chi2 < 1.0 + SLEW_EXCESS_SIGNIFICANCE * np.sqrt(2.0 / n):
                return SlewExcess(0.0, chi2_first, report, theta)
        new = float(np.sqrt(max(np.mean(r**2 - base**2), 0.0)))
        if abs(new - excess) <= 0.1 * max(new, 1e-300):
            excess = new
            break
        excess = new
        prob = replace(prob, slew_excess_rad=excess).at(theta0)
    return SlewExcess(excess, chi2_first)


def information_shares(problem: Problem, theta: np.ndarray, typical: np.ndarray) -> str | None:
    """What the static windows (gyro norm, dot product: Earth rate) and the motion (slews,
    closed turns, known rotations) each tell about the gyro scale factors: their 1-sigma, ppm,
    from each alone and together (Fisher information at ``theta``, every other coefficient
    estimated alongside), or None without slews."""
    sl = problem.layout.term_slices().get("gyro.scale")
    if sl is None or problem.slews is None:
        return None
    J = jacobian(problem, theta, np.diag(typical))  # (R, D), typical-scaled
    rows, start = {}, 0
    for n in problem.invariant_names:
        rows[n] = np.arange(start, start + problem.n_of(n))
        start += problem.n_of(n)
    empty = np.zeros(0, dtype=int)
    static = np.concatenate([rows.get(n, empty) for n in ("gyro_norm", "accel_norm", "dot")])
    motion = np.concatenate([rows.get(n, empty) for n in ("accel_norm", "slew", "closure",
                                                           "rotation")])  # fmt: skip
    idx = np.arange(problem.layout.size)[sl]
    rel = typical[idx] / np.maximum(np.abs(theta[idx]), 1e-300)  # typical -> relative

    def sd_ppm(r: np.ndarray) -> str:
        # a weak prior (100 typical changes) keeps unseen directions finite and makes adding
        # rows never raise a 1-sigma
        cov = np.linalg.inv(J[r].T @ J[r] + 1e-4 * np.eye(J.shape[1]))
        sd = np.sqrt(np.clip(np.diag(cov)[idx], 0, None))
        return "/".join("not seen" if v > 10 else f"{v * w * 1e6:.3g}" for v, w in zip(sd, rel))

    return (
        "gyro scale 1-sigma (x/y/z, ppm, window noise only) from Earth rate in the still "
        f"windows alone: {sd_ppm(static)}; from the slews alone: {sd_ppm(motion)}; together: "
        f"{sd_ppm(np.arange(J.shape[0]))} (one fit, each weighted by its own noise)"
    )


def turn_notes(problem: Problem) -> list[str]:
    """One note per slew that integrates close to whole turns about the vertical: closed
    (checked by Earth rate, with the headings, or declared) or not, and why."""
    notes = []
    for c in problem.turn_candidates:
        head = (
            f"slew {c.slew} (windows {c.first}-{c.second}) turns {c.integrated_deg:+.1f} deg "
            f"about the vertical and gravity returns: "
        )
        if c.how == CHECKED:
            notes.append(
                head + f"a closed turn ({c.turns:+d} x 360 deg), checked by Earth rate: headings "
                f"{c.heading_first_deg:.2f} and {c.heading_second_deg:.2f} deg, change "
                f"{c.heading_change_deg:+.3f} +- {c.sigma_deg:.3g} deg (the closure's 1-sigma)"
            )
        elif c.closed:
            notes.append(head + f"a closed turn ({c.turns:+d} x 360 deg), {c.reason}")
        else:
            notes.append(head + f"not taken as a closed turn: {c.reason}")
    return notes
