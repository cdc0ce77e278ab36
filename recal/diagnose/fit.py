"""One model fitted for diagnose: the baseline's positions, prior and residual weights with a
set of effects added (:func:`fit_effects`), and where its misfit lies: per invariant
(:func:`invariant_rows`), per position and slew (:func:`worst_windows`), and how well it
predicts the positions it did not see (:func:`heldout_chi2_red`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from recal.errors import RecalInputError
from recal.model.error_model import ParameterLayout
from recal.model.plugins import bind_context, values_by_term
from recal.solve.calibrate import build_models
from recal.solve.lm import covariance, solve_lm
from recal.solve.observability import analyze, jacobian
from recal.solve.options import CalibrationOptions
from recal.solve.problem import Problem
from recal.solve.result import UNITS, CalibrationResult
from recal.solve.slew_fit import blind_gyro, blind_gyro_models


@dataclass
class Fit:
    """One model fitted with fixed residual weights."""

    effects: tuple[str, ...]
    problem: Problem
    theta: np.ndarray
    rank: int
    rss: float  # sum of squared whitened residuals (chi^2)
    verdict: str
    sd: np.ndarray | None = None  # 1-sigma per parameter at the solution (NaN where held)
    cov: np.ndarray | None = None  # covariance at the solution
    degenerate: bool = False  # the rank fell at the solution (a degenerate valley)
    jac: np.ndarray | None = None  # whitened Jacobian at the solution, observable directions
    transform: np.ndarray | None = None  # (D, k) parameter change per unit of those directions

    def residual(self) -> np.ndarray:
        return self.problem.residuals(self.theta[None])[0]


def finite_or_none(v: float) -> float | None:
    """JSON has no NaN: an undefined figure is null."""
    return float(v) if np.isfinite(v) else None


#: Singular value (whitened, per typical change) above which diagnose fits a direction. Lower
#: than calibrate's INFO_MIN = 1: an effect many times its typical size shows along a direction
#: the data pin down worse than that typical size (a scale-factor temperature coefficient of
#: 1e-4/degC against a typical 1e-5), and the F-test, not the prior size, must judge it.
FIT_INFO_MIN = 0.1


def fit_effects(
    base: CalibrationResult,
    opt: CalibrationOptions,
    effects: Sequence[str],
    start: dict[str, np.ndarray] | None = None,
    refit: bool = True,
) -> Fit:
    """Fit the model with ``effects`` on the baseline's positions, prior and residual weights,
    from ``start`` (term name -> values; default the baseline's solution), with the covariance
    and the rank at the solution."""
    positions = base.problem.positions
    fresh = build_models(base.problem.sensors, effects, opt.plugin_terms, opt.t0_c)
    fresh = bind_context(fresh, positions, values_by_term(base.layout, base.theta_prior),
                         opt.latitude_deg, opt.height_m, with_slews=base.problem.slews is not None)  # fmt: skip
    # the baseline's own terms (calibrate may have tuned them, e.g. the typical bias change of
    # a gyro calibrated from slews), then the effects
    models = tuple(
        b.with_terms([t for t in m.terms if t.name not in {u.name for u in b.terms}])
        for b, m in zip(base.problem.models, fresh, strict=True)
    )
    if blind_gyro(base.problem.models):  # effects sized for a MEMS gyro, as calibrate's terms
        prior = values_by_term(base.layout, base.theta_prior)
        th = np.concatenate([np.asarray(prior.get(t.name, t.neutral), float)
                             for m in models for t in m.terms])  # fmt: skip
        models = blind_gyro_models(models, ParameterLayout(models), th)
    layout = ParameterLayout(models)
    start = start if start is not None else values_by_term(base.layout, base.theta)
    theta0 = np.concatenate(
        [np.asarray(start.get(t.name, t.neutral), float) for m in models for t in m.terms]
    )
    b = base.problem  # the baseline's slews and known rotations, so every fit sees the same data
    problem = Problem.build(positions, models, opt.latitude_deg, opt.height_m, theta0,
                            slews=b.slews, slew_earth_rate=b.slew_earth_rate,
                            known_rotations=b.known_rotations,
                            slew_excess_rad=b.slew_excess_rad)  # fmt: skip
    # the baseline's closed turns (decided at its prior), not decided again at this start
    problem = replace(problem, closed_turns=b.closed_turns, turn_candidates=b.turn_candidates)
    problem = problem.with_sigma(b.sigma, b.sigma_source)
    if b.wander is not None:  # the baseline's bias wander is part of the noise every fit sees
        problem = problem.with_wander(b.wander, theta0)
    typical = layout.typical(theta0)
    report = analyze(problem, theta0, typical, info_min=FIT_INFO_MIN)
    if report.verdict == "insufficient":
        return Fit(tuple(effects), problem, theta0, report.rank, float("nan"), report.verdict)
    theta = solve_lm(problem, theta0, typical[:, None] * report.basis).theta if refit else theta0
    r = problem.residuals(theta[None])[0]
    at = analyze(problem, theta, typical, info_min=FIT_INFO_MIN)
    cov, _ = covariance(problem, theta, typical[:, None] * at.basis)
    sd = np.where(at.estimated, np.sqrt(np.clip(np.diag(cov), 0, None)), np.nan)
    T = typical[:, None] * at.basis
    # degenerate: directions vanish structurally at the solution (not a weak direction that
    # crosses FIT_INFO_MIN as theta moves)
    degenerate = refit and _structural_rank(problem, theta, typical) < _structural_rank(
        problem, theta0, typical
    )
    return Fit(tuple(effects), problem, theta, report.rank, float(r @ r), report.verdict,
               sd, cov, degenerate=degenerate, jac=jacobian(problem, theta, T.T),
               transform=T)  # fmt: skip


def best_fit(
    base: CalibrationResult,
    opt: CalibrationOptions,
    effects: list[str],
    start: dict[str, np.ndarray],
) -> Fit:
    """The model with ``effects`` fitted from ``start`` (the model before them) and from the
    prior; the better. A large missing effect drags the baseline's weakly pinned directions
    far from the truth, and a fit from there that holds them (they stay below the fitted
    information) settles above the floor (accel.scale_temperature, 1e-4/degC over a 15 degC
    swing: chi2 172 from the baseline, 72 from the prior, on 63 degrees of freedom)."""
    fits = [fit_effects(base, opt, effects, start=start)]
    try:
        fits.append(
            fit_effects(base, opt, effects, start=values_by_term(base.layout, base.theta_prior))
        )
    except RecalInputError:
        pass
    good = [f for f in fits if np.isfinite(f.rss) and not f.degenerate]
    return min(good, key=lambda f: f.rss) if good else fits[0]


def _structural_rank(problem: Problem, theta: np.ndarray, typical: np.ndarray) -> int:
    return analyze(problem, theta, typical, info_min=0.0).rank


def invariant_rows(fit: Fit) -> list[dict[str, Any]]:
    raw = fit.problem.raw_residuals(fit.theta[None])
    rows = []
    for n in fit.problem.invariant_names:
        r = raw[n][0]
        known = fit.problem.noise_known_for(n)
        floor = float(np.sqrt(np.mean(fit.problem.sigma[n] ** 2))) if known else None
        rms = float(np.sqrt(np.mean(r**2)))
        # a slew has two residuals and a known rotation three: rank what they belong to, 0-based
        key, owner = _owners(fit.problem, n)
        score = np.bincount(owner, weights=(r / fit.problem.sigma[n]) ** 2)
        rows.append(
            {
                "name": n,
                "rms": rms,
                "noise_floor": floor,
                "ratio": rms / floor if floor else None,
                "unit": UNITS[n],
                key: [int(i) for i in np.argsort(-score, kind="stable")[:3] if score[i] > 0],
                "per_position": [float(v) for v in r],
            }
        )
    return rows


#: Invariants with one residual per position, in position order.
PER_POSITION = frozenset({"gyro_norm", "accel_norm", "dot"})


def _owners(problem: Problem, name: str) -> tuple[str, np.ndarray]:
    """What each residual of invariant ``name`` belongs to: (JSON key, 0-based index per
    residual) -- a position, a slew (two residuals; a closed turn is one of its slews) or a
    known rotation (three)."""
    k = problem.n_of(name)
    if name in PER_POSITION:  # a triad's invariants may skip the windows it was not still in
        rows = getattr(problem, "rows_of", None)
        return "worst_positions", np.arange(k) if rows is None else np.asarray(rows(name))
    if name == "slew":
        return "worst_slews", np.repeat(np.arange(k // 2), 2)
    if name == "closure" and getattr(problem, "closed_turns", None) is not None:
        return "worst_slews", np.asarray(problem.closed_turns.index, dtype=int)
    if name == "rotation":
        return "worst_rotations", np.repeat(np.arange(k // 3), 3)
    return f"worst_{name}", np.arange(k)


#: How diagnose numbers positions and slews in its text and JSON.
INDEXING = "0-based rows of the positions file (slews: 0-based, slew k joins its two windows)"


def worst_windows(fit: Fit, k: int = 3) -> tuple[list[int], list[dict[str, int]]]:
    """The ``k`` positions (0-based rows) with the largest whitened misfit summed over the
    per-position invariants, and the ``k`` slews with the largest misfit ({"slew", "from_row",
    "to_row"}), largest first and each named once."""
    p = fit.problem
    w = fit.residual()
    per_pos = np.zeros(p.M)
    per_slew = np.zeros(len(p.slews) if p.slews is not None else 0)
    start = 0
    for n in p.invariant_names:
        rows = w[start : start + p.n_of(n)]
        start += p.n_of(n)
        key, owner = _owners(p, n)
        if key == "worst_positions":
            per_pos += np.bincount(owner, weights=rows**2, minlength=p.M)
        elif key == "worst_slews":
            per_slew += np.bincount(owner, weights=rows**2, minlength=per_slew.size)
    positions = [int(i) for i in np.argsort(-per_pos, kind="stable")[:k]]
    slews = [
        {"slew": int(i), "from_row": int(p.slews.first[i]), "to_row": int(p.slews.second[i])}
        for i in np.argsort(-per_slew, kind="stable")[:k]
    ]
    return positions, slews


def heldout_chi2_red(fit: Fit) -> float:
    """Leave-one-position-out chi^2 of the linearised fit over its expectation for a right
    model: positions are left out one at a time (all their invariants; slews and known
    rotations always stay in), the fit is redone without them along the observable directions
    and their whitened residuals predicted. For a linear fit the deletion is exact,
    e_g = (I - H_gg)^-1 r_g with H the hat matrix, and E[e_g' e_g] = tr((I - H_gg)^-1) under
    the window noise; the ratio of the sums is 1 for a right model, above 1 when the model
    fits the noise. NaN without a Jacobian or with fewer than three positions."""
    if fit.jac is None or not fit.jac.size or fit.problem.M < 3:
        return float("nan")
    p = fit.problem
    group = np.concatenate(
        [_owners(p, n)[1] if n in PER_POSITION else np.full(p.n_of(n), -1)
         for n in p.invariant_names]
    )  # fmt: skip
    U, sv, _ = np.linalg.svd(fit.jac, full_matrices=False)
    Q = U[:, sv > sv[0] * 1e-10] if sv.size and sv[0] > 0 else U[:, :0]
    r = fit.residual()
    members = [np.flatnonzero(group == i) for i in range(p.M)]
    press = expected = 0.0
    for size in {len(m) for m in members} - {0}:  # positions with as many rows, batched
        rows = np.stack([m for m in members if len(m) == size])  # (G, size)
        Qg = Q[rows]  # (G, size, rank)
        A = np.eye(size)[None] - Qg @ np.swapaxes(Qg, 1, 2)
        Ainv = np.linalg.pinv(A, rcond=1e-10, hermitian=True)
        e = np.einsum("gij,gj->gi", Ainv, r[rows])
        press += float(np.sum(e * e))
        expected += float(np.trace(Ainv, axis1=1, axis2=2).sum())
    return press / expected if expected > 0 else float("nan")
