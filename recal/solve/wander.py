"""Bias wander between windows: a Gauss-Markov model of each triad's bias and what it does to the
window invariants' covariance.

A window's mean carries its own white noise (its sem) and the bias the sensor had at that time.
A FOG's bias wanders between windows (bias instability, rate random walk, temperature history),
an accelerometer's too; the constant part is the calibrated bias, the rest is noise that two
windows share the more, the closer they are in time. Modelled here, per triad and axis, as a
first-order Gauss-Markov process of steady-state 1-sigma ``sigma`` (output units) and
correlation time ``tau_s``::

    cov(b_i, b_j) = sigma^2 exp(-|t_i - t_j| / tau)       (t: the windows' mid-times, s)

A window's invariants see the bias through their sensitivity to the outputs, so the residuals
of the gyro norm, accel norm and dot product of all windows get a full covariance

    Sigma = D^2 + sum_axes (g_a g_a^T) * sigma_a^2 * rho_a(|t_i - t_j|)

(D: the windows' own noise; g_a: each residual's sensitivity to axis a of its triad's output).
:class:`recal.solve.problem.Problem` whitens the window residuals by its Cholesky factor, so the
least-squares fit is a generalised one and the reported sigma includes the wander. A random walk
over the span of the windows behaves, after the constant bias is taken out, like a Gauss-Markov
process with a correlation time of that span: it is covered by a long ``tau_s``.

:func:`estimate_wander` finds sigma and tau of each triad from the standardised residuals of a
fit (maximum likelihood over a grid of correlation times, a likelihood-ratio test against no
wander); where no time columns exist the windows are taken as independent (tau 0: a per-window
inflation, said so).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.linalg import solve_triangular

from recal.errors import RecalInputError

#: Correlation times the estimate searches, s (0: independent windows).
TAU_GRID_S = (0.0, 900.0, 1800.0, 3600.0, 7200.0, 14400.0, 28800.0, 57600.0, 115200.0, 345600.0)


#: A fitted correlation time below the windows' spacing is not wander (below).
def tau_floor_s(t: np.ndarray, sessions: np.ndarray | None = None) -> float:
    """The shortest correlation time, s, a wander between these windows can show: the median
    gap between consecutive windows of one session (docs/noise.md, "The floor on tau").

    A Gauss-Markov bias correlates neighbouring windows by exp(-gap / tau). Below tau = gap
    that is under 1/e (0.37), and the lag-one correlation of N windows' residuals is known to
    about 1/sqrt(N) (0.18 for 30): a wander that fast is excess scatter independent on each
    window, which no window-to-window correlation distinguishes from model error. So the
    estimate tries 0 (independent excess, said to be such) and tau from this floor up."""
    t = np.asarray(t, float)
    order = np.argsort(t, kind="stable")
    gaps = np.diff(t[order])
    if sessions is not None:  # a gap across sessions is not a spacing
        s = np.asarray(sessions)[order]
        gaps = gaps[s[1:] == s[:-1]]
    gaps = gaps[gaps > 0]
    return float(np.median(gaps)) if gaps.size else 0.0


def correlation_times(
    t: np.ndarray | None, sessions: np.ndarray | None, span_s: float
) -> list[float]:
    """The correlation times the estimate tries, s: 0 (independent excess), the floor
    (:func:`tau_floor_s`) and the grid above it up to twice the span (a slower wander is a
    bias over the span). Only 0 without window times."""
    if t is None:
        return [0.0]
    floor = tau_floor_s(t, sessions)
    grid = [tau for tau in TAU_GRID_S if floor < tau <= 2.0 * span_s]
    return [0.0, *([floor] if floor > 0 else []), *grid]


#: The wander must earn its parameters per triad: sigma, and tau chosen on a grid (about 3
#: effective degrees of freedom): chi-square(3) at 1 %. Measured under no wander (200 triad
#: tests, 30 windows each): 1.5 % exceed it (chi-square(2)'s 9.21: 2 %; the 99 % point: 12.6).
WANDER_SIGNIFICANCE = 11.34
#: The correlation time taken is the longest whose profile 2 ln L lies within this of the best.
TAU_CONSERVATIVE = 2.0
#: A kept wander is carried in the fit at sigma's one-sided 84 % bound (2 ln L within 1 of its
#: best): tens of windows pin sigma to tens of percent, and at the best estimate the coefficients'
#: sigmas missed that (benchmarks/bench_wander.py, 40 units: 98.8 % within 3 sigma, 6 of 480
#: beyond; carried at the bound 99.4 %, RMS z 0.92, chi2_red 0.78; at the 95 % bound 99.4 % but
#: chi2_red 0.66).
SIGMA_CARRIED_DELTA = 1.0
#: A test that must not read wander as a change (the drift test) takes sigma at its one-sided
#: 95 % upper bound: 2 ln L of the profile within 2.71 of its best.
SIGMA_UPPER_DELTA = 2.71
#: The whitening refuses a covariance whose smallest eigenvalue falls below this (rounding).
_JITTER = 1e-10


@dataclass(frozen=True)
class TriadWander:
    """One triad's bias wander: steady-state 1-sigma per axis (output units) and correlation
    time per axis, s (0: independent windows; inf: a constant offset shared by every window)."""

    sigma: np.ndarray  # (3,)
    tau_s: np.ndarray  # (3,)

    def __post_init__(self) -> None:
        s = np.asarray(self.sigma, float).reshape(-1)
        t = np.asarray(self.tau_s, float).reshape(-1)
        if s.shape != (3,) or t.shape != (3,):
            raise RecalInputError("a triad's wander needs 3 sigmas and 3 correlation times")
        if not (np.all(np.isfinite(s)) and np.all(s >= 0) and np.all(t >= 0)):
            raise RecalInputError("wander sigmas must be finite and >= 0, correlation times >= 0")
        object.__setattr__(self, "sigma", s)
        object.__setattr__(self, "tau_s", t)


@dataclass(frozen=True)
class WanderModel:
    """Bias wander of each triad between windows (sensor -> :class:`TriadWander`), and where
    it came from ("estimated from the residuals", "given", ...)."""

    triads: Mapping[str, TriadWander] = field(default_factory=dict)
    source: str = "given"
    notes: tuple[str, ...] = ()

    @property
    def empty(self) -> bool:
        return not any(np.any(t.sigma > 0) for t in self.triads.values())

    def to_json_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": "gauss-markov", "source": self.source}
        for s, t in self.triads.items():
            out[s] = {
                "sigma": [float(v) for v in t.sigma],
                "tau_s": [float(v) if math.isfinite(v) else None for v in t.tau_s],
            }
        if self.notes:
            out["notes"] = list(self.notes)
        return out

    @classmethod
    def from_json_dict(cls, data: Mapping[str, Any], source: str = "given") -> WanderModel:
        """The ``"wander"`` block of a noise file or of calibrate's JSON (sensor -> {"sigma",
        "tau_s"}, output units and s; a null tau is infinite)."""
        if not isinstance(data, Mapping):
            raise RecalInputError("a wander model must be a JSON object")
        triads = {}
        for s in ("gyro", "accel"):
            block = data.get(s)
            if block is None:
                continue
            try:
                tau = [math.inf if v is None else float(v) for v in block["tau_s"]]
                triads[s] = TriadWander(np.array(block["sigma"], float), np.array(tau))
            except (KeyError, TypeError, ValueError) as exc:
                raise RecalInputError(
                    f"wander model, {s}: needs 'sigma' and 'tau_s' ({exc})"
                ) from exc
        return cls(triads, str(data.get("source", source)))


def correlation(t: np.ndarray, tau_s: float) -> np.ndarray:
    """(M, M) exp(-|t_i - t_j| / tau); tau 0: the identity, inf: all ones."""
    if tau_s == 0.0:
        return np.eye(len(t))
    if math.isinf(tau_s):
        return np.ones((len(t), len(t)))
    return np.exp(-np.abs(t[:, None] - t[None, :]) / tau_s)


def window_times(columns: Mapping[str, np.ndarray], M: int) -> np.ndarray | None:
    """The windows' mid-times, s (None without start_s and end_s: times unknown)."""
    if "start_s" not in columns or "end_s" not in columns:
        return None
    t = 0.5 * (np.asarray(columns["start_s"], float) + np.asarray(columns["end_s"], float))
    return t if t.shape == (M,) and np.all(np.isfinite(t)) else None


def window_sessions(columns: Mapping[str, np.ndarray], M: int) -> np.ndarray | None:
    """The windows' ``session`` column (each session restarts the device clock: windows of two
    sessions are not correlated by their times), or None (one session)."""
    s = columns.get("session")
    if s is None:
        return None
    s = np.asarray(s, float)
    return s if s.shape == (M,) else None


def wander_covariance(
    sensitivity: Mapping[str, np.ndarray],
    t: np.ndarray | None,
    model: WanderModel,
    sessions: np.ndarray | None = None,
) -> np.ndarray:
    """(R, R) covariance the wander adds to the window residuals.

    ``sensitivity``: sensor -> (R, M, 3) d residual / d output of each window's axis (zero
    where a residual does not involve the window or the triad); ``t``: (M,) mid-times, s, or
    None (independent windows); ``sessions``: (M,) session of each window (None: one), windows
    of different sessions independent."""
    R = next(iter(sensitivity.values())).shape[0] if sensitivity else 0
    out = np.zeros((R, R))
    for s, g in sensitivity.items():
        tw = model.triads.get(s)
        if tw is None:
            continue
        M = g.shape[1]
        for a in range(3):  # a loop over 3 axes; each term is one (R, M) x (M, M) product
            if tw.sigma[a] == 0:
                continue
            rho = correlation(t, float(tw.tau_s[a])) if t is not None else np.eye(M)
            if sessions is not None:
                rho = rho * (sessions[:, None] == sessions[None, :])
            ga = g[:, :, a]
            out += tw.sigma[a] ** 2 * (ga @ rho @ ga.T)
    return out


def whitener(sigma: np.ndarray, cov_wander: np.ndarray) -> np.ndarray:
    """W (R, R) such that W r_std has unit covariance, r_std = r / sigma: the inverse Cholesky
    factor of I + diag(1/sigma) Sigma_w diag(1/sigma)."""
    C = np.eye(len(sigma)) + cov_wander / np.outer(sigma, sigma)
    try:
        L = np.linalg.cholesky(C)
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(C)
        C = (V * np.maximum(w, _JITTER)) @ V.T
        L = np.linalg.cholesky(C)
    return np.linalg.solve(L, np.eye(len(sigma)))


@dataclass(frozen=True)
class WanderFit:
    """What :func:`estimate_wander` found for one triad: the likelihood gain over no wander
    (2 x log-likelihood ratio), whether it is significant, and the estimate."""

    sensor: str
    sigma: float  # isotropic 1-sigma, output units (at the conservative tau below)
    tau_s: float  # the longest tau within TAU_CONSERVATIVE of the best likelihood
    gain: float
    significant: bool
    sigma_ml: float = 0.0  # the maximum-likelihood pair, for filters that need the best
    tau_ml_s: float = 0.0  # guess rather than a bound (the drift test's innovations)
    joint_gain: float | None = None  # kept by the joint test of the triads no single test kept
    sigma_upper: float = 0.0  # upper bound of sigma at tau_s (SIGMA_UPPER_DELTA), for tests
    sigma_carried: float = 0.0  # what the fit carries when kept (SIGMA_CARRIED_DELTA)


def _sigma_upper(f: Any, sigma: float, delta: float) -> float:
    """The sigma above ``sigma`` (the minimiser of the restricted -log L ``f`` of sigma^2) where
    2 x f has risen by ``delta``: a one-sided upper bound (0 where there is no profile)."""
    if f is None or sigma <= 0:
        return 0.0
    f0 = f(sigma * sigma)
    lo, hi = math.log(sigma), math.log(sigma) + math.log(1e3)
    if 2.0 * (f(math.exp(2 * hi)) - f0) < delta:
        return math.exp(hi)
    for _ in range(40):  # bisection on log sigma
        mid = 0.5 * (lo + hi)
        if 2.0 * (f(math.exp(2 * mid)) - f0) < delta:
            lo = mid
        else:
            hi = mid
    return math.exp(hi)


def _golden_min(f: Any, lo: float, hi: float, steps: int = 30) -> float:
    """The minimiser of a unimodal f on [lo, hi] by golden-section search."""
    g = (math.sqrt(5) - 1) / 2
    a, b = lo, hi
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = f(c), f(d)
    for _ in range(steps):
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = f(d)
    return 0.5 * (a + b)


def estimate_wander(
    r_std: np.ndarray,
    sigma: np.ndarray,
    sensitivity: Mapping[str, np.ndarray],
    t: np.ndarray | None,
    taus: Sequence[float] = TAU_GRID_S,
    jacobian: np.ndarray | None = None,
    sessions: np.ndarray | None = None,
) -> tuple[WanderModel, list[WanderFit]]:
    """Each triad's wander from standardised window residuals ``r_std`` (R,) (raw / sigma at a
    fit), by maximum likelihood of r_std ~ N(0, I + D^-1 Sigma_w D^-1): isotropic sigma per
    triad, tau on ``taus`` (only 0 without times), one triad at a time with the others' found
    wander kept. Kept when 2 x the log-likelihood gain exceeds :data:`WANDER_SIGNIFICANCE`.

    ``jacobian`` (R, k): the standardised residuals' Jacobian along the k estimated directions.
    The fit absorbed what of the wander looks like a coefficient (a wander slower than the
    windows' span is a bias), so a plain likelihood of its residuals finds the wander too fast
    and too small (measured: 94 % of the coefficients within 3 sigma instead of 99 %). With the
    Jacobian the likelihood is the restricted one (REML): each candidate covariance refits the
    coefficients (generalised least squares, linearised) and pays log det of their information.
    """
    R = len(r_std)
    J = None
    if jacobian is not None and jacobian.size:
        U, sv, _ = np.linalg.svd(jacobian, full_matrices=False)
        J = U[:, sv > 1e-10 * sv.max()] * sv[sv > 1e-10 * sv.max()]
    found: dict[str, TriadWander] = {}
    fits: list[WanderFit] = []
    grid = list(taus) if t is not None else [0.0]

    def against(base: np.ndarray) -> Any:
        """A maker: unit covariance -> the restricted -log L of sigma^2 (that unit covariance
        times sigma^2 added to ``base``; None: ``base`` alone). With L L^T = I + B (B: base, standardised), I + B + s2 U =
        L (I + s2 W) L^T, W = L^-1 U L^-T = V diag(lam) V^T: one Cholesky per triad and one
        eigendecomposition per tau, then each sigma costs O(R k^2) (a golden-section search
        of 30 steps per tau: 200 windows in seconds, not minutes)."""
        L = np.linalg.cholesky(np.eye(R) + base / np.outer(sigma, sigma))
        logdet0 = 2.0 * float(np.sum(np.log(np.diag(L))))
        z0 = solve_triangular(L, r_std, lower=True)
        J0 = None if J is None else solve_triangular(L, J, lower=True)

        def make(unit: np.ndarray | None) -> Any:
            if unit is None:  # the base covariance alone: nothing to decompose
                lam, z, Jv = np.zeros(R), z0, J0
            else:
                X = solve_triangular(L, unit / np.outer(sigma, sigma), lower=True)
                lam, V = np.linalg.eigh(solve_triangular(L, X.T, lower=True))
                lam = np.clip(lam, 0.0, None)
                z = V.T @ z0
                Jv = None if J0 is None else V.T @ J0

            def f(s2: float) -> float:
                d = 1.0 / (1.0 + s2 * lam)
                value = float(np.sum(d * z * z)) + logdet0 + float(np.sum(np.log1p(s2 * lam)))
                if Jv is None:
                    return 0.5 * value
                A = Jv.T @ (d[:, None] * Jv)
                bv = Jv.T @ (d * z)
                return 0.5 * (value - float(bv @ np.linalg.solve(A, bv)) + np.linalg.slogdet(A)[1])

            return f

        return make

    # two rounds over the triads: each fitted with the others' wander as last found (the
    # second only when the first found some: otherwise it would repeat the first exactly)
    for round_ in range(2 if len(sensitivity) > 1 else 1):
        if round_ and not found:
            break
        fits = []
        for s in sensitivity:
            others = WanderModel({k: v for k, v in found.items() if k != s})
            make = against(wander_covariance(sensitivity, t, others, sessions))
            n0 = None
            profile = []  # (nll, sigma, tau) per correlation time
            for tau in grid:
                unit = wander_covariance(
                    {s: sensitivity[s]},
                    t,
                    WanderModel({s: TriadWander(np.ones(3), np.full(3, tau))}),
                    sessions,
                )
                d = np.diag(unit)
                if not (d > 0).any():
                    continue
                f = make(unit)
                n0 = f(0.0) if n0 is None else n0
                scale = math.sqrt(float(np.mean(sigma[d > 0] ** 2)) / float(np.mean(d[d > 0])))
                # log sigma over 7 decades around the residuals' scale
                lo, hi = math.log(scale * 1e-4), math.log(scale * 1e3)
                ls = _golden_min(lambda x, f=f: f(math.exp(2 * x)), lo, hi)
                profile.append((f(math.exp(2 * ls)), math.exp(ls), tau, f))
            if not profile or n0 is None:
                continue
            best = min(profile, key=lambda p: p[0])
            if best[0] > n0:  # no wander fits better than the smallest tried: none
                best = (n0, 0.0, 0.0, None)
                profile = [best]
            # the correlation time is poorly pinned by tens of windows, and a too short one
            # understates what the wander shares with the bias: take the longest within the
            # likelihood's 1-sigma-like interval (2 ln L within TAU_CONSERVATIVE of its best)
            near = [p for p in profile if 2.0 * (p[0] - best[0]) <= TAU_CONSERVATIVE]
            pick = max(near, key=lambda p: p[2])
            gain = 2.0 * (n0 - best[0])
            keep = gain > WANDER_SIGNIFICANCE
            upper = _sigma_upper(pick[3], pick[1], SIGMA_UPPER_DELTA)
            carried = _sigma_upper(pick[3], pick[1], SIGMA_CARRIED_DELTA)
            fits.append(
                WanderFit(s, pick[1], pick[2], gain, keep, best[1], best[2], sigma_upper=upper,
                          sigma_carried=carried)
            )  # fmt: skip
            if keep:
                found[s] = TriadWander(np.full(3, carried), np.full(3, pick[2]))
            else:
                found.pop(s, None)
    fits = _joint_test(fits, found, against, sensitivity, t, sessions)
    notes = () if t is not None else ("no start_s/end_s: windows taken as independent",)
    return WanderModel(found, "estimated from the residuals", notes), fits


def _joint_test(
    fits: list[WanderFit],
    found: dict[str, TriadWander],
    against: Any,
    sensitivity: Mapping[str, np.ndarray],
    t: np.ndarray | None,
    sessions: np.ndarray | None,
) -> list[WanderFit]:
    """Keep the triads no single test kept when, together, they earn their parameters.

    Each triad is tested with the others at the wander already kept, so two triads each just
    short of the threshold are both dropped although the windows' misfit is plain (measured: 90
    residuals, chi2_red 1.73, gains 11.3 and 8.7: wander at 0.7 and 1.5 times the window noise
    left out, and the drift test then read it as a step). Their joint gain, at each one's
    maximum-likelihood pair (a lower bound of the joint maximum), is tested against
    chi-square(3 k) at the same 1 % (``found`` is updated in place)."""
    from scipy.stats import chi2 as chi2_dist

    pending = [f for f in fits if not f.significant and f.sigma_ml > 0]
    if len(pending) < 2:
        return fits
    kept = WanderModel(dict(found))
    trial = dict(found)
    for f in pending:
        trial[f.sensor] = TriadWander(np.full(3, f.sigma_ml), np.full(3, f.tau_ml_s))
    n_kept = against(wander_covariance(sensitivity, t, kept, sessions))(None)(0.0)
    n_all = against(wander_covariance(sensitivity, t, WanderModel(trial), sessions))(None)(0.0)
    gain = 2.0 * (n_kept - n_all)
    if gain <= float(chi2_dist.ppf(0.99, 3 * len(pending))):
        return fits
    out = []
    for f in fits:
        if f in pending:
            f = replace(f, significant=True, joint_gain=gain)
            found[f.sensor] = TriadWander(np.full(3, f.sigma_carried), np.full(3, f.tau_s))
        out.append(f)
    return out


def possible_wander(noise_model: Mapping[str, Any] | None) -> WanderModel | None:
    """The wander a test that must not read wander as a change allows for: every triad the
    estimate tested, kept or not, at the one-sided 95 % upper bound of its sigma
    (:data:`SIGMA_UPPER_DELTA`) and its conservative correlation time; a given model as given.

    A calibration keeps a triad's wander only when it is significant, and at its best sigma,
    which keeps its own sigmas sharp; a drift test must instead cover the wander the windows
    could hold. Measured on 40 units with wander at 0.5-6 times the window noise, tau 1-24 h
    (benchmarks/bench_wander.py): with the kept model at its best sigma 13 of 40 unchanged units
    alarmed (4.0 expected at the configured rate; 2 with the simulated wander given). Reads a
    calibration's ``noise_model`` (its ``"wander"`` block and ``"wander_test"`` list)."""
    if not noise_model:
        return None
    block = noise_model.get("wander")
    model = WanderModel.from_json_dict(block, "the accepted version") if block else WanderModel()
    triads = dict(model.triads)
    tests = noise_model.get("wander_test")
    for test in tests if isinstance(tests, list) else ():
        s, tau = test.get("sensor"), test.get("tau_s")
        sigma = max(float(test.get("sigma") or 0.0), float(test.get("sigma_upper") or 0.0))
        if s in ("gyro", "accel") and sigma > 0 and tau is not None:
            triads[s] = TriadWander(np.full(3, sigma), np.full(3, float(tau)))
    if not triads:
        return None
    return WanderModel(triads, "the accepted version's, each triad at its upper bound")


def innovations(
    residual: np.ndarray,
    signature: np.ndarray,
    noise_cov: np.ndarray,
    H: Mapping[str, np.ndarray],
    t: np.ndarray | None,
    sessions: np.ndarray | None,
    model: WanderModel,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The window residuals as a Kalman filter's innovations under the wander, for tests that
    take windows in order and need them independent (the drift test's GLR).

    residual (M, K), signature (M, K, D) (d residual / d a coefficient change), noise_cov
    (M, K, K) the windows' own noise; H: sensor -> (M, K, 3) d residual / d that triad's output
    per axis; the wander state (one per axis of each triad in ``model``) follows its
    Gauss-Markov law between windows (restarted at each session). Returns the innovations
    nu_k = r_k - H x_k|k-1, the signatures run through the same filter (a change present from
    the first window; a step later in the window sequence is approximated by it) and the
    innovations' covariance S_k = H P H^T + R_k. Independent when the model is right."""
    M, K = residual.shape
    names = [s for s in ("gyro", "accel") if s in model.triads and s in H]
    if not names:
        return residual, signature, noise_cov
    sig = np.concatenate([model.triads[s].sigma for s in names])
    tau = np.concatenate([model.triads[s].tau_s for s in names])
    Hall = np.concatenate([H[s] for s in names], axis=2)  # (M, K, n)
    n = len(sig)
    D = signature.shape[2]
    nu, A2, S2 = residual.copy(), signature.copy(), noise_cov.copy()
    x, XA, P = np.zeros(n), np.zeros((n, D)), np.diag(sig**2)
    for k in range(M):  # a filter over windows: each step is a few small matrix products
        first = k == 0 or (sessions is not None and sessions[k] != sessions[k - 1])
        if first:
            x, XA, P = np.zeros(n), np.zeros((n, D)), np.diag(sig**2)
        else:
            gap = 0.0 if t is None else max(float(t[k] - t[k - 1]), 0.0)
            with np.errstate(divide="ignore", invalid="ignore"):
                phi = np.where(tau > 0, np.exp(-gap / np.where(tau > 0, tau, 1.0)), 0.0)
            if t is None:
                phi = np.zeros(n)
            x, XA = phi * x, phi[:, None] * XA
            P = phi[:, None] * P * phi[None, :] + np.diag(sig**2 * (1.0 - phi**2))
        Hk = Hall[k]
        Sk = Hk @ P @ Hk.T + noise_cov[k]
        Sk = 0.5 * (Sk + Sk.T)
        nu[k] = residual[k] - Hk @ x
        A2[k] = signature[k] - Hk @ XA
        S2[k] = Sk
        gain = np.linalg.solve(Sk, Hk @ P).T  # P H^T S^-1, (n, K)
        x = x + gain @ nu[k]
        XA = XA + gain @ A2[k]
        P = P - gain @ Hk @ P
        P = 0.5 * (P + P.T)
    return nu, A2, S2
