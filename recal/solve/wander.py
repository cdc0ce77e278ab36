"""Bias wander between windows: a Gauss-Markov model of each triad's bias and what it does to the
window invariants' covariance, in state-space form (time and memory linear in the windows).

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
That covariance is dense (R^2 memory, R^3 time) but its process is a Markov chain: sampled at
the windows in time order, the bias state x_m (the 3 or 6 axes with wander) follows

    x_m = Phi_m x_{m-1} + w_m,   Phi_m = exp(-gap_m / tau) per axis,   var w_m = sigma^2 (1 - Phi_m^2)

(restarted at each ``session``: its clock restarts, its windows are independent of the last
session's), and window m's residuals observe it, r_m = H_m x_m + e_m, with H_m their
sensitivity rows over the window noise (a :class:`WanderSensitivity`: one window index and one
3-vector per residual and triad). Everything is computed on that chain:

* the whitening (:class:`Whitening`, used by :class:`recal.solve.problem.Problem`) is the Kalman
  filter's standardised innovations: the gains depend on the model only, so the innovations of
  any number of residual vectors are one block-bidiagonal banded solve;
* the restricted likelihood :func:`estimate_wander` profiles over (sigma, tau) uses the banded
  precision of the state, K^-1 + H^T H (block-tridiagonal), and the determinant lemma and
  Woodbury identity: log det C = log det(K^-1 + H^T H) + log det K and
  C^-1 = I - H (K^-1 + H^T H)^-1 H^T; a batch of candidates is one banded Cholesky (LAPACK
  pbtrf of the candidates' matrices stacked along the band) and one banded triangular solve
  for the residuals and the Jacobian's columns.

:class:`recal.solve.problem.Problem` whitens the window residuals so the least-squares fit is a
generalised one and the reported sigma includes the wander. A random walk over the span of the
windows behaves, after the constant bias is taken out, like a Gauss-Markov process with a
correlation time of that span: it is covered by a long ``tau_s``.

:func:`estimate_wander` finds sigma and tau of each triad from the standardised residuals of a
fit (restricted maximum likelihood over a grid of correlation times, a likelihood-ratio test
against no wander); where no time columns exist the windows are taken as independent (tau 0: a
per-window inflation, said so). :func:`wander_gain` is that test's statistic for a given model.
The dense forms (:func:`correlation`, :func:`wander_covariance`, :func:`whitener`) remain as
references for small problems and tests.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

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
    # in order of (session, time): each session restarts the clock
    order = np.lexsort((t,) if sessions is None else (t, np.asarray(sessions)))
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
#: The dense whitening refuses a covariance whose smallest eigenvalue falls below this.
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
    it came from ("estimated from the residuals", "given", ...). ``unproven``: the triads
    carried although their test did not keep them (recal.solve.wander_fit.carry_unproven):
    in the covariance, never claimed as wander."""

    triads: Mapping[str, TriadWander] = field(default_factory=dict)
    source: str = "given"
    notes: tuple[str, ...] = ()
    unproven: frozenset[str] = frozenset()

    @property
    def empty(self) -> bool:
        return not any(np.any(t.sigma > 0) for t in self.triads.values())

    def to_json_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": "gauss-markov", "source": self.source}
        for s, t in self.triads.items():
            out[s] = {
                "sigma": [float(v) for v in t.sigma],
                "tau_s": [float(v) if math.isfinite(v) else None for v in t.tau_s],
                **({"significant": False} if s in self.unproven else {}),
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
        triads, unproven = {}, set()
        for s in ("gyro", "accel"):
            block = data.get(s)
            if block is None:
                continue
            if isinstance(block, Mapping) and block.get("significant") is False:
                unproven.add(s)
            try:
                tau = [math.inf if v is None else float(v) for v in block["tau_s"]]
                triads[s] = TriadWander(np.array(block["sigma"], float), np.array(tau))
            except (KeyError, TypeError, ValueError) as exc:
                raise RecalInputError(
                    f"wander model, {s}: needs 'sigma' and 'tau_s' ({exc})"
                ) from exc
        notes = tuple(str(n) for n in data.get("notes") or ())
        return cls(triads, str(data.get("source", source)), notes, frozenset(unproven))


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


#: The precision form needs 1 - Phi^2 > 0 between consecutive windows: two windows at the same
#: mid-time share their bias exactly, which is floored at this (a relative innovation variance
#: of 1e-12: a difference of 1e-6 sigma between them).
_MIN_INNOVATION = 1e-12
#: Candidates per banded factorisation: the stacked right-hand sides (windows x state axes x
#: (1 + estimated directions) per candidate) are kept under about this many numbers (32 MB).
_BATCH_NUMBERS = 4_000_000
#: Golden-section fraction, Brent's search.
_GOLD = (3.0 - math.sqrt(5.0)) / 2.0
#: The profile's resolution in log sigma (the search's final bracket is a few times this).
_LOG_SIGMA_TOL = 1e-6
#: The carried correlation time's resolution between grid points, in log tau (0.5 %).
_LOG_TAU_TOL = 5e-3


@dataclass(frozen=True)
class WanderSensitivity:
    """d (window residual) / d (each triad's output), one window and one 3-vector per residual.

    A window residual (the gyro norm, accel norm or dot product of one window) sees the bias of
    its own window only, so it is stored compactly: ``window`` (R,) the window (position row)
    each residual belongs to, ``rows`` sensor -> (R, 3) d residual / d output of that window's
    axes (input units per output unit; zeros where the residual does not involve the triad),
    ``n_windows`` M. R x 3 numbers per triad, where the dense (R, M, 3) form took 1.8 GB at 5000
    windows (:meth:`dense` builds it, for small problems and tests)."""

    window: np.ndarray
    rows: Mapping[str, np.ndarray]
    n_windows: int

    def __post_init__(self) -> None:
        w = np.asarray(self.window, dtype=np.int64).reshape(-1)
        rows = {s: np.asarray(g, float).reshape(len(w), 3) for s, g in self.rows.items()}
        if w.size and (w.min() < 0 or w.max() >= self.n_windows):
            raise RecalInputError("wander sensitivity: a residual's window is out of range")
        object.__setattr__(self, "window", w)
        object.__setattr__(self, "rows", rows)

    @property
    def sensors(self) -> tuple[str, ...]:
        return tuple(self.rows)

    @property
    def n_residuals(self) -> int:
        return len(self.window)

    def dense(self) -> dict[str, np.ndarray]:
        """sensor -> (R, M, 3), zero off each residual's window (the form before issue 35)."""
        out = {}
        for s, g in self.rows.items():
            d = np.zeros((self.n_residuals, self.n_windows, 3))
            d[np.arange(self.n_residuals), self.window] = g
            out[s] = d
        return out

    @classmethod
    def from_dense(cls, dense: Mapping[str, np.ndarray]) -> WanderSensitivity:
        """The compact form of sensor -> (R, M, 3) arrays with one window per residual."""
        blocks = {s: np.asarray(g, float) for s, g in dense.items()}
        if not blocks:
            return cls(np.zeros(0, np.int64), {}, 0)
        R, M = next(iter(blocks.values())).shape[:2]
        mass = sum(np.abs(g).sum(axis=2) for g in blocks.values())  # (R, M)
        if np.any(np.count_nonzero(mass, axis=1) > 1):
            raise RecalInputError("wander sensitivity: a residual sees more than one window")
        window = np.argmax(mass, axis=1)
        rows = {s: g[np.arange(R), window] for s, g in blocks.items()}
        return cls(window, rows, M)


def as_sensitivity(sensitivity: Any) -> WanderSensitivity:
    """A :class:`WanderSensitivity`, or the dense sensor -> (R, M, 3) mapping converted."""
    if isinstance(sensitivity, WanderSensitivity):
        return sensitivity
    return WanderSensitivity.from_dense(sensitivity)


@dataclass(frozen=True)
class _Chain:
    """The windows as a Markov chain: in order of (session, mid-time), each with the gap to the
    previous window of its session (inf at a session's first window, and everywhere without
    times: independent), and each residual's place on it (its window's place in the chain and
    its slot among that window's residuals, ``q`` slots per window)."""

    pos: np.ndarray  # (R,) chain index of each residual's window
    slot: np.ndarray  # (R,)
    q: int
    gap: np.ndarray  # (M,) s, in chain order

    @property
    def M(self) -> int:
        return len(self.gap)

    def pad(self, values: np.ndarray) -> np.ndarray:
        """(R, ...) per residual -> (M, q, ...) per window slot (zeros in empty slots: a row of
        zero sensitivity and zero data with unit noise changes no likelihood)."""
        out = np.zeros((self.M, self.q, *values.shape[1:]))
        out[self.pos, self.slot] = values
        return out


def _chain(sens: WanderSensitivity, t: np.ndarray | None, sessions: np.ndarray | None) -> _Chain:
    M, R = sens.n_windows, sens.n_residuals
    if t is None:
        order = np.arange(M)
        gap = np.full(M, np.inf)
    else:
        t = np.asarray(t, float)
        s = np.zeros(M) if sessions is None else np.asarray(sessions, float)
        order = np.lexsort((t, s))  # by session, then time
        ts, ss = t[order], s[order]
        gap = np.full(M, np.inf)
        if M > 1:
            same = ss[1:] == ss[:-1]
            gap[1:] = np.where(same, ts[1:] - ts[:-1], np.inf)
    place = np.empty(M, np.int64)
    place[order] = np.arange(M)
    pos = place[sens.window]
    # slot: a residual's rank among its window's residuals (in residual order)
    by = np.lexsort((np.arange(R), pos))
    first = np.ones(R, bool)
    first[1:] = pos[by][1:] != pos[by][:-1]
    start = np.maximum.accumulate(np.where(first, np.arange(R), 0)) if R else by
    slot = np.empty(R, np.int64)
    slot[by] = np.arange(R) - start
    return _Chain(pos, slot, int(slot.max()) + 1 if R else 1, gap)


def _phi(gap: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """(..., M, n) exp(-gap / tau) for tau (..., n): the correlation of consecutive windows; 0
    at a session's start and for tau 0 (independent windows), 1 for an infinite tau."""
    g = gap[:, None]
    tb = np.asarray(tau, float)[..., None, :]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        phi = np.exp(-g / tb)
    return np.where((tb > 0) & np.isfinite(g), np.nan_to_num(phi, nan=1.0), 0.0)


def _state(
    model: Mapping[str, TriadWander], sens: WanderSensitivity
) -> tuple[list[tuple[str, int]], np.ndarray, np.ndarray]:
    """The state's axes (sensor, axis) of ``model`` that have wander and residuals that see
    them, with their sigma (n,) and tau_s (n,)."""
    axes, sig, tau = [], [], []
    for s in sens.sensors:
        tw = model.get(s)
        if tw is None:
            continue
        for a in range(3):
            if tw.sigma[a] > 0:
                axes.append((s, a))
                sig.append(tw.sigma[a])
                tau.append(tw.tau_s[a])
    return axes, np.array(sig, float), np.array(tau, float)


def _observation(
    sens: WanderSensitivity, sigma: np.ndarray, chain: _Chain, axes: Sequence[tuple[str, int]]
) -> np.ndarray:
    """(M, q, n) each window slot's sensitivity to the state's axes, over the residual's own
    1-sigma (the standardised residuals' observation matrix)."""
    cols = [sens.rows[s][:, a] / sigma for s, a in axes]
    H = np.stack(cols, axis=1) if cols else np.zeros((sens.n_residuals, 0))
    return chain.pad(H)


# ---- the whitening: Kalman innovations, one banded solve --------------------------------------
class Whitening:
    """W with W^T W = C^-1, C = I + D^-1 Sigma_w D^-1 the covariance of the standardised window
    residuals r / sigma (:meth:`apply`), and log det C: the Kalman filter's innovations.

    The filter's gains depend on the model alone (one pass over the windows, each step a few
    products of n x n matrices, n <= 6); the innovations of a batch of residual vectors are then
    x_m = F_m x_{m-1} + K_m z_m, F_m = (I - K_m H_m) Phi_m, a block-bidiagonal system solved for
    every vector at once (LAPACK tbtrs, band 2n - 1), and w_m = chol(S_m)^-1 (z_m - H_m Phi_m
    x_{m-1}). W is the inverse Cholesky factor of C with the residuals in window-time order (a
    residual's whitened value is its innovation: it depends on the windows before it), put back
    in the residuals' own order. Time and memory linear in the windows."""

    def __init__(
        self,
        sigma: np.ndarray,
        sensitivity: Any,
        t: np.ndarray | None,
        model: WanderModel,
        sessions: np.ndarray | None = None,
    ) -> None:
        sens = as_sensitivity(sensitivity)
        sigma = np.asarray(sigma, float)
        self.n_residuals = sens.n_residuals
        chain = _chain(sens, t, sessions)
        axes, sig, tau = _state(model.triads, sens)
        self.chain, self.n = chain, len(axes)
        if not axes:
            self.logdet = 0.0
            return
        H = _observation(sens, sigma, chain, axes)  # (M, q, n)
        phi = _phi(chain.gap, tau)  # (M, n)
        M, q, n = H.shape
        gains = np.empty((M, n, q))
        linv = np.empty((M, q, q))
        eye_q, eye_n = np.eye(q), np.eye(n)
        s2 = sig * sig
        P = np.zeros((n, n))
        for m in range(M):  # the Riccati recursion: one small step per window (n <= 6, q <= 3)
            f = phi[m]
            P = f[:, None] * P * f[None, :] + np.diag(s2 * (1.0 - f * f))
            Hm = H[m]
            PHt = P @ Hm.T
            L = np.linalg.cholesky(Hm @ PHt + eye_q)
            Li = np.linalg.inv(L)
            G = PHt @ (Li.T @ Li)  # P H^T S^-1
            IKH = eye_n - G @ Hm
            P = IKH @ P @ IKH.T + G @ G.T  # Joseph form: stays symmetric positive definite
            gains[m], linv[m] = G, Li
        self.H, self.phi, self.gains, self.linv = H, phi, gains, linv
        self.logdet = float(-2.0 * np.sum(np.log(np.diagonal(linv, axis1=1, axis2=2))))
        # F_m below the unit diagonal, lower band storage: row (m, a), column (m - 1, b) sits at
        # offset n + a - b
        F = (eye_n - np.einsum("mnq,mqk->mnk", gains, H)) * phi[:, None, :]
        ab = np.zeros((2 * n, M, n))
        for a in range(n):
            for b in range(n):
                ab[n + a - b, : M - 1, b] = -F[1:, a, b]
        self._band = np.asfortranarray(ab.reshape(2 * n, M * n))

    def apply(self, z: np.ndarray) -> np.ndarray:
        """(P, R) standardised residuals -> (P, R) whitened (unit covariance under the model)."""
        z = np.asarray(z, float)
        if self.n == 0:
            return z
        from scipy.linalg.lapack import dtbtrs

        chain, n = self.chain, self.n
        P, M = z.shape[0], chain.M
        # window-major (M, ., P): every step below is a batched small matmul over the windows
        zc = np.zeros((M, chain.q, P))
        zc[chain.pos, chain.slot] = z.T
        rhs = np.matmul(self.gains, zc)  # K_m z_m, (M, n, P)
        x, info = dtbtrs(self._band, rhs.reshape(M * n, P), uplo="L", diag="U")
        if info != 0:  # a unit triangular band has no singular pivot
            raise RuntimeError(f"wander whitening: tbtrs info {info}")
        x = x.reshape(M, n, P)
        pred = np.empty_like(x)  # Phi_m x_{m-1}: the state predicted at window m
        pred[0] = 0.0
        pred[1:] = x[:-1] * self.phi[1:, :, None]
        w = np.matmul(self.linv, zc - np.matmul(self.H, pred))
        return w[chain.pos, chain.slot].T


class WanderCovariance:
    """The covariance a wander model adds to a problem's window residuals, in state-space form:
    the model, the residuals' :class:`WanderSensitivity` (at the estimate it was built at), the
    windows' mid-times and sessions. :meth:`whitening` builds the :class:`Whitening` for the
    residuals' current 1-sigma and keeps it (problems copied with other fields share it);
    :meth:`dense` is the (R, R) matrix, for small problems and tests."""

    def __init__(
        self,
        model: WanderModel,
        sensitivity: WanderSensitivity,
        t: np.ndarray | None,
        sessions: np.ndarray | None = None,
    ) -> None:
        self.model, self.sensitivity, self.t, self.sessions = model, sensitivity, t, sessions
        self._last: tuple[np.ndarray, Whitening] | None = None

    def whitening(self, sigma: np.ndarray) -> Whitening:
        sigma = np.asarray(sigma, float)
        if self._last is None or not np.array_equal(self._last[0], sigma):
            W = Whitening(sigma, self.sensitivity, self.t, self.model, self.sessions)
            self._last = (sigma.copy(), W)
        return self._last[1]

    def dense(self) -> np.ndarray:
        return wander_covariance(self.sensitivity, self.t, self.model, self.sessions)


# ---- the restricted likelihood: banded precision, candidates batched ------------------------
def _directions(jacobian: np.ndarray | None) -> np.ndarray | None:
    """The Jacobian's column space, scaled as the REML's log det uses it (left singular vectors
    times their singular values, null directions dropped)."""
    if jacobian is None or not jacobian.size:
        return None
    U, sv, _ = np.linalg.svd(jacobian, full_matrices=False)
    keep = sv > 1e-10 * sv.max()
    return U[:, keep] * sv[keep]


def _finish(CC: np.ndarray, logdet: np.ndarray) -> np.ndarray:
    """Restricted -log L (B,) from Z^T C^-1 Z (B, c, c), Z = [r, J], and log det C (B,):
    0.5 (r' Pi r + log det C + log det J' C^-1 J), Pi the GLS residual maker."""
    value = CC[:, 0, 0] + logdet
    if CC.shape[1] > 1:
        A, b = CC[:, 1:, 1:], CC[:, 1:, 0]
        value = value - np.einsum("bi,bi->b", b, np.linalg.solve(A, b[..., None])[..., 0])
        value = value + np.linalg.slogdet(A)[1]
    return 0.5 * value


class _Restricted:
    """The restricted -log L of standardised window residuals r ~ N(0, C) (with the Jacobian
    ``J`` of the estimated directions: each candidate refits them by GLS and pays log det of
    their information) for batches of candidate wander models.

    For a batch with the same state axes, C = I + H K H^T with K the axes' Gauss-Markov
    covariance (block-diagonal over axes, each a chain): its precision K^-1 is tridiagonal per
    axis, so A = K^-1 + H^T H is banded (upper band n in window-major order). log det C =
    log det A + log det K, Z^T C^-1 Z = Z^T Z - (H^T Z)^T A^-1 (H^T Z). One LAPACK pbtrf and one
    tbtrs do a whole batch: the candidates' A are stacked along the band (decoupled blocks)."""

    def __init__(
        self,
        r_std: np.ndarray,
        sigma: np.ndarray,
        sens: WanderSensitivity,
        chain: _Chain,
        J: np.ndarray | None,
    ) -> None:
        Z = r_std[:, None] if J is None else np.column_stack([r_std, J])
        self.sens, self.sigma, self.chain = sens, sigma, chain
        self.Z = chain.pad(Z)  # (M, q, c)
        self.ZZ = Z.T @ Z
        self._moments: dict[tuple[tuple[str, int], ...], tuple[np.ndarray, np.ndarray]] = {}

    def moments(self, axes: tuple[tuple[str, int], ...]) -> tuple[np.ndarray, np.ndarray]:
        """(M, n, n) H_m^T H_m and (M n, c) H^T Z for these state axes (cached)."""
        if axes not in self._moments:
            H = _observation(self.sens, self.sigma, self.chain, axes)
            HtH = np.einsum("mqa,mqb->mab", H, H)
            U = np.einsum("mqa,mqc->mac", H, self.Z).reshape(-1, self.Z.shape[2])
            self._moments[axes] = (HtH, U)
        return self._moments[axes]

    def model(self, model: Mapping[str, TriadWander]) -> float:
        """-log L (restricted) of one model."""
        axes, sig, tau = _state(model, self.sens)
        return float(self.batch(tuple(axes), sig[None], tau[None])[0])

    def candidates(
        self,
        fixed: Mapping[str, TriadWander],
        free: str,
        sigma: np.ndarray,
        tau: np.ndarray,
    ) -> np.ndarray:
        """-log L (B,) of ``fixed`` plus triad ``free`` at isotropic sigma (B,) and tau (B,)."""
        axes, sig, tf = _state({k: v for k, v in fixed.items() if k != free}, self.sens)
        B = len(sigma)
        axes = (*axes, (free, 0), (free, 1), (free, 2))
        sig_b = np.column_stack([np.tile(sig, (B, 1)), np.repeat(sigma[:, None], 3, axis=1)])
        tau_b = np.column_stack([np.tile(tf, (B, 1)), np.repeat(tau[:, None], 3, axis=1)])
        return self.batch(axes, sig_b, tau_b)

    def batch(self, axes: tuple[tuple[str, int], ...], sig: np.ndarray, tau: np.ndarray):
        """-log L (B,) of B models on the same state axes: sigma (B, n), tau_s (B, n)."""
        B, n = sig.shape
        if n == 0:
            return np.repeat(_finish(self.ZZ[None], np.zeros(1)), B)
        HtH, U = self.moments(axes)
        M, c = self.chain.M, self.ZZ.shape[0]
        size = max(1, _BATCH_NUMBERS // (M * n * c))
        CC = np.empty((B, c, c))
        logdet = np.empty(B)
        for lo in range(0, B, size):  # chunks bound the memory, each chunk is one LAPACK call
            sl = slice(lo, min(B, lo + size))
            CC[sl], logdet[sl] = self._chunk(HtH, U, sig[sl], tau[sl])
        return _finish(CC, logdet)

    def _chunk(self, HtH, U, sig, tau) -> tuple[np.ndarray, np.ndarray]:
        from scipy.linalg.lapack import dpbtrf, dtbtrs

        B, n = sig.shape
        M, c = self.chain.M, U.shape[1]
        phi = _phi(self.chain.gap, tau)  # (B, M, n): phi[m] links window m - 1 to m
        v = (sig * sig)[:, None, :] * np.maximum(1.0 - phi * phi, _MIN_INNOVATION)
        ahead = np.zeros_like(v)  # the next transition's pull on this window's state
        ahead[:, :-1] = phi[:, 1:] ** 2 / v[:, 1:]
        ab = np.zeros((n + 1, B, M, n))  # lower band storage: ab[i - j, j] = A[i, j]
        ab[0] = 1.0 / v + ahead + np.einsum("maa->ma", HtH)[None]
        for d in range(1, n):
            ab[d, :, :, : n - d] = np.diagonal(HtH, offset=-d, axis1=1, axis2=2)[None]
        ab[n, :, : M - 1, :] = -phi[:, 1:] / v[:, 1:]
        logdet_k = np.log(v).sum(axis=(1, 2))
        L, info = dpbtrf(ab.reshape(n + 1, B * M * n), lower=1)
        if info != 0:  # rounding broke positive definiteness in some block: each on its own
            if B == 1:
                return np.full((1, c, c), np.nan), np.full(1, np.inf)
            parts = [self._chunk(HtH, U, sig[i : i + 1], tau[i : i + 1]) for i in range(B)]
            return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
        logdet_a = 2.0 * np.log(L[0].reshape(B, M * n)).sum(axis=1)
        rhs = np.tile(U.T, (1, B))  # (c, B M n): its transpose is the Fortran right-hand side
        Y, info = dtbtrs(L, rhs.T, uplo="L")
        Y = Y.T.reshape(c, B, M * n).transpose(1, 0, 2)  # (B, c, M n)
        CC = self.ZZ[None] - np.matmul(Y, Y.transpose(0, 2, 1))
        return CC, logdet_a + logdet_k


# ---- the searches: vectorised over independent one-dimensional problems ---------------------
def _brent_min(
    f: Callable[[np.ndarray, np.ndarray], np.ndarray],
    lo: np.ndarray,
    hi: np.ndarray,
    tol: float = _LOG_SIGMA_TOL,
    max_iter: int = 200,
) -> tuple[np.ndarray, np.ndarray]:
    """Minimise N unimodal functions on [lo_i, hi_i] at once by Brent's method (a parabola
    through the three best points where it is trusted, a golden-section step where not): about
    a dozen evaluations each for a smooth profile, where plain golden section takes 30.
    ``f(i, x)``: the values of functions ``i`` (an index array) at ``x``. Returns (x, f(x))."""
    a, b = np.array(lo, float), np.array(hi, float)
    N = len(a)
    x = a + _GOLD * (b - a)
    w, v = x.copy(), x.copy()
    fx = np.asarray(f(np.arange(N), x), float)
    fw, fv = fx.copy(), fx.copy()
    d, e = np.zeros(N), np.zeros(N)
    active = np.ones(N, bool)
    for _ in range(max_iter):
        xm = 0.5 * (a + b)
        tol1 = 1.5e-8 * np.abs(x) + tol / 3.0
        tol2 = 2.0 * tol1
        active &= np.abs(x - xm) > tol2 - 0.5 * (b - a)
        if not active.any():
            break
        r = (x - w) * (fx - fv)
        qq = (x - v) * (fx - fw)
        p = (x - v) * qq - (x - w) * r
        qq = 2.0 * (qq - r)
        p = np.where(qq > 0, -p, p)
        qq = np.abs(qq)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = p / qq
        trusted = (
            (np.abs(e) > tol1)
            & (np.abs(p) < np.abs(0.5 * qq * e))
            & (p > qq * (a - x))
            & (p < qq * (b - x))
        )
        e_gold = np.where(x >= xm, a - x, b - x)
        u_para = x + step
        near_end = (u_para - a < tol2) | (b - u_para < tol2)
        step = np.where(near_end, np.copysign(tol1, xm - x), step)
        e_new = np.where(trusted, d, e_gold)
        d_new = np.where(trusted, step, _GOLD * e_gold)
        e = np.where(active, e_new, e)
        d = np.where(active, d_new, d)
        u = x + np.where(np.abs(d) >= tol1, d, np.copysign(tol1, d))
        idx = np.flatnonzero(active)
        fu = fx.copy()
        fu[idx] = f(idx, u[idx])
        better = active & (fu <= fx)
        worse = active & ~better
        # bracket
        a = np.where(better & (u >= x), x, np.where(worse & (u < x), u, a))
        b = np.where(better & (u < x), x, np.where(worse & (u >= x), u, b))
        # the three best points
        shift_w = worse & ((fu <= fw) | (w == x))
        shift_v = worse & ~shift_w & ((fu <= fv) | (v == x) | (v == w))
        v_new = np.where(better | shift_w, w, np.where(shift_v, u, v))
        fv_new = np.where(better | shift_w, fw, np.where(shift_v, fu, fv))
        w_new = np.where(better, x, np.where(shift_w, u, w))
        fw_new = np.where(better, fx, np.where(shift_w, fu, fw))
        x = np.where(better, u, x)
        fx = np.where(better, fu, fx)
        v, fv, w, fw = v_new, fv_new, w_new, fw_new
    return x, fx


def _rise(
    f: Callable[[np.ndarray], np.ndarray],
    x0: float,
    f0: float,
    deltas: np.ndarray,
    span: float = math.log(1e3),
    tol: float = 1e-9,
    max_iter: int = 100,
) -> np.ndarray:
    """For each delta, the x in (x0, x0 + span] where 2 (f(x) - f0) reaches delta (f rising
    from its minimum f0 at x0; x0 + span where it does not get there). ``f(x)``: values at an
    array of points. Solved on h(x) = sqrt(2 (f(x) - f0)) - sqrt(delta), nearly linear where f
    is nearly quadratic about its minimum, by false position with the Illinois correction (an
    end kept twice in a row has its value halved) and a bisection when the bracket stops
    halving: a handful of evaluations where bisection took 40."""
    root = np.sqrt(np.asarray(deltas, float))
    K = len(root)

    def h(x: np.ndarray, which: np.ndarray) -> np.ndarray:
        return np.sqrt(np.maximum(2.0 * (np.asarray(f(x), float) - f0), 0.0)) - root[which]

    lo, hi = np.full(K, float(x0)), np.full(K, float(x0) + span)
    h_lo = -root
    h_hi = h(hi[:1], np.arange(K)) if K else np.zeros(0)  # the same point for every delta
    out = hi.copy()
    active = h_hi >= 0
    last = np.zeros(K, int)  # the end the last step moved: +1 the upper, -1 the lower
    width = hi - lo
    for it in range(max_iter):
        active &= (hi - lo) > tol * max(1.0, abs(x0))
        if not active.any():
            break
        with np.errstate(divide="ignore", invalid="ignore"):
            fp = hi - h_hi * (hi - lo) / (h_hi - h_lo)
        mid = 0.5 * (lo + hi)
        slow = (it % 4 == 3) & ((hi - lo) > 0.5 * width)  # not halved in 4 steps: bisect
        x = np.where(slow | ~np.isfinite(fp) | (fp <= lo) | (fp >= hi), mid, fp)
        if it % 4 == 3:
            width = hi - lo
        idx = np.flatnonzero(active)
        hx = np.zeros(K)
        hx[idx] = h(x[idx], idx)
        up, down = active & (hx >= 0), active & (hx < 0)
        h_lo = np.where(up & (last == 1), 0.5 * h_lo, h_lo)
        h_hi = np.where(down & (last == -1), 0.5 * h_hi, h_hi)
        last = np.where(up, 1, np.where(down, -1, last))
        hi, h_hi = np.where(up, x, hi), np.where(up, hx, h_hi)
        lo, h_lo = np.where(down, x, lo), np.where(down, hx, h_lo)
        done = active & (np.abs(hx) < 1e-12 * (1.0 + root))  # on the root itself
        out = np.where(active, np.where(done, x, hi), out)
        active &= ~done
    return out


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


def estimate_wander(
    r_std: np.ndarray,
    sigma: np.ndarray,
    sensitivity: Any,
    t: np.ndarray | None,
    taus: Sequence[float] = TAU_GRID_S,
    jacobian: np.ndarray | None = None,
    sessions: np.ndarray | None = None,
    refine_tau: bool = True,
) -> tuple[WanderModel, list[WanderFit]]:
    """Each triad's wander from standardised window residuals ``r_std`` (R,) (raw / sigma at a
    fit), by maximum likelihood of r_std ~ N(0, I + D^-1 Sigma_w D^-1): isotropic sigma per
    triad, tau on ``taus`` (only 0 without times), one triad at a time with the others' found
    wander kept. Kept when 2 x the log-likelihood gain exceeds :data:`WANDER_SIGNIFICANCE`.

    ``sensitivity``: a :class:`WanderSensitivity` (or the dense sensor -> (R, M, 3) form).
    ``jacobian`` (R, k): the standardised residuals' Jacobian along the k estimated directions.
    The fit absorbed what of the wander looks like a coefficient (a wander slower than the
    windows' span is a bias), so a plain likelihood of its residuals finds the wander too fast
    and too small (measured: 94 % of the coefficients within 3 sigma instead of 99 %). With the
    Jacobian the likelihood is the restricted one (REML): each candidate covariance refits the
    coefficients (generalised least squares, linearised) and pays log det of their information.

    The correlation time carried is the longest whose profile 2 ln L lies within
    :data:`TAU_CONSERVATIVE` of the best: on the grid ``taus``, then (``refine_tau``, the
    default) between the picked grid point and the next one up, to :data:`_LOG_TAU_TOL`
    (:func:`_band_edge`). Tens of windows pin tau poorly and the band spans grid points, but at
    thousands of windows the profile is sharp and the grid's factor 2 left the carried tau up to
    half the truth, and the bias's 1-sigma with it (benchmarks/bench_wander_scale.py, 2000
    windows, tau 6 h: the gyro's carried at 4 h in 38 of 40 sessions, 98.8 % of scale and bias
    within 3 sigma). ``refine_tau=False`` is the grid alone (as before issue 35).

    The likelihood is computed on the windows' chain (module docstring): per triad, sigma is
    found for all correlation times at once by Brent's method on log sigma (over 7 decades
    around the residuals' scale, to :data:`_LOG_SIGMA_TOL`), each step one banded factorisation
    of the batch; time and memory linear in the windows (5000 windows, both triads: seconds).
    """
    sens = as_sensitivity(sensitivity)
    r_std, sigma = np.asarray(r_std, float), np.asarray(sigma, float)
    chain = _chain(sens, t, sessions)
    ev = _Restricted(r_std, sigma, sens, chain, _directions(jacobian))
    grid = np.array(list(taus) if t is not None else [0.0], float)
    found: dict[str, TriadWander] = {}
    fits: list[WanderFit] = []
    # two rounds over the triads: each fitted with the others' wander as last found (the
    # second only when the first found some: otherwise it would repeat the first exactly)
    for round_ in range(2 if len(sens.sensors) > 1 else 1):
        if round_ and not found:
            break
        fits = []
        for s in sens.sensors:
            d = np.sum(sens.rows[s] ** 2, axis=1)  # the unit covariance's diagonal
            if not (d > 0).any() or not grid.size:
                continue
            others = {k: v for k, v in found.items() if k != s}
            n0 = ev.model(others)
            scale = math.sqrt(float(np.mean(sigma[d > 0] ** 2)) / float(np.mean(d[d > 0])))
            # log sigma over 7 decades around the residuals' scale, every tau at once

            def f(i: np.ndarray, x: np.ndarray, s: str = s, others: dict = others) -> np.ndarray:
                return ev.candidates(others, s, np.exp(x), grid[i])

            lo, hi = math.log(scale * 1e-4), math.log(scale * 1e3)
            ls, nll = _brent_min(f, np.full(grid.size, lo), np.full(grid.size, hi))
            profile = [(float(nll[i]), math.exp(ls[i]), float(grid[i])) for i in range(grid.size)]
            best = min(profile, key=lambda p: p[0])
            if best[0] > n0:  # no wander fits better than the smallest tried: none
                best = (n0, 0.0, 0.0)
                profile = [best]
            # the correlation time is poorly pinned by tens of windows, and a too short one
            # understates what the wander shares with the bias: take the longest within the
            # likelihood's 1-sigma-like interval (2 ln L within TAU_CONSERVATIVE of its best)
            near = [p for p in profile if 2.0 * (p[0] - best[0]) <= TAU_CONSERVATIVE]
            pick = max(near, key=lambda p: p[2])
            above = [p for p in profile if p[2] > pick[2]]
            if refine_tau and pick[2] > 0 and pick[1] > 0 and above:
                # ... and between the grid's points: where the profile is sharp (thousands of
                # windows) the grid's factor 2 left tau up to half the truth
                nxt = min(above, key=lambda p: p[2])

                def profile_at(tau: float, s=s, others=others, lo=lo, hi=hi) -> tuple:
                    def f(i, x):
                        return ev.candidates(others, s, np.exp(x), np.full(len(x), tau))

                    x, v = _brent_min(f, np.array([lo]), np.array([hi]))
                    return (float(v[0]), math.exp(x[0]), tau)

                pick = _band_edge(profile_at, pick, nxt, best[0])
            gain = 2.0 * (n0 - best[0])
            keep = gain > WANDER_SIGNIFICANCE
            upper = carried = 0.0
            if pick[1] > 0:  # one-sided bounds on sigma at the picked tau, both at once

                def g(x: np.ndarray, s: str = s, others: dict = others, tau=pick[2]):
                    return ev.candidates(others, s, np.exp(x), np.full(len(x), tau))

                deltas = np.array([SIGMA_UPPER_DELTA, SIGMA_CARRIED_DELTA])
                upper, carried = np.exp(_rise(g, math.log(pick[1]), pick[0], deltas))
            fits.append(
                WanderFit(s, pick[1], pick[2], gain, keep, best[1], best[2],
                          sigma_upper=float(upper), sigma_carried=float(carried))
            )  # fmt: skip
            if keep:
                found[s] = TriadWander(np.full(3, carried), np.full(3, pick[2]))
            else:
                found.pop(s, None)
    fits = _joint_test(fits, found, ev)
    notes = () if t is not None else ("no start_s/end_s: windows taken as independent",)
    return WanderModel(found, "estimated from the residuals", notes), fits


def _band_edge(
    profile_at: Callable[[float], tuple[float, float, float]],
    inside: tuple,
    outside: tuple,
    best: float,
    max_steps: int = 30,
) -> tuple:
    """The longest tau between two profile points, ``inside`` (2 (value - best) within
    TAU_CONSERVATIVE) and ``outside`` (beyond it; each (value, sigma, tau, ...)), whose profile
    stays within: false position on log tau with the Illinois correction, to
    :data:`_LOG_TAU_TOL`. ``profile_at(tau)`` -> (value, sigma, tau). Returns the last point
    found within the band (``inside`` if none further)."""

    def h(p: tuple) -> float:
        return 2.0 * (p[0] - best) - TAU_CONSERVATIVE

    lo, hi = inside[:3], outside[:3]
    x_lo, x_hi = math.log(lo[2]), math.log(hi[2])
    h_lo, h_hi = h(lo), h(hi)
    last = 0
    for _ in range(max_steps):
        if x_hi - x_lo < _LOG_TAU_TOL:
            break
        x = x_hi - h_hi * (x_hi - x_lo) / (h_hi - h_lo) if h_hi != h_lo else 0.5 * (x_lo + x_hi)
        if not x_lo < x < x_hi:
            x = 0.5 * (x_lo + x_hi)
        # keep the step off the ends: false position creeps along a curved profile
        x = min(max(x, x_lo + 0.1 * _LOG_TAU_TOL), x_hi - 0.1 * _LOG_TAU_TOL)
        p = profile_at(math.exp(x))
        if h(p) <= 0:
            lo, x_lo = p, x
            h_hi = 0.5 * h_hi if last == -1 else h_hi
            h_lo, last = h(p), -1
        else:
            hi, x_hi = p, x
            h_lo = 0.5 * h_lo if last == 1 else h_lo
            h_hi, last = h(p), 1
    return lo


def _joint_test(
    fits: list[WanderFit], found: dict[str, TriadWander], ev: _Restricted
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
    trial = dict(found)
    for f in pending:
        trial[f.sensor] = TriadWander(np.full(3, f.sigma_ml), np.full(3, f.tau_ml_s))
    gain = 2.0 * (ev.model(found) - ev.model(trial))
    if gain <= float(chi2_dist.ppf(0.99, 3 * len(pending))):
        return fits
    out = []
    for f in fits:
        if f in pending:
            f = replace(f, significant=True, joint_gain=gain)
            found[f.sensor] = TriadWander(np.full(3, f.sigma_carried), np.full(3, f.tau_s))
        out.append(f)
    return out


def wander_gain(
    r_std: np.ndarray,
    sigma: np.ndarray,
    sensitivity: Any,
    t: np.ndarray | None,
    model: WanderModel,
    jacobian: np.ndarray | None = None,
    sessions: np.ndarray | None = None,
) -> float:
    """2 x (restricted -log L with no wander - with ``model``): the likelihood-ratio statistic
    of a given wander model on a fit's standardised window residuals ``r_std`` (R,) (raw /
    ``sigma``), ``jacobian`` (R, k) the standardised residuals' Jacobian along the estimated
    directions (None: the plain likelihood). The statistic :func:`estimate_wander` tests,
    exact, computed through the model's Kalman innovations (:class:`Whitening`): linear in the
    windows, any correlation time (0, finite or infinite)."""
    sens = as_sensitivity(sensitivity)
    r_std = np.asarray(r_std, float)
    J = _directions(jacobian)
    Z = r_std[:, None] if J is None else np.column_stack([r_std, J])
    W = Whitening(sigma, sens, t, model, sessions)
    Wz = W.apply(Z.T)  # (c, R)
    with_model = _finish((Wz @ Wz.T)[None], np.array([W.logdet]))[0]
    without = _finish((Z.T @ Z)[None], np.zeros(1))[0]
    return float(2.0 * (without - with_model))


# ---- dense references (small problems and tests) --------------------------------------------
def correlation(t: np.ndarray, tau_s: float) -> np.ndarray:
    """(M, M) exp(-|t_i - t_j| / tau); tau 0: the identity, inf: all ones (dense: tests)."""
    if tau_s == 0.0:
        return np.eye(len(t))
    if math.isinf(tau_s):
        return np.ones((len(t), len(t)))
    return np.exp(-np.abs(t[:, None] - t[None, :]) / tau_s)


def wander_covariance(
    sensitivity: Any,
    t: np.ndarray | None,
    model: WanderModel,
    sessions: np.ndarray | None = None,
) -> np.ndarray:
    """(R, R) covariance the wander adds to the window residuals, dense: R^2 memory, the
    reference :class:`Whitening` and :func:`estimate_wander` are checked against on small
    problems (the calibration never builds it).

    ``sensitivity``: a :class:`WanderSensitivity` or sensor -> (R, M, 3); ``t``: (M,) mid-times,
    s, or None (independent windows); ``sessions``: (M,) session of each window (None: one),
    windows of different sessions independent."""
    sens = as_sensitivity(sensitivity)
    R, M = sens.n_residuals, sens.n_windows
    out = np.zeros((R, R))
    same = np.ones((M, M)) if sessions is None else sessions[:, None] == sessions[None, :]
    for s, g in sens.rows.items():
        tw = model.triads.get(s)
        if tw is None:
            continue
        for a in range(3):  # 3 axes; each term is one (R, R) outer product through the windows
            if tw.sigma[a] == 0:
                continue
            rho = correlation(t, float(tw.tau_s[a])) if t is not None else np.eye(M)
            rho = (rho * same)[np.ix_(sens.window, sens.window)]
            out += tw.sigma[a] ** 2 * (g[:, a, None] * rho * g[None, :, a])
    return out


def whitener(sigma: np.ndarray, cov_wander: np.ndarray) -> np.ndarray:
    """W (R, R) such that W r_std has unit covariance, r_std = r / sigma: the inverse Cholesky
    factor of I + diag(1/sigma) Sigma_w diag(1/sigma) (dense: tests and small problems)."""
    C = np.eye(len(sigma)) + cov_wander / np.outer(sigma, sigma)
    try:
        L = np.linalg.cholesky(C)
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(C)
        C = (V * np.maximum(w, _JITTER)) @ V.T
        L = np.linalg.cholesky(C)
    return np.linalg.solve(L, np.eye(len(sigma)))


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
