"""Noise of still IMU data: Allan deviation, a white + Gauss-Markov model, the standard error
of a window mean, and a per-axis summary (docs/engine.md, "Correlated noise"; docs/noise.md).

Four ideas, one section each:

1. **Allan deviation with confidence intervals** (:func:`allan_deviation`): the overlapping
   Allan variance of rate samples, pooled over several still stretches, with the equivalent
   degrees of freedom of Howe, Allan and Barnes (1981) per noise type and chi-square intervals.
2. **The white + Gauss-Markov fit** (:func:`fit_white_gm`): AVAR(T) = q / T + s2 G(T / tau),
   fitted by maximum likelihood (each variance estimate is a scaled chi-square with its degrees
   of freedom), so a near-zero estimate from one difference cannot drag the fit down; the
   Gauss-Markov part is kept only when a likelihood-ratio test at 1 % says so.
3. **The standard error of a window mean** (:func:`standard_errors`,
   :func:`pooled_standard_errors`): never below the white value std / sqrt(n) unless the data
   show negative correlation with confidence; inflated by the fitted model for correlated noise.
4. **A per-axis summary** (:func:`summarize_axis`): angle / velocity random walk, bias
   instability and correlation time.

Pure numpy and scipy.stats; no I/O. Times are in frames unless a name says ``_s``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy import stats

#: chi-square(2) at 0.1 %: the Gauss-Markov part must earn its two parameters. Nominally 0.1 %;
#: the search over correlation times and the correlated Allan levels make it about 1 % on white
#: data (measured: 9.21, the nominal 1 %, kept a Gauss-Markov part on 3-6 % of white axes).
GM_SIGNIFICANCE = 13.82
#: One-sided level of the negative-correlation test of :func:`standard_errors`.
NEGATIVE_CORRELATION_LEVEL = 0.01
#: Correlation times tried per octave of averaging time.
TAU_PER_OCTAVE = 4
#: 1-sigma two-sided confidence of the Allan deviation intervals.
ONE_SIGMA = math.erf(1 / math.sqrt(2))
#: Bias instability = minimum of the Allan deviation / this (IEEE Std 952, flicker floor).
BIAS_INSTABILITY_FACTOR = math.sqrt(2 * math.log(2) / math.pi)
#: Power-law exponents alpha of the rate PSD (f^alpha) the EDF formulas know: white PM
#: (angle quantisation), white FM (white rate noise), flicker FM (bias instability), RW FM.
ALPHAS = (2, 0, -1, -2)


# ---- 1. Allan deviation with confidence intervals ------------------------------------------
def edf_simple(n_phase: np.ndarray | float, m: np.ndarray | float, alpha: int) -> np.ndarray:
    """Equivalent degrees of freedom of an overlapping Allan variance (Howe, Allan, Barnes 1981).

    n_phase: phase (integrated) samples of the stretch, i.e. rate samples + 1; m: averaging
    factor; alpha: the rate PSD exponent (:data:`ALPHAS`). Vectorised; at least 1 where defined,
    0 where 2 m exceeds the rate samples.
    """
    n = np.asarray(n_phase, dtype=float)
    m = np.asarray(m, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        if alpha == 2:
            e = (n + 1) * (n - 2 * m) / (2 * (n - m))
        elif alpha == 0:
            e = (3 * (n - 1) / (2 * m) - 2 * (n - 2) / n) * 4 * m * m / (4 * m * m + 5)
        elif alpha == -1:
            e = np.where(m == 1, 2 * (n - 2) / (2.3 * n - 4.9), 5 * n * n / (4 * m * (n + 3 * m)))
        elif alpha == -2:
            e = (n - 2) / m * ((n - 1) ** 2 - 3 * m * (n - 1) + 4 * m * m) / (n - 3) ** 2
        else:
            raise ValueError(f"alpha must be one of {ALPHAS}, not {alpha}")
    ok = (n - 1 >= 2 * m) & np.isfinite(e)
    return np.where(ok, np.maximum(np.where(ok, e, 1.0), 1.0), 0.0)


def octave_factors(longest: int, per_octave: int = 1) -> np.ndarray:
    """Averaging factors 1, 2, 4, ... (``per_octave`` per octave, distinct integers) up to
    half of ``longest`` rate samples."""
    if longest < 2:
        return np.zeros(0, dtype=np.int64)
    top = math.log2(longest // 2)
    m = np.unique(np.round(2.0 ** (np.arange(int(top * per_octave) + 1) / per_octave)))
    return m[m <= longest // 2].astype(np.int64)


@dataclass(frozen=True)
class AllanCurve:
    """Pooled overlapping Allan variance of still stretches, one column per axis.

    tau_s: averaging times (L,); m: averaging factors (L,); avar: Allan variance (L, k) in
    (input units)^2; terms: differences pooled per level (L,); n_phase: phase samples of each
    stretch (S,), for the degrees of freedom; rate_hz: sample rate.
    """

    tau_s: np.ndarray
    m: np.ndarray
    avar: np.ndarray
    terms: np.ndarray
    n_phase: np.ndarray
    rate_hz: float

    @property
    def adev(self) -> np.ndarray:
        return np.sqrt(self.avar)

    def edf(self, alpha: int | np.ndarray = 0) -> np.ndarray:
        """(L,) degrees of freedom: each stretch's (:func:`edf_simple`) summed, as independent.

        alpha: one exponent, or one per level (as :meth:`WhiteGM.alpha` gives)."""
        alpha = np.broadcast_to(np.asarray(alpha), self.m.shape)
        out = np.zeros(self.m.shape[0])
        for a in np.unique(alpha):
            sel = alpha == a
            out[sel] = edf_simple(self.n_phase[None, :], self.m[sel, None], int(a)).sum(axis=1)
        return out

    def interval(
        self, alpha: int | np.ndarray = 0, confidence: float = ONE_SIGMA
    ) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) Allan deviation bounds, (L, k): chi-square with :meth:`edf` dof."""
        return deviation_interval(self.adev, self.edf(alpha)[:, None], confidence)


def deviation_interval(
    adev: np.ndarray, edf: np.ndarray, confidence: float = ONE_SIGMA
) -> tuple[np.ndarray, np.ndarray]:
    """Two-sided chi-square interval of a deviation estimated with ``edf`` degrees of freedom."""
    edf = np.maximum(np.asarray(edf, dtype=float), 1e-12)
    lo_q = stats.chi2.ppf((1 + confidence) / 2, edf)
    hi_q = stats.chi2.ppf((1 - confidence) / 2, edf)
    return adev * np.sqrt(edf / lo_q), adev * np.sqrt(edf / hi_q)


def allan_deviation(
    segments: Sequence[np.ndarray], rate_hz: float, m: np.ndarray | None = None
) -> AllanCurve:
    """Overlapping Allan variance of rate samples, pooled over still stretches.

    segments: arrays (n_i, k) of rate samples (or (n_i,)), each one contiguous and evenly
    sampled at ``rate_hz``. Per level m, the sum over all stretches of (ybar_(i+m) - ybar_i)^2 / 2
    (m-sample averages, every start i) divided by the number of terms: for one stretch this is
    the textbook overlapping estimator (allantools.oadev on frequency data). m: averaging
    factors, default octaves up to half the longest stretch.
    """
    segs = [np.asarray(s, dtype=float).reshape(np.shape(s)[0], -1) for s in segments]
    segs = [s for s in segs if s.shape[0] >= 2]
    if not segs:
        raise ValueError("no stretch of at least 2 samples")
    k = segs[0].shape[1]
    if m is None:
        m = octave_factors(max(s.shape[0] for s in segs))
    m = np.asarray(m, dtype=np.int64)
    sq = np.zeros((m.shape[0], k))
    terms = np.zeros(m.shape[0])
    for s in segs:
        x = s - s.mean(axis=0)  # a constant offset cancels; this keeps the cumsum small
        c = np.concatenate((np.zeros((1, k)), np.cumsum(x, axis=0)))
        for j, mj in enumerate(m):
            if 2 * mj > s.shape[0]:
                continue
            d = c[2 * mj :] - 2 * c[mj:-mj] + c[: -2 * mj]  # m * (ybar_(i+m) - ybar_i)
            sq[j] += 0.5 * np.einsum("ij,ij->j", d, d) / float(mj * mj)
            terms[j] += d.shape[0]
    keep = terms > 0
    avar = sq[keep] / terms[keep, None]
    n_phase = np.array([s.shape[0] + 1 for s in segs], dtype=float)
    return AllanCurve(m[keep] / rate_hz, m[keep], avar, terms[keep], n_phase, float(rate_hz))


# ---- 2. The white + Gauss-Markov model -------------------------------------------------------
def gm_allan(x: np.ndarray) -> np.ndarray:
    """Allan variance of a unit-variance Gauss-Markov process at averaging time x * tau."""
    x = np.asarray(x, dtype=float)
    r = -np.expm1(-x) / x
    return 2.0 / x * (1.0 - r) - r * r


def gm_mean_var(x: np.ndarray) -> np.ndarray:
    """Variance of the mean of a unit-variance Gauss-Markov process over x * tau."""
    x = np.asarray(x, dtype=float)
    return 2.0 / x * (1.0 + np.expm1(-x) / x)


@dataclass(frozen=True)
class WhiteGM:
    """White noise plus one first-order Gauss-Markov process, in frames.

    white: q, the white variance per sample (AVAR = q / T); gm_var: s2, the Gauss-Markov
    variance; tau: its correlation time, frames (meaningless when gm_var is 0); lr: twice the
    log-likelihood gained by the Gauss-Markov part (compared with :data:`GM_SIGNIFICANCE`).
    """

    white: float
    gm_var: float = 0.0
    tau: float = 1.0
    lr: float = 0.0

    def avar(self, t: np.ndarray) -> np.ndarray:
        """Allan variance at averaging times t, frames."""
        t = np.asarray(t, dtype=float)
        return self.white / t + self.gm_var * gm_allan(t / self.tau)

    def mean_var(self, n: np.ndarray) -> np.ndarray:
        """Variance of the mean of n frames about the long-run mean."""
        n = np.asarray(n, dtype=float)
        return self.white / n + self.gm_var * gm_mean_var(n / self.tau)

    def sample_var(self, n: np.ndarray) -> np.ndarray:
        """Expected per-sample variance (ddof 1) of a window of n frames."""
        n = np.asarray(n, dtype=float)
        return self.white + self.gm_var * _gm_sample_var(n, self.tau)

    def alpha(self, t: np.ndarray) -> np.ndarray:
        """Dominant power-law type (:data:`ALPHAS`) at averaging times t, from the local slope
        mu of AVAR ~ T^mu: alpha = -mu - 1, rounded to a known type (for the EDF)."""
        t = np.asarray(t, dtype=float)
        mu = np.log(self.avar(t * 1.05) / self.avar(t / 1.05)) / math.log(1.05**2)
        alpha = np.clip(np.rint(-mu - 1), -2, 0).astype(int)
        return alpha


def _gm_sample_var(n: np.ndarray, tau: float | np.ndarray) -> np.ndarray:
    """E[s^2] (ddof 1) of a unit-variance Gauss-Markov process over n frames."""
    return n / np.maximum(n - 1, 1) * (1.0 - gm_mean_var(n / tau))


@dataclass(frozen=True)
class Observations:
    """Variance estimates for :func:`fit_white_gm`: value ~ E * chi2(dof) / dof.

    value, dof: (K,); white: (K,) the expectation per unit white level q; gm: callable taking
    correlation times (P,) and giving (P, K) expectations per unit Gauss-Markov variance.
    """

    value: np.ndarray
    dof: np.ndarray
    white: np.ndarray
    gm: Callable[[np.ndarray], np.ndarray]

    @staticmethod
    def allan(t: np.ndarray, avar: np.ndarray, dof: np.ndarray) -> Observations:
        """Allan variances at averaging times t (frames)."""
        t = np.asarray(t, dtype=float)
        return Observations(
            np.asarray(avar, float), np.asarray(dof, float), 1.0 / t,
            lambda taus: gm_allan(t[None, :] / taus[:, None]),
        )  # fmt: skip

    @staticmethod
    def sample_variance(n: np.ndarray, var: np.ndarray) -> Observations:
        """Per-sample variances (ddof 1) of windows of n frames."""
        n = np.asarray(n, dtype=float)
        return Observations(
            np.asarray(var, float), np.maximum(n - 1, 0), np.ones_like(n),
            lambda taus: _gm_sample_var(n[None, :], taus[:, None]),
        )  # fmt: skip

    def __add__(self, other: Observations) -> Observations:
        return Observations(
            np.concatenate((self.value, other.value)),
            np.concatenate((self.dof, other.dof)),
            np.concatenate((self.white, other.white)),
            lambda taus: np.concatenate((self.gm(taus), other.gm(taus)), axis=1),
        )


def fit_white_gm(obs: Observations, taus: np.ndarray, iterations: int = 40) -> WhiteGM:
    """Maximum-likelihood white + Gauss-Markov fit of variance estimates, one axis.

    Each estimate is taken as E chi2(dof) / dof, so the negative log-likelihood is
    sum dof / 2 (value / E + ln E). White only has a closed form; with a Gauss-Markov part, for
    every correlation time in ``taus`` (frames) at once, iteratively reweighted least squares
    (weights dof / E^2: Fisher scoring of a gamma model with identity link) with q, s2 >= 0.
    The Gauss-Markov part is kept when it gains more than :data:`GM_SIGNIFICANCE`.
    """
    ok = (obs.dof > 0) & np.isfinite(obs.value) & (obs.value >= 0)
    v, nu, h = obs.value[ok], obs.dof[ok], obs.white[ok]
    if v.size == 0 or not (v > 0).any():
        return WhiteGM(0.0)
    scale = float(np.sum(nu * v / h) / np.sum(nu))  # the white-only ML level
    y = v / scale
    white = WhiteGM(scale)
    taus = np.asarray(taus, dtype=float)
    if taus.size == 0 or v.size < 3:
        return white
    g = obs.gm(taus)[:, ok]  # (P, K)
    nll0 = float(np.sum(nu * (y / h + np.log(h)))) / 2  # white-only, at q = 1 (scaled)
    c1 = np.ones(taus.shape[0])
    c2 = np.zeros(taus.shape[0])
    tiny = 1e-12
    for _ in range(iterations):
        e = np.maximum(c1[:, None] * h + c2[:, None] * g, tiny)
        w = nu / (e * e)
        a11 = (w * h * h).sum(axis=1)
        a12 = (w * h * g).sum(axis=1)
        a22 = (w * g * g).sum(axis=1)
        b1 = (w * h * y).sum(axis=1)
        b2 = (w * g * y).sum(axis=1)
        det = a11 * a22 - a12 * a12
        with np.errstate(invalid="ignore", divide="ignore"):
            n1 = (a22 * b1 - a12 * b2) / det
            n2 = (a11 * b2 - a12 * b1) / det
            only_white, only_gm = b1 / a11, b2 / a22
        n1, n2 = np.where(n2 < 0, only_white, n1), np.where(n2 < 0, 0.0, n2)
        n2, n1 = np.where(n1 < 0, only_gm, n2), np.where(n1 < 0, 0.0, n1)
        good = np.isfinite(n1) & np.isfinite(n2)
        c1, c2 = np.where(good, n1, c1), np.where(good, np.maximum(n2, 0.0), c2)
    e = np.maximum(c1[:, None] * h + c2[:, None] * g, tiny)
    nll = (nu * (y / e + np.log(e))).sum(axis=1) / 2
    nll = np.where((c2 > 0) & np.isfinite(nll), nll, np.inf)
    i = int(np.argmin(nll))
    lr = 2.0 * (nll0 - float(nll[i]))
    if not np.isfinite(lr) or lr < GM_SIGNIFICANCE:
        return WhiteGM(scale, lr=max(lr, 0.0) if np.isfinite(lr) else 0.0)
    return WhiteGM(float(c1[i]) * scale, float(c2[i]) * scale, float(taus[i]), lr)


def tau_grid(t_min: float, t_max: float, per_octave: int = TAU_PER_OCTAVE) -> np.ndarray:
    """Correlation times tried, frames: ``per_octave`` per octave from t_min to t_max."""
    if not (t_max > 0 and t_min > 0):
        return np.zeros(0)
    octaves = max(math.log2(t_max / t_min), 0.0)
    return t_min * 2.0 ** (np.arange(round(octaves * per_octave) + 1) / per_octave)


# ---- 3. The standard error of a window mean -------------------------------------------------
def allan_sums(blocks: list[np.ndarray], block: int) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping Allan sums of one window from its complete blocks' sums (k, 7).

    Each block row is [valid frames, 6 sums] (gyro x y z, accel x y z). Row j of the result
    averages over m = 2^j blocks: sum over k of (ybar_(k+m) - ybar_k)^2 / 2 per axis, and the
    number of terms. Blocks missing more than half their frames are left out.
    """
    if not blocks:
        return np.zeros((0, 6)), np.zeros(0)
    b = np.concatenate(blocks)
    k = b.shape[1] - 1
    b = b[b[:, 0] >= (block + 1) // 2]
    y = b[:, 1:] / b[:, :1] if b.size else np.zeros((0, k))
    c = np.concatenate((np.zeros((1, k)), np.cumsum(y, axis=0)))
    sq, terms = [], []
    m = 1
    while 2 * m <= y.shape[0]:
        avg = (c[m:] - c[:-m]) / m
        d = avg[m:] - avg[:-m]
        sq.append(0.5 * (d * d).sum(axis=0))
        terms.append(d.shape[0])
        m *= 2
    if not sq:
        return np.zeros((0, k)), np.zeros(0)
    return np.array(sq), np.array(terms, dtype=float)


def block_sums(x: np.ndarray, block: int) -> np.ndarray:
    """The complete blocks of samples x (n, k) as :func:`allan_sums` takes them: (blocks, k + 1)."""
    k = x.shape[0] // block
    b = x[: k * block].reshape(k, block, x.shape[1]).sum(axis=1)
    return np.column_stack((np.full(k, float(block)), b))


def standard_errors(
    samples: np.ndarray,
    std: np.ndarray,
    allan: Sequence[tuple[np.ndarray, np.ndarray]],
    block: int,
) -> np.ndarray:
    """(M, k) standard errors of the means of M windows of one recording, input units.

    samples: frames per window (M,); std: per-sample standard deviations (M, k), ddof 1;
    allan: per window the (sq, terms) of :func:`allan_sums` over blocks of ``block`` frames.

    Per axis, a :class:`WhiteGM` model is fitted (:func:`fit_white_gm`) to every window's
    per-sample variance (dof n - 1: it pins the white level) and to the Allan variances at
    T = block, 2 block, ... pooled over the windows (white-noise EDF). The inflation over white
    noise is F(n) = var(mean of n) / (E[s^2](n) / n) >= 1; each window gets
    std_w sqrt(F(n_w) / n_w): the shape from the recording, the level its own.

    Below white only with evidence (:func:`negatively_correlated`): when the pooled Allan
    variance at T = block is below both the white value sigma^2 / block and the fitted model,
    each with one-sided significance 1 % (chi-square with its EDF; what negatively correlated
    noise, e.g. differenced or quantised angle increments, gives), F is the ratio
    AVAR(block) block / sigma^2 at its upper 99 % confidence bound instead, for every window. Windows shorter than two blocks
    contribute their variance only; with no Allan statistics at all this is std / sqrt(n).
    """
    samples = np.asarray(samples, dtype=float)
    std = np.asarray(std, dtype=float)
    white_sem = std / np.sqrt(np.maximum(samples, 1.0))[:, None]
    if samples.size == 0:
        return white_sem
    factor = inflation_factors(samples, std, allan, block)
    return white_sem * np.sqrt(factor)


def inflation_factors(
    samples: np.ndarray,
    std: np.ndarray,
    allan: Sequence[tuple[np.ndarray, np.ndarray]],
    block: int,
) -> np.ndarray:
    """(M, k) factors F = sem^2 / (std^2 / n) of :func:`standard_errors`."""
    samples = np.asarray(samples, dtype=float)
    std = np.asarray(std, dtype=float)
    k = std.shape[1]
    levels = max((a[0].shape[0] for a in allan), default=0)
    out = np.ones_like(std)
    if levels == 0:
        return out
    sq = np.zeros((levels, k))
    terms = np.zeros(levels)
    edf = np.zeros(levels)
    m = 2.0 ** np.arange(levels)
    for a_sq, a_terms in allan:
        j = a_sq.shape[0]
        sq[:j] += a_sq
        terms[:j] += a_terms
        if j:  # this window's blocks: level-0 differences + 1
            edf[:j] += edf_simple(a_terms[0] + 2, m[:j], 0)
    use = terms > 0
    t = block * m[use]
    taus = tau_grid(float(block), float(t[-1]))
    dof_s = np.maximum(samples - 1, 0)
    for c in range(k):
        var = std[:, c] ** 2
        pooled = float(dof_s @ var) / max(float(dof_s.sum()), 1.0)
        if not pooled > 0:
            continue  # noiseless: 0 stays 0
        avar = sq[use, c] / terms[use]
        obs = Observations.sample_variance(samples, var) + Observations.allan(t, avar, edf[use])
        model = fit_white_gm(obs, taus)
        f = model.mean_var(samples) * samples / model.sample_var(samples)
        out[:, c] = np.maximum(f, 1.0)
        if negatively_correlated(avar[0], edf[use][0], pooled / t[0], float(model.avar(t[0]))):
            nu, ratio = edf[use][0], float(avar[0] * t[0] / pooled)
            out[:, c] = nu * ratio / stats.chi2.ppf(NEGATIVE_CORRELATION_LEVEL, nu)
    return out


def negatively_correlated(avar: float, edf: float, white: float, model: float) -> bool:
    """Whether an Allan variance ``avar`` (``edf`` dof) at the shortest level shows negative
    correlation with one-sided confidence 1 - :data:`NEGATIVE_CORRELATION_LEVEL`.

    Two chi-square tests must both reject: against ``white`` (the per-sample variance / T: no
    correlation) and against ``model`` (the fitted white + Gauss-Markov prediction). The second
    keeps a slow Gauss-Markov process, whose variance inflates the per-sample variance but not
    the short-term Allan variance, from passing for negative correlation.
    """
    if not (edf > 0 and avar >= 0):
        return False
    limit = stats.chi2.ppf(NEGATIVE_CORRELATION_LEVEL, edf) / edf
    return avar < limit * white and avar < limit * model


class WindowStats(Protocol):
    """What :func:`pooled_standard_errors` reads of a window (recal.detect.windows.Window has it)."""

    samples: int
    gyro_std: np.ndarray
    accel_std: np.ndarray
    block_frames: int
    allan_sq: np.ndarray
    allan_terms: np.ndarray


def pooled_standard_errors(windows: Sequence[WindowStats]) -> tuple[np.ndarray, np.ndarray]:
    """(M, 3) gyro and (M, 3) accel standard errors of the window means, input units.

    Correlated noise included, the windows' statistics pooled over the recording
    (:func:`standard_errors`; docs/engine.md, "Correlated noise"). Windows with another block
    length than the others are pooled per block length.
    """
    out = np.zeros((len(windows), 6))
    blocks = np.array([w.block_frames for w in windows], dtype=np.int64)
    for block in np.unique(blocks):
        idx = np.flatnonzero(blocks == block)
        group = [windows[i] for i in idx]
        out[idx] = standard_errors(
            np.array([w.samples for w in group], dtype=float),
            np.array([np.concatenate((w.gyro_std, w.accel_std)) for w in group]).reshape(-1, 6),
            [(w.allan_sq, w.allan_terms) for w in group],
            max(int(block), 1),
        )
    return out[:, :3], out[:, 3:]


# ---- 4. A per-axis summary -------------------------------------------------------------------
@dataclass(frozen=True)
class AxisNoise:
    """Noise of one axis from its still stretches. Units: the input's, time in s.

    white: random-walk coefficient N (angle random walk for a gyro, velocity random walk for an
        accelerometer), input units per sqrt(Hz) (= units x sqrt(s)): AVAR(tau) = N^2 / tau.
    bias_instability: minimum of the measured Allan deviation / 0.664 (IEEE Std 952), input
        units, at bias_instability_tau_s; an upper bound when the curve still falls at its
        longest averaging time (bias_instability_bound).
    correlation_time_s, gm_sigma: the Gauss-Markov part of the fit (None when not significant,
        or when shorter than :data:`SHORT_CORRELATION_FRAMES`: then it is counted as white).
    model: the fitted model (AVAR in input units^2, times in frames of the curve).
    """

    name: str
    white: float
    bias_instability: float
    bias_instability_tau_s: float
    bias_instability_bound: bool
    correlation_time_s: float | None
    gm_sigma: float | None
    model: WhiteGM

    def to_json(self) -> dict[str, object]:
        return {
            "name": self.name,
            "white": self.white,
            "bias_instability": self.bias_instability,
            "bias_instability_tau_s": self.bias_instability_tau_s,
            "bias_instability_upper_bound": self.bias_instability_bound,
            "correlation_time_s": self.correlation_time_s,
            "gauss_markov_sigma": self.gm_sigma,
        }


def fit_curve(curve: AllanCurve, column: int) -> WhiteGM:
    """:func:`fit_white_gm` of one axis of a curve, octave levels only (denser ones are
    strongly correlated with them), with the white-noise EDF then the fitted model's."""
    t = curve.m.astype(float)
    octave = np.isclose(np.log2(t), np.round(np.log2(t)))
    taus = tau_grid(max(t[octave][0], 1.0), float(t[octave][-1]))
    alpha = np.zeros(t.shape[0], dtype=int)
    model = WhiteGM(0.0)
    for _ in range(2):  # the EDF depends on the noise type, which the fit tells
        obs = Observations.allan(t[octave], curve.avar[octave, column], curve.edf(alpha)[octave])
        model = fit_white_gm(obs, taus)
        if model.white <= 0 and model.gm_var <= 0:
            break
        alpha = model.alpha(t)
    return model


#: A Gauss-Markov part with a correlation time below this many frames is the sensor's own
#: low-pass filter (MEMS data have lag-1 correlations from it): beyond a few frames it averages
#: like white noise, so :func:`summarize_axis` counts it as white (q + 2 tau s2).
SHORT_CORRELATION_FRAMES = 10.0


def summarize_axis(curve: AllanCurve, column: int, name: str) -> AxisNoise:
    """The :class:`AxisNoise` of one column of a curve."""
    model = fit_curve(curve, column)
    gm = model.gm_var > 0 and model.tau >= SHORT_CORRELATION_FRAMES
    white = model.white if gm else model.white + 2 * model.tau * model.gm_var
    adev = curve.adev[:, column]
    i = int(np.argmin(adev))
    return AxisNoise(
        name=name,
        white=math.sqrt(white / curve.rate_hz),
        bias_instability=float(adev[i]) / BIAS_INSTABILITY_FACTOR,
        bias_instability_tau_s=float(curve.tau_s[i]),
        bias_instability_bound=i == adev.shape[0] - 1,
        correlation_time_s=model.tau / curve.rate_hz if gm else None,
        gm_sigma=math.sqrt(model.gm_var) if gm else None,
        model=model,
    )
