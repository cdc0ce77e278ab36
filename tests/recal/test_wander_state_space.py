"""The wander in state-space form (issue 35, item 6): the Kalman whitening, the banded restricted
likelihood, the estimate and the likelihood-ratio statistic agree with the dense R x R formulas
they replace on small problems, and nothing is skipped past a size."""

from __future__ import annotations

import math

import numpy as np
import pytest

from recal.model.coefficients import CoefficientSet
from recal.sim.simulate import NoiseSpec, simulate_positions
from recal.solve.calibrate import calibrate
from recal.solve.observability import jacobian
from recal.solve.options import CalibrationOptions
from recal.solve.wander_chain import WanderSensitivity
from recal.solve.wander_covariance import Whitening, wander_covariance
from recal.solve.wander_estimate import (
    SIGMA_CARRIED_DELTA,
    SIGMA_UPPER_DELTA,
    TAU_CONSERVATIVE,
    WANDER_SIGNIFICANCE,
    correlation_times,
    estimate_wander,
)
from recal.solve.wander_likelihood import wander_gain
from recal.solve.wander_model import TriadWander, WanderModel, window_times

TRUTH = CoefficientSet.seed_truth()


def _random_problem(seed: int, M: int = 45):
    """Two sessions (the second restarts the clock), accelerometer-only windows (no gyro norm
    nor dot product there), residuals of both triads: a compact sensitivity and its times."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(300.0, 3000.0, M))
    sessions = np.where(np.arange(M) < 2 * M // 3, 0.0, 1.0)
    t[sessions == 1] -= t[sessions == 1][0] - 100.0
    gyro_windows = np.flatnonzero(rng.uniform(size=M) > 0.15)
    ng = len(gyro_windows)
    window = np.concatenate([gyro_windows, np.arange(M), gyro_windows])
    R = len(window)
    rows = {"gyro": np.zeros((R, 3)), "accel": np.zeros((R, 3))}
    rows["gyro"][:ng] = rng.normal(size=(ng, 3))
    rows["accel"][ng : ng + M] = 1e-2 * rng.normal(size=(M, 3))
    rows["gyro"][ng + M :] = 0.3 * rng.normal(size=(ng, 3))
    rows["accel"][ng + M :] = 1e-2 * rng.normal(size=(ng, 3))
    sigma = rng.uniform(0.5, 2.0, R)
    return WanderSensitivity(window, rows, M), t, sessions, sigma, rng


MODELS = {
    "both, finite": WanderModel(
        {
            "gyro": TriadWander(np.array([1.0, 0.5, 2.0]), np.array([3600.0, 7200.0, 1e4])),
            "accel": TriadWander(np.array([30.0, 0.0, 10.0]), np.array([100.0, 5000.0, 9e4])),
        }
    ),  # fmt: skip
    "tau 0 and infinite": WanderModel(
        {
            "gyro": TriadWander(np.array([1.0, 0.5, 2.0]), np.array([0.0, 7200.0, np.inf])),
            "accel": TriadWander(np.full(3, 20.0), np.full(3, np.inf)),
        }
    ),  # fmt: skip
    "gyro only": WanderModel({"gyro": TriadWander(np.full(3, 1.5), np.full(3, 14400.0))}),
    "none": WanderModel({}),
}


def _dense_C(sens, t, sessions, sigma, model) -> np.ndarray:
    cov = wander_covariance(sens, t, model, sessions)
    return np.eye(len(sigma)) + cov / np.outer(sigma, sigma)


def _dense_nll(r, J, C) -> float:
    """The restricted -log L of r ~ N(0, C) with the GLS refit along J (the formula the dense
    estimate used)."""
    L = np.linalg.cholesky(C)
    z = np.linalg.solve(L, r)
    value = float(z @ z) + 2.0 * float(np.sum(np.log(np.diag(L))))
    if J is None:
        return 0.5 * value
    Jw = np.linalg.solve(L, J)
    A, b = Jw.T @ Jw, Jw.T @ z
    return 0.5 * (value - float(b @ np.linalg.solve(A, b)) + np.linalg.slogdet(A)[1])


@pytest.mark.parametrize("name", list(MODELS))
def test_the_kalman_whitening_is_the_dense_one(name: str) -> None:
    """W^T W = C^-1 and log det C, with two sessions, tau 0, finite and infinite, an axis
    without wander and windows that have no gyro residuals."""
    sens, t, sessions, sigma, rng = _random_problem(1)
    C = _dense_C(sens, t, sessions, sigma, MODELS[name])
    z = rng.normal(size=(6, sens.n_residuals))
    W = Whitening(sigma, sens, t, MODELS[name], sessions)
    w = W.apply(z)
    assert w.shape == z.shape
    np.testing.assert_allclose(w @ w.T, z @ np.linalg.solve(C, z.T), rtol=1e-10, atol=1e-10)
    assert W.logdet == pytest.approx(np.linalg.slogdet(C)[1], rel=1e-10, abs=1e-10)
    # without times the windows are independent: a per-window inflation
    C0 = _dense_C(sens, None, sessions, sigma, MODELS[name])
    w0 = Whitening(sigma, sens, None, MODELS[name], sessions).apply(z)
    np.testing.assert_allclose(w0 @ w0.T, z @ np.linalg.solve(C0, z.T), rtol=1e-10, atol=1e-10)


def test_the_banded_restricted_likelihood_is_the_dense_one() -> None:
    """The banded precision's -log L (the estimate's) and the innovations' (wander_gain's)
    against the dense formula: 1e-8 relative, with and without the Jacobian."""
    from recal.solve.wander_chain import window_chain
    from recal.solve.wander_likelihood import RestrictedLikelihood, reml_directions

    sens, t, sessions, sigma, rng = _random_problem(2)
    r = rng.normal(size=sens.n_residuals)
    J = rng.normal(size=(sens.n_residuals, 7))
    for jac in (None, J):
        Jd = reml_directions(jac)
        ev = RestrictedLikelihood(r, sigma, sens, window_chain(sens, t, sessions), Jd)
        base = _dense_nll(r, Jd, np.eye(len(r)))
        for name in ("both, finite", "gyro only", "none"):
            dense = _dense_nll(r, Jd, _dense_C(sens, t, sessions, sigma, MODELS[name]))
            assert ev.model(MODELS[name].triads) == pytest.approx(dense, rel=1e-8)
        for name in ("both, finite", "tau 0 and infinite", "gyro only"):
            dense = _dense_nll(r, Jd, _dense_C(sens, t, sessions, sigma, MODELS[name]))
            gain = wander_gain(r, sigma, sens, t, MODELS[name], jacobian=jac, sessions=sessions)
            assert gain == pytest.approx(2.0 * (base - dense), rel=1e-8, abs=1e-9)
    # a batch of candidates is the candidates one by one
    ev = RestrictedLikelihood(r, sigma, sens, window_chain(sens, t, sessions), reml_directions(J))
    fixed = {"accel": MODELS["both, finite"].triads["accel"]}
    sig, tau = np.array([0.3, 1.0, 3.0, 1.0]), np.array([900.0, 3600.0, 0.0, 5e4])
    batch = ev.candidates(fixed, "gyro", sig, tau)
    for k in range(4):
        model = WanderModel({**fixed, "gyro": TriadWander(np.full(3, sig[k]), np.full(3, tau[k]))})
        dense = _dense_nll(r, reml_directions(J), _dense_C(sens, t, sessions, sigma, model))
        assert batch[k] == pytest.approx(dense, rel=1e-8)


def test_the_compact_sensitivity_round_trips() -> None:
    sens, *_ = _random_problem(3, M=12)
    back = WanderSensitivity.from_dense(sens.dense())
    np.testing.assert_array_equal(back.window[np.any(sens.rows["gyro"] != 0, axis=1)],
                                  sens.window[np.any(sens.rows["gyro"] != 0, axis=1)])  # fmt: skip
    for s in sens.sensors:
        np.testing.assert_array_equal(back.rows[s], sens.rows[s])


# ---- the estimate against the dense one (the algorithm before issue 35) ---------------------
def _golden_min(f, lo: float, hi: float, steps: int = 30) -> float:
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


def _bound(f, sigma: float, delta: float) -> float:
    if sigma <= 0:
        return 0.0
    f0 = f(sigma)
    lo, hi = math.log(sigma), math.log(sigma) + math.log(1e3)
    if 2.0 * (f(math.exp(hi)) - f0) < delta:
        return math.exp(hi)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if 2.0 * (f(math.exp(mid)) - f0) < delta else (lo, mid)
    return math.exp(hi)


def _dense_estimate(r, sigma, sens, t, taus, J, sessions):
    """The dense estimate: per triad and tau a golden-section search of log sigma (7 decades),
    the longest tau within TAU_CONSERVATIVE, bounds by bisection, two rounds, the joint test."""
    from scipy.stats import chi2

    from recal.solve.wander_likelihood import reml_directions

    Jd = reml_directions(J)

    def nll(model: dict) -> float:
        return _dense_nll(r, Jd, _dense_C(sens, t, sessions, sigma, WanderModel(model)))

    found: dict = {}
    fits: list = []
    for round_ in range(2):
        if round_ and not found:
            break
        fits = []
        for s in sens.sensors:
            others = {k: v for k, v in found.items() if k != s}
            n0 = nll(others)
            d = np.sum(sens.rows[s] ** 2, axis=1)
            scale = math.sqrt(float(np.mean(sigma[d > 0] ** 2)) / float(np.mean(d[d > 0])))
            profile = []
            for tau in taus:

                def f(sg, tau=tau, s=s, others=others):
                    return nll({**others, s: TriadWander(np.full(3, sg), np.full(3, tau))})

                ls = _golden_min(lambda x, f=f: f(math.exp(x)), math.log(scale * 1e-4),
                                 math.log(scale * 1e3))  # fmt: skip
                profile.append((f(math.exp(ls)), math.exp(ls), tau, f))
            best = min(profile, key=lambda p: p[0])
            if best[0] > n0:
                best = (n0, 0.0, 0.0, None)
                profile = [best]
            pick = max((p for p in profile if 2 * (p[0] - best[0]) <= TAU_CONSERVATIVE),
                       key=lambda p: p[2])  # fmt: skip
            gain = 2.0 * (n0 - best[0])
            f = pick[3] or (lambda sg: 0.0)
            up, car = _bound(f, pick[1], SIGMA_UPPER_DELTA), _bound(f, pick[1], SIGMA_CARRIED_DELTA)
            fits.append(dict(sensor=s, sigma=pick[1], tau_s=pick[2], gain=gain,
                             significant=gain > WANDER_SIGNIFICANCE, sigma_ml=best[1],
                             tau_ml_s=best[2], sigma_upper=up, sigma_carried=car))  # fmt: skip
            if gain > WANDER_SIGNIFICANCE:
                found[s] = TriadWander(np.full(3, car), np.full(3, pick[2]))
            else:
                found.pop(s, None)
    pending = [f for f in fits if not f["significant"] and f["sigma_ml"] > 0]
    if len(pending) >= 2:
        trial = dict(found)
        for f in pending:
            trial[f["sensor"]] = TriadWander(np.full(3, f["sigma_ml"]), np.full(3, f["tau_ml_s"]))
        joint = 2.0 * (nll(found) - nll(trial))
        if joint > chi2.ppf(0.99, 3 * len(pending)):
            for f in pending:
                f["significant"] = True
    return fits


def _session(seed: int, windows: int, k_gyro: float, k_accel: float, gap_s: float):
    base = NoiseSpec(window_s=600.0, rate_hz=100.0)
    n = 600.0 * 100.0
    noise = NoiseSpec(
        window_s=600.0, slew_s=gap_s - 600.0, rate_hz=100.0, gm_tau_s=4 * 3600.0,
        gm_gyro_dph=k_gyro * base.per_sample_sigma("gyro") / np.sqrt(n),
        gm_accel_ug=k_accel * base.per_sample_sigma("accel") / np.sqrt(n) * 1e6,
    )  # fmt: skip
    return simulate_positions(TRUTH, "random", windows, 45.0, seed=seed, noise=noise)


@pytest.mark.parametrize(
    ("seed", "windows", "k_gyro", "k_accel", "gap_s", "split"),
    [(11, 40, 2.0, 2.0, 720.0, False), (12, 60, 1.0, 0.7, 3600.0, True),
     (13, 32, 0.0, 0.0, 5400.0, False)],
)  # fmt: skip
def test_the_estimate_is_the_dense_one(seed, windows, k_gyro, k_accel, gap_s, split) -> None:
    """On 30-60 windows of a calibration's residuals the state-space estimate finds what the
    dense one finds: the same correlation times and decisions, sigma to the profile's
    resolution, the likelihood gains to 1e-8 (the correlation time on the grid alone, as the
    dense estimate took it)."""
    pos = _session(seed, windows, k_gyro, k_accel, gap_s)
    res = calibrate(pos, CalibrationOptions(latitude_deg=45.0, method="lm"))
    prob, theta = res.problem, res.theta
    raw = prob.raw_residuals(theta[None])
    sigma = prob.window_sigma()
    r = np.concatenate([raw[n][0] for n in prob.window_invariants]) / sigma
    T = prob.layout.typical(theta)[:, None] * res.observability.basis
    J = jacobian(prob, theta, T.T)[: len(r)]
    t = window_times(prob.positions.columns, prob.M)
    sessions = (np.arange(prob.M) >= prob.M // 2).astype(float) if split else None
    taus = correlation_times(t, sessions, float(np.ptp(t)))
    sens = prob.wander_sensitivity(theta)
    _, fits = estimate_wander(
        r, sigma, sens, t, taus=taus, jacobian=J, sessions=sessions, refine_tau=False
    )
    dense = _dense_estimate(r, sigma, sens, t, taus, J, sessions)
    assert [f.sensor for f in fits] == [d["sensor"] for d in dense]
    for f, d in zip(fits, dense, strict=True):
        assert f.tau_s == d["tau_s"] and f.tau_ml_s == d["tau_ml_s"]
        assert f.significant == d["significant"]
        assert f.gain == pytest.approx(d["gain"], rel=1e-8, abs=1e-7)
        for key in ("sigma", "sigma_ml", "sigma_upper", "sigma_carried"):
            assert getattr(f, key) == pytest.approx(d[key], rel=1e-4, abs=1e-12), key


def test_the_carried_tau_is_the_band_edge_between_grid_points() -> None:
    """refine_tau: the carried tau is the longest whose profile (sigma re-fitted, dense) stays
    within TAU_CONSERVATIVE of the best, found between the picked grid point and the next one
    (one triad: one round)."""
    from recal.solve.wander_estimate import _LOG_TAU_TOL
    from recal.solve.wander_likelihood import reml_directions

    pos = _session(12, 60, 1.0, 0.0, 3600.0)
    res = calibrate(pos, CalibrationOptions(latitude_deg=45.0, method="lm"))
    prob, theta = res.problem, res.theta
    raw = prob.raw_residuals(theta[None])
    sigma = prob.window_sigma()
    r = np.concatenate([raw[n][0] for n in prob.window_invariants]) / sigma
    T = prob.layout.typical(theta)[:, None] * res.observability.basis
    J = jacobian(prob, theta, T.T)[: len(r)]
    t = window_times(prob.positions.columns, prob.M)
    taus = correlation_times(t, None, float(np.ptp(t)))
    full = prob.wander_sensitivity(theta)
    sens = WanderSensitivity(full.window, {"gyro": full.rows["gyro"]}, full.n_windows)
    (grid,) = estimate_wander(r, sigma, sens, t, taus=taus, jacobian=J, refine_tau=False)[1]
    (fit,) = estimate_wander(r, sigma, sens, t, taus=taus, jacobian=J)[1]
    Jd = reml_directions(J)

    def profile(tau: float) -> float:  # dense: sigma by golden section
        def f(sg: float) -> float:
            model = WanderModel({"gyro": TriadWander(np.full(3, sg), np.full(3, tau))})
            return _dense_nll(r, Jd, _dense_C(sens, t, None, sigma, model))

        return f(math.exp(_golden_min(lambda x: f(math.exp(x)), math.log(1e-3), math.log(1e2))))

    best = profile(grid.tau_ml_s)
    nxt = min(tau for tau in taus if tau > grid.tau_s)
    assert grid.tau_s < fit.tau_s < nxt  # moved off the grid, not past the next point
    assert 2.0 * (profile(fit.tau_s) - best) <= TAU_CONSERVATIVE + 1e-6
    assert 2.0 * (profile(fit.tau_s * math.exp(2 * _LOG_TAU_TOL)) - best) > TAU_CONSERVATIVE
    assert fit.gain == pytest.approx(grid.gain, rel=1e-10) and fit.significant


def test_wander_is_estimated_past_the_old_size_limit() -> None:
    """700 windows (2100 window residuals; the dense estimate stopped at 1500): estimated, kept,
    and the coefficients within 3 sigma."""
    pos = _session(14, 700, 2.0, 2.0, 720.0)
    res = calibrate(pos, CalibrationOptions(latitude_deg=45.0, method="lm", wander="auto"))
    tests = res.noise_model["wander_test"]
    assert isinstance(tests, list) and all(t["significant"] for t in tests)
    assert res.problem.window_sigma().size > 1500
    names = res.layout.names
    core = np.array([".scale." in n or ".bias." in n for n in names]) & res.observability.estimated
    z = (res.theta - TRUTH.to_vector(res.layout)) / np.sqrt(np.diag(res.covariance))
    assert np.all(np.abs(z[core]) < 3.0)
    assert 0.7 < res.chi2_red < 1.5
