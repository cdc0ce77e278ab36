"""Drift test: have the coefficients changed since they were accepted? (issue 20)

New static windows are checked against the accepted coefficients through the rotation-invariant
quantities the engine calibrates from (:mod:`recal.solve.problem`): the gyro norm against Earth rate,
the accelerometer norm against local gravity and their dot product. Per window k the three raw
residuals r_k (input units) are modelled as

    r_k = A_k (delta + 1[k >= tau] Delta) + e_k,     e_k ~ N(0, R_k),   delta ~ N(0, P)

* ``A_k`` (3 x D) = -d r_k / d theta at the accepted coefficients: how each coefficient moves the
  invariants (a coefficient that truly rose by Delta shifts the residuals by A_k Delta);
* ``R_k`` (3 x 3) the window's own noise (its *_sem columns, else *_std / sqrt(samples),
  :meth:`Positions.std_of_mean`) carried into the invariants, with the correlation between an
  invariant and the dot product that share a triad's noise;
* ``delta`` the accepted coefficients' own error, covariance ``P`` (a calibration's full
  covariance, a coefficients file's "covariance" block, else its 1-sigma as a diagonal). It is the *same* in every window,
  so it correlates all residuals: a test that whitens each window alone sees it as a persistent
  shift and alarms on it. Here the stacked residuals are whitened with their full covariance
  ``blockdiag(R_k) + A P A^T`` (by the Woodbury identity, never an n x n matrix);
* ``Delta`` a change of one coefficient j (a step at window tau).

The statistic is the generalised likelihood ratio of a step in one coefficient, maximised over
the coefficient j and the change window tau (the last :attr:`DriftConfig.lookback` windows):

    T_n = max_{tau, j} z_j(tau, n)^2 / I_jj(tau, n)

with z the score and I the Fisher information of Delta_j given the windows up to n (the
coefficients' own uncertainty projected out). Under no change each ratio is chi-square with one
degree of freedom.

Threshold (the derivation): the configured false-alarm rate is one per N =
:attr:`DriftConfig.false_alarm_windows` windows (default 720: 30 days at 24 windows a day). Over
L windows that is a probability q = 1 - exp(-L / N) that a steady sequence alarms at all, so h is
the 1 - q quantile of max_{n < L} T_n under no change. The null model is known exactly (the
whitened windows are w = e + C Lp eta, e and eta standard normal: the windows' noise and the
coefficients' own error), so :func:`null_threshold` simulates it for *these* windows (L up to
:data:`NULL_WINDOWS`, at least :data:`NULL_EXCEEDANCES` expected exceedances, a fixed seed so the
same input gives the same threshold). An upper limit needs no simulation: window n alarms when
any of its W x D (change window, coefficient) ratios exceeds h, so by the union bound the chance
is at most W D P(chi2_1 > h), and

    h_bound = chi2_1.isf(1 / (N W D))

guarantees the rate. The ratios are strongly correlated across tau, j and n, so the bound is
conservative (about 23 against a simulated 17 for 30 windows, 27 coefficients, N = 720); it is
used when q is too small to simulate, and the simulated threshold never exceeds it. Nothing is
tuned by hand.

The suspect: after an alarm, with every window so far (else at the largest statistic), the pair
(tau, j) that maximises the ratio names the coefficient, and Delta_j = z_j / I_jj its size (e.g.
"gyro x scale, about +600 ppm"); candidates within 10 % of it are marked alike.

Pure numerics: no I/O. :func:`drift_inputs` builds the per-window quantities from positions and
coefficients, :func:`drift_test` runs the sequential test on them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.error_model import Model, ParameterLayout
from recal.model.positions import Positions
from recal.model.reference import OMEGA_IE_DEG_H, dot_reference, normal_gravity_g

#: Invariants of one window, in the order of the rows of A_k, R_k and r_k.
INVARIANTS = ("gyro_norm", "accel_norm", "dot")
#: Coefficients a triad must have to be tested (the others default to neutral).
REQUIRED_TERMS = ("scale", "bias")
#: Finite-difference step of A_k in units of each coefficient's typical change.
FD_STEP = 1e-3
#: Windows the threshold's null simulation covers at most (recal.diagnose.drift.null_threshold).
NULL_WINDOWS = 120
#: Exceedances of the threshold the null simulation expects at least, and its run limits.
NULL_EXCEEDANCES = 50
NULL_MIN_RUNS = 1000
NULL_MAX_RUNS = 20000
NULL_BATCH = 1000
#: Plain CUSUM baseline (:func:`plain_cusum`): reference value k in sigma of one window.
PLAIN_CUSUM_K = 0.5


@dataclass(frozen=True)
class DriftConfig:
    """The drift test's settings, in configuration terms.

    false_alarm_windows: mean number of windows between false alarms when nothing changes
        (default 720: one per 30 days at an expected 24 windows a day).
    lookback: the change window tau is searched over the last ``lookback`` windows; older
        changes are still seen, as a step within the look-back.
    seed: of the null simulation that sets the threshold (:func:`null_threshold`).
    watch: coefficient groups a step is searched in (term names' second part: scale, bias,
        misalignment, quadratic, or an effect's); fewer directions lower the threshold a little
        (scale and bias only: 16.4 instead of 17.4 on 30 windows).
    """

    false_alarm_windows: float = 720.0
    lookback: int = 30
    seed: int = 0
    watch: tuple[str, ...] = ("scale", "bias", "misalignment", "quadratic")

    @classmethod
    def per_days(cls, days: float, windows_per_day: float, lookback: int = 30) -> DriftConfig:
        """One false alarm per ``days`` at an expected ``windows_per_day``."""
        if days <= 0 or windows_per_day <= 0:
            raise RecalInputError("the false-alarm period and the window rate must be positive")
        return cls(days * windows_per_day, lookback)


@dataclass(frozen=True)
class DriftInputs:
    """Per-window quantities of the test (M windows, D coefficients).

    residual: (M, 3) raw invariant residuals at the accepted coefficients (deg/h, g, (deg/h)*g);
        0 where inactive.
    active: (M, 3) which invariants a window has (a triad missing, a gyro not still).
    noise_cov: (M, 3, 3) window noise of the residuals (identity on inactive rows).
    signature: (M, 3, D) A_k = -d residual / d theta (zero rows where inactive).
    coeff_cov: (D, D) covariance of the accepted coefficients.
    theta: (D,) accepted coefficients; names: (D,) flat names ("gyro.scale.Kx", ...).
    notes: what was assumed (a diagonal covariance, a triad not tested, ...).
    """

    residual: np.ndarray
    active: np.ndarray
    noise_cov: np.ndarray
    signature: np.ndarray
    coeff_cov: np.ndarray
    theta: np.ndarray
    names: tuple[str, ...]
    notes: tuple[str, ...] = ()
    time_s: np.ndarray | None = None

    @property
    def M(self) -> int:
        return int(self.residual.shape[0])


@dataclass
class DriftResult:
    """Outcome of :func:`drift_test`; per-window arrays have one entry per window (row)."""

    statistic: np.ndarray  # (M,) T_n, chi-square units
    threshold: float
    alarm_window: int | None  # first row with T_n > threshold
    change_window: np.ndarray  # (M,) the maximising tau at each n
    coefficient: np.ndarray  # (M,) index of the maximising coefficient at each n
    change: np.ndarray  # (M,) its estimated step, coefficient units
    change_sigma: np.ndarray  # (M,) 1-sigma of that step
    suspects: list[dict[str, Any]] = field(default_factory=list)
    directions: int = 0  # D in the threshold
    config: DriftConfig = field(default_factory=DriftConfig)
    threshold_bound: float = float("nan")  # the union bound (an upper limit of the threshold)
    null_runs: int = 0  # null sequences simulated for the threshold (0: the union bound)


# ---- inputs --------------------------------------------------------------------------------
def drift_inputs(
    positions: Positions,
    coefficients: CoefficientSet,
    covariance: np.ndarray | Mapping[str, Any] | None = None,
    latitude_deg: float = 45.0,
    height_m: float = 0.0,
    wander: Any = None,
) -> DriftInputs:
    """Residuals, noise, signatures and coefficient covariance of ``positions`` at
    ``coefficients``. ``covariance``: (D, D) in the layout of the tested triads (a
    :class:`~recal.solve.calibrate.CalibrationResult`'s, when it covers the same triads), or a
    coefficients file's ``"covariance"`` block (names + matrix); without it,
    ``coefficients.uncertainty`` as a diagonal (unknown sigma: 0, with a note).

    ``wander``: the accepted version's bias wander between windows
    (:class:`recal.solve.wander.WanderModel`, or its JSON block). The windows are then taken
    as a Kalman filter's innovations under it (:func:`recal.solve.wander.innovations`), which
    are independent as the GLR needs: wander no longer accumulates into a false step."""
    from recal.solve.problem import Problem

    if not -90.0 <= latitude_deg <= 90.0:
        raise RecalInputError(f"--latitude {latitude_deg} is outside [-90, 90] deg")
    notes: list[str] = []
    sensors, models, layout, theta = accepted_model(positions, coefficients, notes)
    problem = Problem.build(positions, models, latitude_deg, height_m, theta, use_dot=False)
    M, D = len(positions), layout.size
    # invariants at theta and at +-FD_STEP typical changes of each coefficient, in one batch
    step = FD_STEP * layout.typical(theta)
    pts = np.concatenate([theta[None], theta + np.diag(step), theta - np.diag(step)])
    x = problem.physical(pts)
    free = problem.vertical_free  # the gyro norm across gravity, no dot (recal.detect.creep)
    values = _invariants(x, sensors, problem.latitudes_deg, height_m, free)  # (2D+1, M, 3)
    residual = values[0]
    signature = -(values[1 : D + 1] - values[D + 1 :]) / (2 * step[:, None, None])
    signature = np.moveaxis(signature, 0, -1)  # (M, 3, D)
    active = np.zeros((M, 3), bool)
    active[:, 0] = "gyro" in sensors
    active[:, 1] = "accel" in sensors
    active[:, 2] = len(sensors) == 2
    still = positions.columns.get("gyro_still")
    if still is not None:
        active[still == 0, 0] = active[still == 0, 2] = False
    active[free, 2] = False
    noise, sens = _noise_and_sensitivity(problem, theta, x, sensors)
    residual = np.where(active, residual, 0.0)
    signature = np.where(active[..., None], signature, 0.0)
    both = active[:, :, None] & active[:, None, :]
    noise = np.where(both, noise, np.eye(3))
    cov = coefficient_covariance(coefficients, layout, covariance, notes)
    from recal.solve.wander import window_times

    time_s = window_times(positions.columns, M)
    if wander is not None:
        from recal.solve.wander import WanderModel, innovations, window_sessions

        model = wander if isinstance(wander, WanderModel) else WanderModel.from_json_dict(wander)
        if not model.empty:
            H = {s: np.where(active[..., None], v, 0.0) for s, v in sens.items()}
            sessions = window_sessions(positions.columns, M)
            residual, signature, noise = innovations(
                residual, signature, noise, H, time_s, sessions, model
            )
            notes.append(
                f"windows taken as innovations under the accepted version's bias wander "
                f"({', '.join(sorted(model.triads))}): wander is not read as a step"
            )
    return DriftInputs(
        residual, active, noise, signature, cov, theta, tuple(layout.names), tuple(notes), time_s
    )


def accepted_model(
    positions: Positions, coefficients: CoefficientSet, notes: list[str]
) -> tuple[tuple[str, ...], tuple[Model, ...], ParameterLayout, np.ndarray]:
    """The triads ``positions`` can test against ``coefficients`` (gyro first), their models
    (the seed terms plus the effects the coefficients carry), the flat layout and the accepted
    coefficients as a vector in it. Raises RecalInputError when nothing can be tested."""
    from recal.solve.calibrate import build_models

    sensors = _tested_sensors(positions, coefficients, notes)
    seed = {f"{s}.{k}" for s in sensors for k in ("scale", "bias", "misalignment", "quadratic")}
    effects = [n for n in coefficients.values if n not in seed and n.split(".")[0] in sensors]
    models = build_models(sensors, effects, [], coefficients.t0_c)
    layout = ParameterLayout(models)
    return sensors, models, layout, coefficients.to_vector(layout)


def _tested_sensors(
    positions: Positions, coefficients: CoefficientSet, notes: list[str]
) -> tuple[str, ...]:
    """Triads present in the positions and complete in the coefficients, gyro first."""
    source = coefficients.metadata.get("source", "coefficients")
    sensors = []
    for s in ("gyro", "accel"):
        if not getattr(positions, f"has_{s}"):
            continue
        have = [k for k in REQUIRED_TERMS if coefficients.get(f"{s}.{k}") is not None]
        if not have:
            notes.append(f"{s} not tested: {source} has no {s} coefficients")
            continue
        if len(have) < len(REQUIRED_TERMS):
            missing = ", ".join(f"{s}.{k}" for k in REQUIRED_TERMS if k not in have)
            raise RecalInputError(f"{source}: {missing} missing (needed to test the {s} triad)")
        sensors.append(s)
    if not sensors:
        present = [s for s in ("gyro", "accel") if getattr(positions, f"has_{s}")]
        raise RecalInputError(
            f"{source} has no coefficients for the triad(s) in {positions.source} "
            f"({', '.join(present)})"
        )
    for s in sensors:
        if positions.noise_source(s) is None:
            raise RecalInputError(
                f"{positions.source}: no {s}_x/y/z_sem or _std columns: the drift test needs "
                "each window's own noise"
            )
    return tuple(sensors)


def _invariants(
    x: dict[str, np.ndarray],
    sensors: Sequence[str],
    lat: np.ndarray,
    h: float,
    free: np.ndarray | None = None,
) -> np.ndarray:
    """(P, M, 3) residuals |w| - Omega, |f| - g, w.f - ref (0 where a triad is missing); ``lat``
    (M,) each window's latitude, deg. Where ``free`` (M,), the window's vertical rate is no
    measurement (recal.detect.creep): the gyro's residual is its rate across gravity less
    Earth's horizontal rate (the dot product is then left out by the caller)."""
    some = next(iter(x.values()))
    out = np.zeros(some.shape[:2] + (3,))
    lat = np.broadcast_to(np.asarray(lat, float), some.shape[1:2])
    g = np.array([normal_gravity_g(float(v), h) for v in lat])
    if "gyro" in x:
        w = x["gyro"]
        ref = np.full(len(lat), OMEGA_IE_DEG_H)
        sq = np.sum(w * w, axis=-1)
        if free is not None and free.any() and "accel" in x:
            f = x["accel"]
            vf = np.sum(w * f, axis=-1)
            sq = np.where(free, np.maximum(sq - vf**2 / np.sum(f * f, axis=-1), 0.0), sq)
            ref = np.where(free, OMEGA_IE_DEG_H * np.cos(np.radians(lat)), ref)
        out[..., 0] = np.sqrt(sq) - ref
    if "accel" in x:
        out[..., 1] = np.linalg.norm(x["accel"], axis=-1) - g
    if len(sensors) == 2:
        dot_ref = np.array([dot_reference(float(v), h) for v in lat])
        out[..., 2] = np.einsum("pmi,pmi->pm", x["gyro"], x["accel"]) - dot_ref
    return out


def _noise_and_sensitivity(
    problem, theta: np.ndarray, x: dict[str, np.ndarray], sensors
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(M, 3, 3) covariance of the window residuals from each window's standard errors, and
    sensor -> (M, 3, 3) d residual / d output of each axis (the wander's way in).

    The output noise (M, 3) goes to input units through the inverse model's own Jacobian
    d x / d N (per window, by central differences on all windows at once), then to the
    invariants: d|x| = u . dx and d(w . f) = f . dw + w . df."""
    M = problem.M
    sl = problem.layout.model_slices()
    J = np.zeros((M, 3, 6))  # d invariants / d (input gyro, input accel)
    cov_in = np.zeros((M, 6, 6))
    dxdn_of: dict[str, np.ndarray] = {}
    for i, s in enumerate(("gyro", "accel")):
        if s not in sensors:
            continue
        m = problem.model(s)
        v = x[s][0]  # (M, 3)
        sem = problem.positions.std_of_mean(s)
        out = problem.output(s)
        h = np.maximum(np.abs(out), 1e-12) * 1e-6
        dxdn = np.empty((M, 3, 3))
        for a in range(3):
            up, dn = out.copy(), out.copy()
            up[:, a] += h[:, a]
            dn[:, a] -= h[:, a]
            th = theta[None, sl[s]]
            dxdn[:, :, a] = (
                m.inverse(th, up, problem.ctx)[0] - m.inverse(th, dn, problem.ctx)[0]
            ) / (2 * h[:, a, None])
        dxdn_of[s] = dxdn
        cov_in[:, 3 * i : 3 * i + 3, 3 * i : 3 * i + 3] = np.einsum(
            "mia,ma,mja->mij", dxdn, sem**2, dxdn
        )
        J[:, i, 3 * i : 3 * i + 3] = v / np.linalg.norm(v, axis=1, keepdims=True)
    if len(sensors) == 2:
        J[:, 2, :3] = x["accel"][0]
        J[:, 2, 3:] = x["gyro"][0]
        grads = problem.norm_gradients("gyro_norm", {s: x[s][0] for s in sensors})
        J[:, 0, :3] = grads["gyro"]  # across gravity where the vertical rate is free
        if "accel" in grads:
            J[:, 0, 3:] = grads["accel"]
    sens = {
        s: np.einsum("mia,mab->mib", J[:, :, 3 * i : 3 * i + 3], dxdn_of[s])
        for i, s in enumerate(("gyro", "accel"))
        if s in dxdn_of
    }
    return np.einsum("mia,mab,mjb->mij", J, cov_in, J), sens


def coefficient_covariance(
    coefficients: CoefficientSet,
    layout,
    covariance: np.ndarray | Mapping[str, Any] | None,
    notes: list[str],
) -> np.ndarray:
    """(D, D) covariance of the accepted coefficients in ``layout``'s order: ``covariance`` as an
    array in that order, or as the coefficients file's ``"covariance"`` block (names + matrix,
    :func:`covariance_to_json`), else the 1-sigma values as a diagonal."""
    D = layout.size
    if covariance is not None and not isinstance(covariance, Mapping):
        cov = np.asarray(covariance, float)
        if cov.shape != (D, D):
            raise RecalInputError(f"coefficient covariance is {cov.shape}, expected ({D}, {D})")
        return 0.5 * (cov + cov.T)
    sigma = np.full(D, np.nan)
    for name, sl in layout.term_slices().items():
        u = coefficients.uncertainty.get(name)
        if u is not None and np.size(u) == sl.stop - sl.start:
            sigma[sl] = u
    if covariance is not None:
        return _named_cov(covariance, layout.names, sigma, notes)
    if not coefficients.uncertainty:
        notes.append(
            "the coefficients carry no 'uncertainty': taken as exact (their own error then "
            "counts as drift)"
        )
    elif np.isnan(sigma).any():
        unknown = [n for n, s in zip(layout.names, sigma, strict=True) if np.isnan(s)]
        notes.append(f"no uncertainty for {', '.join(unknown)}: taken as exact")
    else:
        notes.append(
            "coefficient uncertainty from the file's 1-sigma values as a diagonal covariance "
            "(the file has no 'covariance': their correlations are lost)"
        )
    return np.diag(np.nan_to_num(sigma) ** 2)


def covariance_to_json(names: Sequence[str], covariance: np.ndarray) -> dict[str, Any]:
    """The ``"covariance"`` block a coefficients file carries beside its 1-sigma values."""
    return {
        "names": list(names),
        "matrix": np.asarray(covariance, float).tolist(),
        "kind": "covariance of the flat coefficients (names: term.parameter), units as the "
        "coefficients",
    }


def _named_cov(
    block: Mapping[str, Any], names: Sequence[str], sigma: np.ndarray, notes: list[str]
) -> np.ndarray:
    """The file's covariance reordered to ``names``; coefficients it lacks keep their 1-sigma
    (uncorrelated)."""
    try:
        have = [str(n) for n in block["names"]]
        matrix = np.asarray(block["matrix"], float)
    except (KeyError, TypeError, ValueError):
        raise RecalInputError("'covariance' must have 'names' and a numeric 'matrix'") from None
    if matrix.shape != (len(have), len(have)) or not np.isfinite(matrix).all():
        raise RecalInputError(
            f"'covariance' matrix must be {len(have)} x {len(have)} finite numbers"
        )
    pos = {n: i for i, n in enumerate(have)}
    idx = np.array([pos.get(n, -1) for n in names])
    inside = idx >= 0
    cov = np.diag(np.nan_to_num(sigma) ** 2)
    sub = matrix[np.ix_(idx[inside], idx[inside])]
    cov[np.ix_(inside, inside)] = 0.5 * (sub + sub.T)
    if not inside.all():
        missing = [n for n, ok in zip(names, inside, strict=True) if not ok]
        notes.append(f"the file's covariance lacks {', '.join(missing)}: their 1-sigma used")
    notes.append("coefficient uncertainty from the file's covariance")
    return cov


# ---- the test ------------------------------------------------------------------------------
def threshold(config: DriftConfig, directions: int) -> float:
    """h with lookback x directions x P(chi2_1 > h) = 1 / false_alarm_windows (union bound)."""
    from scipy.stats import chi2

    if config.false_alarm_windows <= 1 or config.lookback < 1:
        raise RecalInputError("false_alarm_windows must exceed 1 and lookback be at least 1")
    return float(chi2.isf(1.0 / (config.false_alarm_windows * config.lookback * directions), 1))


def whiten(inputs: DriftInputs) -> tuple[np.ndarray, np.ndarray]:
    """(M, 3) whitened residuals w_k = L_k^-1 r_k and (M, 3, D) signatures L_k^-1 A_k, with
    R_k = L_k L_k^T (Cholesky)."""
    L = np.linalg.cholesky(inputs.noise_cov)
    w = np.linalg.solve(L, inputs.residual[..., None])[..., 0]
    C = np.linalg.solve(L, inputs.signature)
    return w, C


def drift_test(inputs: DriftInputs, config: DriftConfig | None = None) -> DriftResult:
    """The sequential GLR over (change window, coefficient) for windows 0..M-1 in row order."""
    config = config or DriftConfig()
    w, C = whiten(inputs)
    M, D = inputs.M, C.shape[2]
    # a coefficient is a direction only where the windows see it at all
    info_all = np.einsum("mid,mid->d", C, C)
    seen = info_all > 1e-12 * max(info_all.max(), 1e-300)
    seen &= np.array([n.split(".")[1] in config.watch for n in inputs.names])
    # square root of the coefficient covariance (it may be singular: held, exact)
    lam, V = np.linalg.eigh(inputs.coeff_cov)
    Lp = V * np.sqrt(np.clip(lam, 0.0, None))
    F = np.concatenate([np.zeros((1, D, D)), np.cumsum(np.einsum("mid,mie->mde", C, C), axis=0)])
    S = np.concatenate([np.zeros((1, D)), np.cumsum(np.einsum("mid,mi->md", C, w), axis=0)])
    stats, flat = _scan(S[None], F, Lp, seen, config.lookback)
    stat, flat = stats[0], flat[0]
    bound = threshold(config, int(seen.sum()))
    h, runs = null_threshold(C, F, Lp, seen, config, bound)
    alarm = next((n for n in range(M) if stat[n] > h), None)
    tau_best = np.array(
        [max(0, n - config.lookback + 1) + int(f) // D for n, f in enumerate(flat)], int
    )
    j_best = flat % D
    change, change_sd = np.zeros(M), np.full(M, np.inf)
    for n in range(M):
        z, info = _score(S, F, Lp, n, tau_best[n : n + 1])
        j = j_best[n]
        if info[0, j] > 0:
            change[n], change_sd[n] = z[0, j] / info[0, j], 1.0 / np.sqrt(info[0, j])
    result = DriftResult(stat, h, alarm, tau_best, j_best, change, change_sd,
                         directions=int(seen.sum()), config=config, threshold_bound=bound,
                         null_runs=runs)  # fmt: skip
    # named with every window so far: at the alarm a few windows often cannot tell a scale from
    # the same axis's bias (their ratios tie); the windows after it can
    at = M - 1 if alarm is not None else int(np.argmax(stat)) if M else None
    if at is not None:
        result.suspects = suspects(inputs, S, F, Lp, at, int(tau_best[at]), seen)
    return result


def gain_parts(
    F: np.ndarray, Lp: np.ndarray, n: int, tau: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """G K (T, D, D) and diag(I) (T, D) for a step at each ``tau`` seen by window ``n``.

    With whitened windows the stacked covariance is I + B B^T, B = C Lp; by Woodbury its inverse
    is I - B (I + B^T B)^-1 B^T, so for a step signature a = C e_j on windows tau..n:
    z = a^T Sigma^-1 w = (S_n - S_tau) - G K S_n and I = G - G K G, with G = F_n - F_tau the
    information from tau on, K = Lp (I + Lp^T F_n Lp)^-1 Lp^T."""
    Mn = np.eye(Lp.shape[1]) + Lp.T @ F[n + 1] @ Lp
    K = Lp @ np.linalg.solve(Mn, Lp.T)
    G = F[n + 1][None] - F[tau]  # (T, D, D)
    GK = G @ K
    info = np.einsum("tdd->td", G) - np.einsum("tde,ted->td", GK, G)
    return GK, np.maximum(info, 0.0)


def _score(
    S: np.ndarray, F: np.ndarray, Lp: np.ndarray, n: int, tau: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Score z (T, D) and information diag(I) (T, D) of a step in each coefficient at each
    ``tau`` given windows 0..n, with the common coefficient error projected out (:func:`gain_parts`)."""
    GK, info = gain_parts(F, Lp, n, tau)
    z = (S[n + 1][None] - S[tau]) - GK @ S[n + 1]
    return z, info


def _scan(
    S: np.ndarray,
    F: np.ndarray,
    Lp: np.ndarray,
    seen: np.ndarray,
    lookback: int,
    where: bool = True,
) -> tuple[np.ndarray, np.ndarray | None]:
    """T_n for a batch of score sequences S (P, M+1, D): (P, M) statistics and, with ``where``,
    (P, M) flat index t * D + j of the maximising (change window offset t, coefficient j)."""
    P, M, D = S.shape[0], S.shape[1] - 1, S.shape[2]
    stat = np.zeros((P, M))
    arg = np.zeros((P, M), int) if where else None
    for n in range(M):
        tau = np.arange(max(0, n - lookback + 1), n + 1)
        GK, info = gain_parts(F, Lp, n, tau)
        T = tau.size
        ok = seen & (info > 1e-12 * max(info.max(), 1e-300))
        inv = np.where(ok, 1.0 / np.where(ok, info, 1.0), 0.0).reshape(T * D)
        z = (S[:, n + 1, None, :] - S[:, tau, :]).reshape(P, T * D)
        z -= S[:, n + 1] @ GK.reshape(T * D, D).T
        z *= z
        z *= inv
        if arg is None:
            stat[:, n] = z.max(axis=1)
        else:
            arg[:, n] = np.argmax(z, axis=1)
            stat[:, n] = z[np.arange(P), arg[:, n]]
    return stat, arg


def null_threshold(
    C: np.ndarray,
    F: np.ndarray,
    Lp: np.ndarray,
    seen: np.ndarray,
    config: DriftConfig,
    bound: float,
) -> tuple[float, int]:
    """The threshold at the configured false-alarm rate for these windows, and the simulated
    runs it took (0: the union bound ``bound`` was used).

    Under no change the whitened windows are w = e + C Lp eta (e, eta standard normal: the
    window noise and the coefficients' own error). One false alarm per N = false_alarm_windows
    windows means, over the first L = min(M, NULL_WINDOWS) windows, P(max_{n<L} T_n > h) =
    q = 1 - exp(-L / N): h is the 1 - q quantile of max_n T_n over simulated null sequences of
    exactly these windows (fixed seed: the same input gives the same threshold). Never above
    the union bound; the bound itself when q is too small to simulate (fewer than
    NULL_EXCEEDANCES exceedances expected in NULL_MAX_RUNS runs)."""
    M = C.shape[0]
    L = min(M, NULL_WINDOWS)
    if L == 0:
        return bound, 0
    q = -np.expm1(-L / config.false_alarm_windows)
    runs = int(np.ceil(NULL_EXCEEDANCES / q))
    if runs > NULL_MAX_RUNS:
        return bound, 0
    runs = max(runs, NULL_MIN_RUNS)
    from threadpoolctl import threadpool_limits

    rng = np.random.default_rng(config.seed)
    dF = F[1 : L + 1] - F[:L]  # (L, D, D) per-window information
    # small products: BLAS threads only contend (4x slower on a loaded 2-core machine)
    with threadpool_limits(1, user_api="blas"):
        maxima = _null_maxima(C[:L], dF, F[: L + 1], Lp, seen, config, runs, rng)
    h = float(np.quantile(maxima, 1.0 - q))
    return min(h, bound), runs


def _null_maxima(
    C: np.ndarray,
    dF: np.ndarray,
    F: np.ndarray,
    Lp: np.ndarray,
    seen: np.ndarray,
    config: DriftConfig,
    runs: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """max_n T_n of ``runs`` simulated null sequences of the windows C (L, 3, D)."""
    L, D = C.shape[0], C.shape[2]
    maxima = []
    for start in range(0, runs, NULL_BATCH):
        P = min(NULL_BATCH, runs - start)
        e = rng.standard_normal((P, L, 3))
        eta = rng.standard_normal((P, Lp.shape[1])) @ Lp.T  # (P, D) coefficient errors
        u = np.einsum("mid,pmi->pmd", C, e) + np.einsum("mde,pe->pmd", dF, eta)
        S = np.concatenate([np.zeros((P, 1, D)), np.cumsum(u, axis=1)], axis=1)
        maxima.append(_scan(S, F, Lp, seen, config.lookback, False)[0].max(axis=1))
    return np.concatenate(maxima)


def suspects(
    inputs: DriftInputs,
    S: np.ndarray,
    F: np.ndarray,
    Lp: np.ndarray,
    n: int,
    tau: int,
    seen: np.ndarray,
    top: int = 3,
) -> list[dict[str, Any]]:
    """The coefficients a step at ``tau`` seen at window ``n`` looks like, best first; "alike"
    marks those whose ratio is within 10 % of the best (the windows cannot tell them apart)."""
    z, info = _score(S, F, Lp, n, np.array([tau]))
    z, info = z[0], info[0]
    ok = seen & (info > 1e-12 * max(info.max(), 1e-300))
    ratio = np.where(ok, z * z / np.where(ok, info, 1.0), 0.0)
    out = []
    for j in np.argsort(-ratio)[:top]:
        if not ok[j]:
            continue
        size = z[j] / info[j]
        out.append({
            "coefficient": inputs.names[j],
            "statistic": float(ratio[j]),
            "change": float(size),
            "sigma": float(1.0 / np.sqrt(info[j])),
            "change_window": int(tau),
            "description": describe_change(inputs.names[j], size, inputs.theta[j]),
            "alike": bool(ratio[j] >= 0.9 * ratio.max()),
            "window": int(n),
        })  # fmt: skip
    return out


def describe_change(name: str, change: float, value: float) -> str:
    """'gyro x scale, about +600 ppm' for a step ``change`` of flat coefficient ``name``."""
    sensor, term, param = (name.split(".") + ["", ""])[:3]
    axis = param[-1] if param[-1:] in "xyz" else ""
    if term == "scale":
        return f"{sensor} {axis} scale, about {change / value * 1e6:+.3g} ppm"
    if term == "bias" and sensor == "accel":
        return f"accel {axis} bias, about {change * 1e6:+.3g} micro-g"
    if term == "bias":
        return f"gyro {axis} bias, about {change:+.3g} deg/h"
    if term == "misalignment":
        return f"{sensor} misalignment {param}, about {change * 1e6:+.3g} micro-rad"
    if term == "quadratic":
        return f"accel {axis} quadratic, about {change * 1e6:+.3g} micro-g/g^2"
    return f"{name}, about {change:+.3g}"


# ---- baseline ------------------------------------------------------------------------------
def plain_cusum(inputs: DriftInputs, config: DriftConfig | None = None) -> DriftResult:
    """The baseline the issue measures against: a two-sided CUSUM per invariant on the residuals
    whitened by each window's own noise alone (the coefficients' uncertainty ignored), reference
    value k = 0.5 sigma, threshold from Siegmund's approximation of the in-control run length,
    ARL0 = (exp(2k(h + 1.166)) - 2k(h + 1.166) - 1) / (2 k^2), set to 6 x false_alarm_windows
    (six one-sided CUSUMs)."""
    from scipy.optimize import brentq

    config = config or DriftConfig()
    k = PLAIN_CUSUM_K
    sd = np.sqrt(np.einsum("mii->mi", inputs.noise_cov))
    y = np.where(inputs.active, inputs.residual / sd, 0.0)
    target = 6.0 * config.false_alarm_windows

    def arl(hh: float) -> float:
        b = 2 * k * (hh + 1.166)
        return (np.exp(b) - b - 1) / (2 * k * k) - target

    h = float(brentq(arl, 0.0, 100.0))
    up = np.zeros(3)
    lo = np.zeros(3)
    stat = np.zeros(inputs.M)
    alarm = None
    for n in range(inputs.M):
        on = inputs.active[n]
        up = np.where(on, np.maximum(0.0, up + y[n] - k), up)
        lo = np.where(on, np.maximum(0.0, lo - y[n] - k), lo)
        stat[n] = max(up.max(), lo.max())
        if alarm is None and stat[n] > h:
            alarm = n
    zeros = np.zeros(inputs.M)
    return DriftResult(stat, h, alarm, zeros.astype(int), zeros.astype(int), zeros, zeros,
                       directions=3, config=config)  # fmt: skip
