"""The estimate of bias wander (:mod:`recal.solve.wander`): the correlation times it searches
(:func:`tau_floor_s`, :func:`correlation_times`), its significance and the bounds carried, and
:func:`estimate_wander`: restricted maximum likelihood of each triad's sigma over the grid of
correlation times (vectorised Brent searches), the likelihood-ratio test against no wander, the
conservative correlation time and the joint test of the triads no single test kept."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from recal.solve.wander_chain import as_sensitivity, window_chain
from recal.solve.wander_likelihood import RestrictedLikelihood, reml_directions
from recal.solve.wander_model import TriadWander, WanderModel

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


#: Golden-section fraction, Brent's search.
_GOLD = (3.0 - math.sqrt(5.0)) / 2.0
#: The profile's resolution in log sigma (the search's final bracket is a few times this).
_LOG_SIGMA_TOL = 1e-6
#: The carried correlation time's resolution between grid points, in log tau (0.5 %).
_LOG_TAU_TOL = 5e-3


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
    chain = window_chain(sens, t, sessions)
    ev = RestrictedLikelihood(r_std, sigma, sens, chain, reml_directions(jacobian))
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
    fits: list[WanderFit], found: dict[str, TriadWander], ev: RestrictedLikelihood
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
