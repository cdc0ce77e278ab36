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
``drift_null.NULL_WINDOWS``, at least ``NULL_EXCEEDANCES`` expected exceedances, a fixed seed so the
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
coefficients, :func:`drift_test` runs the sequential test on them. The parts live beside this
module: the windows' residuals, noise and signatures (:mod:`recal.diagnose.drift_windows`), the
coefficients' covariance and its file block (:mod:`recal.diagnose.drift_covariance`), the GLR
score and scan (:mod:`recal.diagnose.drift_glr`), the threshold's null simulation
(:mod:`recal.diagnose.drift_null`) and the suspects (:mod:`recal.diagnose.drift_suspects`); the
plain CUSUM baseline the benchmark compares against is benchmarks/drift_cusum.py.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from recal.diagnose.drift_covariance import coefficient_covariance
from recal.diagnose.drift_glr import scan, score
from recal.diagnose.drift_null import null_threshold
from recal.diagnose.drift_suspects import suspects
from recal.diagnose.drift_windows import accepted_model, invariants, noise_and_sensitivity
from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.positions import Positions

#: Finite-difference step of A_k in units of each coefficient's typical change.
FD_STEP = 1e-3


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
    (:class:`recal.solve.wander_model.WanderModel`, or its JSON block). The windows are then taken
    as a Kalman filter's innovations under it (:func:`recal.solve.wander_covariance.innovations`), which
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
    values = invariants(x, sensors, problem.latitudes_deg, height_m, free)  # (2D+1, M, 3)
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
    noise, sens = noise_and_sensitivity(problem, theta, x, sensors)
    residual = np.where(active, residual, 0.0)
    signature = np.where(active[..., None], signature, 0.0)
    both = active[:, :, None] & active[:, None, :]
    noise = np.where(both, noise, np.eye(3))
    cov = coefficient_covariance(coefficients, layout, covariance, notes)
    from recal.solve.wander_model import window_times

    time_s = window_times(positions.columns, M)
    if wander is not None:
        from recal.solve.wander_covariance import innovations
        from recal.solve.wander_model import WanderModel, window_sessions

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
    stats, flat = scan(S[None], F, Lp, seen, config.lookback)
    stat, flat = stats[0], flat[0]
    bound = threshold(config, int(seen.sum()))
    h, runs = null_threshold(
        C,
        F,
        Lp,
        seen,
        bound,
        false_alarm_windows=config.false_alarm_windows,
        lookback=config.lookback,
        seed=config.seed,
    )
    alarm = next((n for n in range(M) if stat[n] > h), None)
    tau_best = np.array(
        [max(0, n - config.lookback + 1) + int(f) // D for n, f in enumerate(flat)], int
    )
    j_best = flat % D
    change, change_sd = np.zeros(M), np.full(M, np.inf)
    for n in range(M):
        z, info = score(S, F, Lp, n, tau_best[n : n + 1])
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
        result.suspects = suspects(
            inputs.names, inputs.theta, S, F, Lp, at, int(tau_best[at]), seen
        )
    return result
