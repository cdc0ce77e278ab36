"""Calibration from static positions: the engine's one entry point.

:func:`calibrate` takes a positions table and :class:`CalibrationOptions` and returns a
:class:`CalibrationResult` holding the coefficients, the per-coefficient status ("estimated" or
"held"), the Gauss-Newton 1-sigma, the MCS spread (swarm methods), the observability verdict and
the residuals. The steps:

1. models: the seed model per triad plus requested catalogue/plugin effects;
2. prior: the previous calibration, or one derived from the data (common scale from the median
   norm, everything else neutral);
3. observability decided on real noise: with noise columns (*_sem, else *_std) at the prior;
   without them structural rank only, an LM fit, the noise from its residuals, then the
   decision -- never on the provisional sigma. Designs that cannot show scale and bias are
   refused; rank decides, not counting, and an exactly determined design is estimated with a
   note that the residual cannot check it;
4. solve on the observable directions (LM; or MCS-NAFSA/SAFSA/OAFSA, optionally LM-polished);
5. observability and covariance at the solution.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any, NamedTuple

import numpy as np

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.error_model import Model, ParameterLayout
from recal.model.plugins import bind_context, plugin_file, values_by_term
from recal.model.positions import Positions
from recal.model.terms import Term, catalogue_terms
from recal.solve.believable import physical_bounds, unbelievable
from recal.solve.consider import consider_covariance
from recal.solve.convergence import fixed_point, projected_start, swarm_convergence
from recal.solve.earth_rate import (  # noqa: F401 - scale_noise_needed: re-exported
    MIN_EARTH_RATE_CONTRAST,
    earth_rate_invisible,
    scale_noise_needed,
)
from recal.solve.lm import covariance, solve_lm
from recal.solve.mcs import SWARM_METHODS, run_mcs, solver_for
from recal.solve.notes import excess_note, observability_notes
from recal.solve.observability import (
    INFO_MIN,
    ObservabilityReport,
    analyze,
    typical_jacobian,
)
from recal.solve.options import CalibrationOptions
from recal.solve.phases import paper_phases, whitened_phase
from recal.solve.prior import HeldUncertainty, describe_prior, gyro_prior_sigma, prior_uncertainty
from recal.solve.problem import Problem
from recal.solve.result import MC_KIND, MC_KIND_PAPER, UNITS, CalibrationResult  # noqa: F401 - re-exported, were defined here
from recal.solve.slew_fit import (  # noqa: F401 - the public ones re-exported, were defined here
    SLEW_EXCESS_SIGNIFICANCE,
    SLEW_GYRO_BIAS_TYPICAL_DPH,
    SLEW_GYRO_G_SENSITIVITY_TYPICAL_DPH_PER_G,
    SLEW_GYRO_MISALIGNMENT_TYPICAL,
    SLEW_GYRO_SCALE_TYPICAL,
    SLEW_PRIOR_SLEWS,
    SlewExcess,
    blind_gyro,
    blind_gyro_models,
    information_shares,
    slew_excess,
    slew_prior,
    slews_see_earth_rate,
    turn_notes,
    usable_slews,
)
from recal.solve.start import data_prior, references
from recal.solve.surrogate import SurrogateProblem
from recal.solve.wander_fit import (  # noqa: F401 - WANDER_*: re-exported, were defined here
    WANDER_MIN_SPAN_S,
    WANDER_TEST,
    refit_with_wander,
    wander_note,
)

METHODS = ("lm",) + SWARM_METHODS
#: NAFSA's iterations per cycle on the default whitened phase, searched in blocks of 3 whitened
#: directions (recal.solve.separable); seed 000 Table 1's 60 are for its category phases in raw
#: units (--paper). A 3-direction block in sigma units: after 12 iterations the runs scatter
#: about 0.1 sigma from their minima (MC std / LM sigma 1.026 against 1.022 at 60), the mean
#: 0.03 sigma (30-position KVH-like captures with slews, seeds 3000 and 9001-9004;
#: benchmarks/bench_mcs_slews.py reports other seeds). SAFSA and OAFSA keep 60.
WHITENED_NAFSA_ITERATIONS = 12
#: The steps :func:`calibrate` reports to its ``progress`` callback with LM (one call each).
LM_STEPS = ("set-up", "observability", "fit", "fixed point", "uncertainty")


def build_models(
    sensors: Sequence[str], effects: Sequence[str], plugin_terms: Sequence[Term], t0_c: float
) -> tuple[Model, ...]:
    """Seed models for ``sensors`` plus catalogue effects (by name) and plugin terms."""
    catalogue = catalogue_terms(t0_c)
    extra: list[Term] = []
    for name in effects:
        if name in catalogue:
            extra.append(catalogue[name])
        elif not any(t.name == name for t in plugin_terms):
            known = ", ".join(sorted(catalogue) + [t.name for t in plugin_terms])
            raise RecalInputError(f"unknown effect '{name}'; known effects: {known}")
    # plugins are candidates for diagnose, never part of the model unless named in effects
    extra += [t for t in plugin_terms if t.name in effects]
    for t in extra:
        if t.sensor not in sensors:
            raise RecalInputError(f"effect {t.name} needs the {t.sensor} triad (--sensor)")
    return tuple(Model.seed(s, [t for t in extra if t.sensor == s]) for s in sensors)


def _plugin_metadata(layout: ParameterLayout) -> dict[str, Any]:
    """{"plugins": {effect: file}} for the plugin effects in the model (a coefficients file
    names what must be loaded to read it back), or nothing."""
    files = {t.name: plugin_file(t) for t in layout.term_of()}
    files = {n: f for n, f in files.items() if f is not None}
    return {"plugins": files} if files else {}


def _resolve_sensors(positions: Positions, sensor: str | None) -> tuple[str, ...]:
    if sensor in (None, "auto"):
        found = tuple(s for s in ("gyro", "accel") if getattr(positions, f"has_{s}"))
        return found
    if sensor == "both":
        return ("gyro", "accel")
    if sensor in ("gyro", "accel"):
        return (sensor,)
    raise RecalInputError(f"--sensor must be gyro, accel or both, not {sensor!r}")


def _decided(report: ObservabilityReport, when: str = "") -> ObservabilityReport:
    """``report``, or :class:`RecalInputError` when nothing at all can be estimated
    (docs/reference.md#cli). A design that cannot show some scale factors or biases is a
    partial success: those are held at the prior with its uncertainty, the verdict stays
    "insufficient" (a gate can refuse to publish it) and a note says so
    (:func:`recal.solve.notes.observability_notes`)."""
    if report.verdict == "insufficient" and report.rank == 0:
        where = f" {when}" if when else ""
        raise RecalInputError(f"unusable design{where}: nothing can be estimated: {report.message}")
    return report


def _same_span(a: np.ndarray, b: np.ndarray, tol: float = 1e-9) -> bool:
    """True when the orthonormal column sets ``a`` and ``b`` span the same subspace."""
    if a.shape != b.shape:
        return False
    return bool(np.all(np.linalg.svd(a.T @ b, compute_uv=False) > 1 - tol)) if a.size else True


class _SetUp(NamedTuple):
    """What a calibration starts from (shared by :func:`calibrate` and :func:`check_design`)."""

    sensors: tuple[str, ...]
    notes: list[str]
    layout: ParameterLayout
    theta0: np.ndarray  # the prior, (D,)
    prior_source: str
    problem: Problem
    typical: np.ndarray  # typical change per parameter, (D,)
    held: HeldUncertainty  # the prior's 1-sigma
    #: the observability at the prior and an LM fit on it, when set-up already made them
    first: tuple[ObservabilityReport, np.ndarray] | None


def _set_up(positions: Positions, opt: CalibrationOptions) -> _SetUp:
    """Sensors, notes, layout, prior theta0, its source, the Problem and typical changes.

    With slews and both triads the gyro is calibrated from the static invariants (Earth rate)
    and the slews together, each weighted by its own noise: a MEMS gyro's Earth-rate
    information then carries little weight without any threshold deciding. Earth's turn over
    a slew is taken out or left in the noise by comparing the two error budgets
    (:func:`slews_see_earth_rate`). Without slews a gyro whose outputs do not show Earth rate
    (:func:`earth_rate_invisible`) is left out by default.
    """
    sensors = _resolve_sensors(positions, opt.sensor)
    notes: list[str] = []
    slews = usable_slews(positions, opt, notes) if positions.has_gyro else None
    prior_scale = opt.prior.values.get("gyro.scale") if opt.prior is not None else None
    problem_gyro = earth_rate_invisible(positions, prior_scale) if "gyro" in sensors else None
    with_slews = slews is not None and positions.has_accel and "gyro" in sensors
    if with_slews and opt.sensor == "gyro":
        if problem_gyro:
            raise RecalInputError(
                problem_gyro + "; the slews could calibrate it with the accelerometers: leave "
                "--sensor out or use --sensor both"
            )
        with_slews = False
    if with_slews:
        sensors = ("gyro", "accel")
    elif problem_gyro and opt.sensor in (None, "auto") and "accel" in sensors:
        sensors = ("accel",)  # the default calibrates what the data can show
        notes.append(f"gyro not calibrated: {problem_gyro}")
    elif problem_gyro:
        raise RecalInputError(problem_gyro + "; use --sensor accel")
    if slews is not None and set(sensors) != {"gyro", "accel"}:
        notes.append("slews not used: they need both triads calibrated together")
        slews = None
    models = build_models(sensors, opt.effects, opt.plugin_terms, opt.t0_c)
    layout = ParameterLayout(models)
    start = data_prior(positions, layout, opt.latitude_deg, opt.height_m, MIN_EARTH_RATE_CONTRAST)
    if opt.prior is not None:
        fallback = {n: start.theta[sl] for n, sl in layout.term_slices().items()}
        theta0 = opt.prior.to_vector(layout, fallback)
    else:
        theta0 = start.theta
    # plugin terms may need site quantities or extra columns: bound to these positions here
    models = bind_context(models, positions, values_by_term(layout, theta0), opt.latitude_deg,
                          opt.height_m, with_slews=slews is not None)  # fmt: skip
    layout = ParameterLayout(models)
    excess, earth_rate, blind = 0.0, True, False
    gyro_sigma: dict[str, np.ndarray] | None = None  # the heading check's gyro prior 1-sigma

    def build(theta: np.ndarray) -> Problem:
        if blind:  # the bias's typical change for a gyro blind to Earth rate
            nonlocal models, layout
            models = blind_gyro_models(models, layout, theta)
            layout = ParameterLayout(models)
        return Problem.build(
            positions, models, opt.latitude_deg, opt.height_m, theta,
            slews=slews, slew_earth_rate=earth_rate, known_rotations=opt.known_rotations,
            turn_closure_sigma_deg=opt.turn_closure_sigma_deg, slew_excess_rad=excess,
            gyro_prior_sigma=gyro_sigma,
        )  # fmt: skip

    if slews is not None:
        # Earth's turn over the slews: taken out where a window mean measures Earth rate better
        # than leaving it in (a FOG), else left in with the zero rate from the two windows (a
        # MEMS gyro). The gyro's scale for that judgement: the prior's, else the median output
        # norm over Earth rate -- a gyro whose window means do not follow Earth rate
        # (problem_gyro: bias wander, or a MEMS whose output norm at rest is its bias) is
        # treated as blind to it even when its white noise alone would allow it
        earth_rate = not problem_gyro and slews_see_earth_rate(
            positions, prior_scale, opt.latitude_deg
        )
        blind = not earth_rate
        if blind:
            notes.append(
                f"gyro calibrated from the still windows and {len(slews)} slews in one fit: "
                "Earth rate is below the window-mean gyro noise, so Earth's turn over each slew "
                "is left in its noise, the zero rate over a slew is the mean output of its two "
                "windows, and the bias's typical change is taken as the larger of "
                f"{SLEW_GYRO_BIAS_TYPICAL_DPH:.4g} deg/h and 1000 ppm of the bias"
            )
            if opt.prior is None:  # the gyro's start from the slews
                theta0 = slew_prior(build(theta0), theta0)
        else:  # the Earth-rate heading check of closed turns: the gyro's prior 1-sigma
            gyro_sigma = gyro_prior_sigma(positions, layout, theta0, opt, start)
    problem = build(theta0)
    typical = layout.typical(theta0)
    own = None  # the data-derived start's own 1-sigma (a blind gyro's start is the slews')
    if opt.prior is None and start.sigma.shape == theta0.shape:
        own = start.sigma.copy()
        if blind:
            own[layout.model_slices()["gyro"]] = np.nan
    # the prior's 1-sigma: what a held coefficient carries, and which of two coefficients that
    # trade off is estimated (the one whose prior uncertainty shows more in the invariants)
    held = prior_uncertainty(positions, problem.layout, theta0, typical, opt, own)
    first = None
    if slews is not None:
        notes.append(
            f"{len(slews)} slews integrated ({slews.sums.shape[1]} increments each, coning "
            f"included; {np.median(slews.duration_s):.3g} s median)"
        )
        notes += turn_notes(problem)
        fit = slew_excess(problem, theta0, typical, held.sigma / typical, held.bar(layout, typical))
        excess, chi2_slews = fit.excess, fit.chi2_first
        if excess == 0 and fit.report is not None and fit.theta is not None:
            first = (fit.report, fit.theta)
        if excess > 0:
            plain, problem = problem, build(theta0)
            if (
                problem.noise_known
                and analyze(problem, theta0, typical).verdict == "insufficient"
                and analyze(plain, theta0, typical).verdict != "insufficient"
            ):
                notes.append(
                    f"the slews misfit beyond their window noise (slew chi2_red "
                    f"{chi2_slews:.3g}); an unmodelled error of {excess * 1e3:.3g} mrad per "
                    "slew residual would leave scale or bias unseen, so they keep the window "
                    "noise as their weight and the misfit scales the 1-sigma instead"
                )
                excess, problem = 0.0, plain
        if excess > 0:
            notes.append(
                f"the slews misfit beyond their window noise (slew chi2_red {chi2_slews:.3g} "
                f"at the first fit): an unmodelled error of {excess * 1e3:.3g} mrad per slew "
                "residual, estimated from their misfit, is added to their noise so each slew "
                "carries the weight its scatter allows (recal diagnose lists the worst slews)"
            )
        shares = information_shares(problem, theta0, typical)
        if shares:
            notes.append(shares)
    prior_source = describe_prior(layout, theta0, start.how, opt.prior,
                                  gyro_from_slews=blind and opt.prior is None)  # fmt: skip
    return _SetUp(sensors, notes, layout, theta0, prior_source, problem, typical, held, first)


def check_design(
    positions: Positions, options: CalibrationOptions | None = None, partial_ok: bool = True
) -> None:
    """Raise :class:`RecalInputError` when ``calibrate`` would refuse these positions for their
    design (nothing can be estimated), or, with ``partial_ok`` False, when it could only give a
    partial calibration (some scale factor or bias not separable: a gate does not publish it):
    at the prior, on the window noise when the positions carry it, else on structural rank
    alone (the decision on the estimated noise needs a fit). Cheap, so a service can answer a
    trigger with the reason."""
    opt = options or CalibrationOptions()
    su = _set_up(positions, opt)
    info_min = INFO_MIN if su.problem.noise_known else 0.0
    weights = su.held.sigma / su.typical
    bar = su.held.bar(su.layout, su.typical)
    report = _decided(analyze(su.problem, su.theta0, su.typical, info_min=info_min,
                              weights=weights, bar=bar))  # fmt: skip
    if not partial_ok and report.verdict == "insufficient":
        raise RecalInputError(f"only a partial calibration: {report.message}")


def calibrate(
    positions: Positions,
    options: CalibrationOptions | None = None,
    progress: Callable[[int], None] | None = None,
) -> CalibrationResult:
    """Recalibrate from static positions. Raises :class:`RecalInputError` for unusable input,
    a design from which nothing can be estimated, or a result that cannot be believed
    (:mod:`recal.solve.believable`).

    ``progress``: called as the work advances -- for a swarm with the Monte Carlo runs done
    (fractions as a batch goes through its cycles), for LM with 1 per step of :data:`LM_STEPS`.
    """
    opt = options or CalibrationOptions()
    t_start = time.perf_counter()

    def step() -> None:  # LM: one of LM_STEPS done
        if progress is not None and opt.method == "lm":
            progress(1)

    if opt.method not in METHODS:
        raise RecalInputError(f"--method must be one of {', '.join(METHODS)}, not {opt.method!r}")
    if opt.method != "lm" and opt.mc_runs < 1:
        raise RecalInputError("--mc must be at least 1")
    if not -90 <= opt.latitude_deg <= 90:
        raise RecalInputError(f"--latitude {opt.latitude_deg} is outside [-90, 90] deg")
    su = _set_up(positions, opt)
    sensors, notes, layout, theta0, prior_source, problem, typical, held_sigma, _ = su
    step()
    weights = held_sigma.sigma / typical
    bar = held_sigma.bar(layout, typical)
    evaluations = 0
    theta_fit: np.ndarray | None = None  # an LM optimum on report.basis, when one exists
    if problem.noise_known and su.first is not None:
        report, theta_fit = _decided(su.first[0]), su.first[1]  # set-up's fit (slews)
    elif problem.noise_known:
        report = _decided(analyze(problem, theta0, typical, weights=weights, bar=bar))
    else:
        # Noise first: the provisional sigma is no noise information, so judge structural rank
        # only, fit, estimate the noise from the residuals, and decide on that.
        structural = _decided(analyze(problem, theta0, typical, info_min=0.0, weights=weights,
                                      bar=bar))  # fmt: skip
        if structural.redundancy > 0:
            lm = solve_lm(problem, theta0, typical[:, None] * structural.basis)
            evaluations += lm.evaluations
            problem = problem.with_sigma_from_residuals(lm.theta, structural.rank)
            report = _decided(analyze(problem, lm.theta, typical, weights=weights, bar=bar),
                              "on the estimated noise")  # fmt: skip
            if len(problem.invariant_names) == 1 and _same_span(report.basis, structural.basis):
                theta_fit = lm.theta  # a uniform sigma rescales chi2 but cannot move the optimum
        else:
            report = structural  # no redundancy: the noise cannot be estimated
    step()
    mcs = None
    T = typical[:, None] * report.basis
    if opt.method == "lm":
        if theta_fit is None:
            lm = solve_lm(problem, theta0, T)
            theta_fit, evaluations = lm.theta, evaluations + lm.evaluations
        theta = theta_fit
    else:
        if opt.paper:
            # the seed's objective (eq. 14 per invariant over its noise floor); by default the
            # swarm minimises the least squares LM does (recal.solve.problem.Problem.objective)
            problem = replace(problem, paper_objective=True)
            phases = paper_phases(layout, typical)
        else:

            def phases(base: np.ndarray, model, problem=problem, report=report) -> list:
                if isinstance(model, SurrogateProblem) and model.quadratic:
                    # whitened for the cycle's Gauss-Newton model, where it is taken
                    return [whitened_phase(problem, model.theta_ref, typical, report,
                                           model.objective(base), jacobian_along=model.jacobian_along)]  # fmt: skip
                mean = base.mean(axis=0)
                return [whitened_phase(problem, mean, typical, report, problem.objective(base))]

        cfg = opt.swarm_config
        if opt.paper and cfg is None and opt.method == "nafsa":
            cfg = solver_for("nafsa")[1](cf_mode="literal")
        elif cfg is None and opt.method == "nafsa":
            cfg = solver_for("nafsa")[1](iterations=WHITENED_NAFSA_ITERATIONS)
        threshold = opt.indicator_threshold
        if threshold is None:
            threshold = 1e-8 if opt.paper else 0.0
        mcs = run_mcs(
            problem,
            theta0,
            phases,
            opt.method,
            opt.mc_runs,
            opt.seed,
            cfg,
            opt.cycles,
            progress=progress,
            indicator_threshold=threshold,
            # the slews linearised about the runs' mean every cycle, each run on its own
            # perturbed data (recal.solve.surrogate); paper mode: the exact objective, the same data
            linearise=None if opt.paper else typical,
            perturb=not opt.paper,
        )
        theta, evaluations = mcs.mean, evaluations + mcs.evaluations
        if opt.polish:
            lm = solve_lm(problem, theta, T)
            theta, evaluations = lm.theta, evaluations + lm.evaluations
    step()
    info_min = INFO_MIN if report.noise_decided else 0.0
    J_at = None  # the observability Jacobian at the answer, when it is already known
    if opt.method == "lm" or opt.polish:
        fixed = fixed_point(problem, theta, theta0, typical, report.basis)
        problem, theta, evaluations = fixed.problem, fixed.theta, evaluations + fixed.evaluations
        convergence = fixed.convergence
    else:
        assert mcs is not None
        # the gap to LM's minimum within the Monte Carlo mean's own sampling error
        J_at = typical_jacobian(problem, theta, typical)  # this check's and the analysis below
        convergence = swarm_convergence(problem, theta, theta0, typical, info_min, opt.method,
                                        mcs.runs, mcs.pairs, report.basis, J_at)  # fmt: skip
        evaluations += convergence.pop("evaluations", 0)
    step()
    solved = report
    report = analyze(problem, theta, typical, info_min=info_min, weights=weights, bar=bar, J=J_at)
    if opt.refuse_at_solution:
        report = _decided(report, "at the solution")
    if opt.paper and opt.method != "lm":
        # the seed's swarm searched every direction, the held ones too: those go back to the
        # prior (their values were arbitrary), only the observable part of its answer is kept
        theta = projected_start(theta, theta0, typical, report.basis)
        notes.append(
            "paper mode: the swarm also searched the directions no norm can see "
            f"({'; '.join(report.held_directions) or 'none'}); their values were arbitrary and "
            "are put back at the prior"
        )
    elif _same_span(report.basis, solved.basis):
        pass
    elif report.rank > solved.rank and _same_span(
        report.basis @ (report.basis.T @ solved.basis), solved.basis
    ):
        # judged at the solution the data show more: the new directions are fitted too (from
        # the solution, so nothing estimated goes back)
        lm = solve_lm(problem, theta, typical[:, None] * report.basis)
        theta, evaluations = lm.theta, evaluations + lm.evaluations
    else:
        # some direction estimated from the start is no longer pinned down at the solution:
        # it stays estimated (it moved; its 1-sigma says how well it is known), so the
        # status, the covariance and the held part are those of the directions solved for;
        # a scale factor or bias no longer seen there still makes the verdict (diagnose
        # rescues such a baseline, a gate does not publish it)
        if report.verdict == "insufficient":
            report = replace(solved, verdict=report.verdict, message=report.message)
        else:
            report = solved
    # bias wander between the windows: their residuals share noise the closer they are in time
    noise_model: dict[str, Any] = {}
    if opt.wander not in (None, "none") and problem.noise_known and problem.window_invariants:
        problem, theta, noise_model, more = refit_with_wander(
            problem, theta, theta0, typical, report, opt
        )
        evaluations += more
        if noise_model.get("wander"):
            notes.append(wander_note(noise_model["wander"]))
    # held means held: a coefficient no estimated coordinate touches is the prior, bitwise
    theta = np.where(report.estimated, theta, theta0)
    T = typical[:, None] * report.basis
    cov_measurement, chi2_red = covariance(problem, theta, T)
    # the held coefficients are not exact: their prior uncertainty moves the estimated ones.
    # A prior wider than physics allows (no unit is further off) is held at that bound.
    bounds = physical_bounds(layout, theta0, references(opt.latitude_deg, opt.height_m),
                             blind_gyro(problem.models))  # fmt: skip
    at_bound = ~report.estimated & (held_sigma.sigma > bounds)
    if at_bound.any():
        held_sigma = held_sigma._replace(sigma=np.where(at_bound, bounds, held_sigma.sigma))
        notes.append(
            "held at its physical bound (its prior 1-sigma was wider than any unit can be off): "
            + ", ".join(layout.names[i] for i in np.flatnonzero(at_bound))
        )
    sigma0 = held_sigma.sigma
    cov_held = consider_covariance(problem, theta, typical, report.basis, report.null, sigma0)
    cov = cov_measurement + cov_held
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    if opt.refuse_at_solution:
        why = unbelievable(
            problem, theta, theta0, typical, report.estimated, sd,
            np.sqrt(np.clip(np.diag(cov_measurement), 0, None)),
            references(opt.latitude_deg, opt.height_m), blind_gyro(problem.models),
        )  # fmt: skip
        if why:
            raise RecalInputError(
                f"no believable calibration from these positions: {why}; nothing is written "
                "(give a --prior, or positions that tilt the axes)"
            )
    step()
    status_flat = np.where(report.estimated, "estimated", "held")
    notes += observability_notes(report, problem)
    if convergence and not convergence.get("converged"):
        notes.append(f"not converged: {convergence.get('reason')}")
    if not problem.noise_known:
        notes.append(
            "no *_std or *_sem columns: noise estimated from the fit residuals"
            if report.redundancy > 0
            else "no *_std or *_sem columns and no redundancy: the noise and the uncertainty "
            "are unknown"
        )
    if problem.noise_known and chi2_red > 1e3:
        notes.append(
            f"chi2_red = {chi2_red:.3g}: the invariants are far off; check --latitude, the "
            "sensor's output units and that the windows are really static"
        )
    elif problem.noise_known and chi2_red > 4.0:
        notes.append(excess_note(problem, theta, T, chi2_red, opt.method))
    slices = layout.term_slices()
    coeffs = CoefficientSet.from_vector(
        layout,
        theta,
        opt.t0_c,
        method=opt.method,
        prior=prior_source,
        positions=problem.M,
        source=positions.source,
        **_plugin_metadata(layout),
    )
    coeffs.uncertainty = {n: sd[sl] for n, sl in slices.items()}
    return CalibrationResult(
        coefficients=coeffs,
        status={n: status_flat[sl] for n, sl in slices.items()},
        uncertainty={n: sd[sl] for n, sl in slices.items()},
        covariance=cov,
        covariance_measurement=cov_measurement,
        held_uncertainty=held_sigma,
        convergence=convergence,
        noise_model=noise_model,
        turn_closure_declared_deg=max(float(opt.turn_closure_sigma_deg), 0.0),
        observability=report,
        problem=problem,
        theta=theta,
        theta_prior=theta0,
        chi2_red=chi2_red,
        method=opt.method + (" (paper mode)" if opt.paper and opt.method != "lm" else ""),
        evaluations=evaluations,
        wall_time_s=time.perf_counter() - t_start,
        prior_source=prior_source,
        mcs=mcs,
        notes=notes,
    )
