"""The standard error of a window mean when the noise is not white: a filtered FOG on a rocking hull.

A FOG's output passes its own low-pass filter (a 1 kHz output through a second-order low-pass of
tens to hundreds of Hz), so neighbouring samples are correlated. The variance of a weighted mean
``sum w_i x_i`` (weights slowly varying, sum 1) of stationary noise with autocovariance C(l) is

    var = sum_ij w_i w_j C(i - j) ~= S0 * sum w_i^2,    S0 = sum_l C(l),

to relative order (correlation length / n)^2, where S0 is the noise's *long-run* variance: the
spectral density at zero frequency (per sample, two-sided, times the sample rate). For white noise
S0 is the per-sample variance, and the second differences of the samples give it without seeing
the waves (var(d2) = 6 sigma^2: what :mod:`recal.detect.hull` did). Through a low-pass of DC gain 1,
S0 is still the input's variance but the samples' second differences see only the filter's
high-frequency tail: 5 % of S0 for a 200 Hz cutoff at 1 kHz, 0.5 % at 100 Hz, so those sems were 4
to 14 times too small.

**The statistic.** For a block length m, the samples' moving average over m, taken ``BOXES`` (p)
times, then differenced ``DIFFERENCES`` (k) times at lag m: ``D = Delta_m^k B_m^p x``, a linear
filter h_m with response G_m(f) = (2 sin(pi f m))^k (sin(pi f m) / (m sin(pi f)))^p (f in cycles
per sample) and sum h = 0. For noise of spectral density S(f),

    V(m) = mean(D^2) / sum h_m^2 = int S |G_m|^2 df / int |G_m|^2 df,

an average of the spectrum over |G_m|^2, which peaks near f = 1 / (2 m) (``m`` samples is half the
period probed). Below, it falls as (pi f m)^(2 k): a polynomial of degree < k (a slow drift, the
heading creep) is removed exactly, and a wave of rate amplitude R and frequency f_w adds about
(R^2 / 2) m (pi f_w m)^(2 k), times a factor of order one, to V. Above, the boxes make it fall as
f^(-2 p), so the filter's roll-off is seen only through small sidelobes (plain block means, p = 1,
leave a deficit that decays only as 1/m: 3 % at m = 64 for a 100 Hz filter at 1 kHz).
With k = 6, p = 3, V(m) = S0 when the spectrum is flat between about 1/(4 m) and 1/m: for white
noise at every m (at m = 1 it is mean((Delta^6 x)^2) / 924, the same estimate as the second
differences', with a 28 % larger scatter); for a low-pass of cutoff fc once 1 / (2 m) is a third
of fc or less (both in cycles per sample); and the waves stay out while m is short against them
(at 1 kHz, 3 degrees of roll at 3.5 s, noise-free, give 0.6 % of a KVH-class gyro's S0 at
m = 128).

**The block length from the data.** V is computed at m = 1, 2, 4, ... up to ``MAX_BLOCK_S`` (and
while at least half the samples remain): a low-pass makes it rise towards S0, waves would make it
rise again much later (as m^(2 k + 1)). The estimate is taken from the first level from which V
stops rising: the first m whose successor is not larger by ``RISE_SIGMAS`` of the two levels'
statistical scatter (relative sd sqrt(2 sum rho^2 / N) for N differences, rho the autocorrelation
of h_m: exact for Gaussian noise flat over the band). If that is m = 1 (no rise at all: white noise
down to the Nyquist frequency), V(1) is the estimate, so white noise keeps the plain estimate. If
the noise rose first, the next level's V is taken: the rise to it was within the scatter, and one
more doubling takes a second-order filter's deficit, (1 / (2 m fc))^4, down 16 times. No plateau
before the longest block: the last V (a filter too slow for the bound, or waves too strong: then
the sem errs large).

**Assumptions.** The noise is stationary over the window, and its spectrum is flat from the
frequency V is read at (1 / (2 m dt): the Nyquist frequency for white noise, 4-60 Hz behind a
filter) down to 1 / window length: white noise, or white noise through a low-pass whose cutoff is
12 Hz or more (correlation time below about 20 ms; below that the longest block, 0.13 s at 1 kHz,
no longer reaches the plateau and the sem comes out low). The weights vary slowly against the
noise's correlation (a window holds thousands of correlation times). A Gauss-Markov bias, bias instability or a random walk of the rate (spectral density
rising at low frequency) are not counted: like the second-difference estimate before it, this is
the sem of the sensor's fast noise (the diagnose and wander models handle the slow parts).
Negatively correlated noise (angle quantisation: a falling V) keeps V(1), which overstates it. The
waves, the yaw swing and the heading creep are far below the probe frequencies (periods of 3.5 s
and longer, ``SHORTEST_WAVE_S``).

Pure numpy, vectorised over samples and axes (the loop is over at most a dozen block lengths).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy import stats

from recal.detect.noise import edf_simple

#: k: differences at lag m (a wave leaks into V as (pi f_w m)^(2 k)).
DIFFERENCES = 6
#: p: moving averages over m (the filter's roll-off leaks into V as f^(-2 p)).
BOXES = 3
#: Shortest wave period a hull shows, s (``shared/spec/vessel.md``: 3.5-20 s).
SHORTEST_WAVE_S = 3.5
#: The longest block, s: a 25th of the shortest wave period (pi f_w m = 0.13, at which 3 degrees
#: of roll at 3.5 s add 0.6 % of a KVH-class gyro's noise to V at 1 kHz).
MAX_BLOCK_S = SHORTEST_WAVE_S / 25.0
#: A level "rises" when the next one is larger by this many of their combined relative sd.
RISE_SIGMAS = 2.0


@lru_cache(maxsize=64)
def _kernel_stats(m: int, k: int, p: int) -> tuple[float, float]:
    """sum h^2 and sum_l rho_l^2 of the filter h = Delta_m^k B_m^p (B_m: mean of m samples)."""
    h = np.ones(1)
    box = np.full(m, 1.0 / m)
    for _ in range(p):
        h = np.convolve(h, box)
    for _ in range(k):
        h = np.concatenate((h, np.zeros(m))) - np.concatenate((np.zeros(m), h))
    h2 = float(h @ h)
    # autocorrelation by FFT (h may be thousands of samples long)
    size = 1 << (2 * len(h) - 1).bit_length()
    spec = np.fft.rfft(h, size)
    acf = np.fft.irfft(np.abs(spec) ** 2, size)
    rho2 = float(np.sum(acf**2)) / h2**2
    return h2, rho2


def _doubled(y: np.ndarray, m: int, p: int) -> np.ndarray:
    """B_2m^p x from y = B_m^p x (rows): B_2m = B_m (1 + T^m) / 2, T^m the shift by m."""
    for _ in range(p):
        y = 0.5 * (y[:, m:] + y[:, :-m])
    return y


def _level(y: np.ndarray, m: int, k: int) -> tuple[np.ndarray, int]:
    """mean((Delta_m^k y)^2) per row of y (c, n) and the number of terms."""
    for _ in range(k):
        y = y[:, m:] - y[:, :-m]
    return np.einsum("ij,ij->i", y, y) / y.shape[1], y.shape[1]


def long_run_variance(
    x: np.ndarray, dt: float, max_block_s: float = MAX_BLOCK_S
) -> tuple[np.ndarray, np.ndarray]:
    """S0 per column of samples x (n,) or (n, c) evenly spaced by dt (s), and the block (samples)
    it was read at (see the module docstring). NaN with fewer than 4 samples."""
    x = np.asarray(x, dtype=float)
    flat = x.ndim == 1
    x = x.reshape(len(x), -1)
    n, ncol = x.shape
    out = np.full(ncol, np.nan)
    block = np.ones(ncol, dtype=np.int64)
    if n < 4:
        return (out[0], block[0]) if flat else (out, block)
    y = np.ascontiguousarray((x - x.mean(axis=0)).T)  # (c, n): B_1^p x = x
    k = min(DIFFERENCES, n - 2)  # a handful of samples: fewer differences (n >= 4: k >= 2)
    p = BOXES
    longest = max(1.0, max_block_s / dt) if dt > 0 and math.isfinite(dt) else 1.0
    levels: list[int] = []
    values: list[np.ndarray] = []
    rel_sd: list[float] = []
    take = np.full(ncol, -1)  # the level each column is read at, once decided
    m = 1
    while True:
        v, terms = _level(y, m, k)
        h2, rho2 = _kernel_stats(m, k, p)
        levels.append(m)
        values.append(v / h2)
        rel_sd.append(math.sqrt(2.0 * rho2 / terms))
        j = len(levels) - 1
        if j:  # did V rise from level j - 1 to level j? The first level that does not: stop
            limit = 1.0 + RISE_SIGMAS * math.hypot(rel_sd[j - 1], rel_sd[j])
            flat_here = (take < 0) & ~(values[j] > values[j - 1] * limit)
            take[flat_here] = 0 if j == 1 else j  # no rise at all: V(1); else the level after
        m2 = 2 * m
        if (take >= 0).all() or m2 > longest or p * (m2 - 1) + k * m2 > n // 2:
            break
        y = _doubled(y, m, p)
        m = m2
    take[take < 0] = len(levels) - 1  # never stopped rising: the longest block
    V = np.array(values)  # (levels, c)
    out = V[take, np.arange(ncol)]
    block = np.array(levels, dtype=np.int64)[take]
    return (out[0], block[0]) if flat else (out, block)


def weighted_mean_sem(x: np.ndarray, sum_w2: float, dt: float) -> np.ndarray:
    """Standard error of sum_i w_i x_i (weights summing to 1, sum w_i^2 = ``sum_w2``, varying
    slowly against the noise's correlation) per column: sqrt(S0 sum w^2)."""
    s0, _ = long_run_variance(x, dt)
    return np.sqrt(np.maximum(s0, 0.0) * sum_w2)


def static_white_std(
    std: np.ndarray, allan_sq: np.ndarray, allan_terms: np.ndarray, block: int
) -> np.ndarray:
    """The per-sample sd a still window's white level should have (:mod:`recal.detect.noise`
    takes the per-sample variance as the white noise's level): the window's own ``std``, unless
    its Allan variance at one block (``block`` frames) says, with one-sided confidence 99 %,
    that the long-run level AVAR(block) * block exceeds std^2; then sqrt(AVAR(block) * block).

    A low-pass inside the sensor makes the per-sample variance smaller than the long-run level
    (21 % of it for a second-order 100 Hz filter at 1 kHz): the white + Gauss-Markov model then
    explained the Allan variances with a Gauss-Markov part it had to squeeze into the per-sample
    variance, and its sems came out 1.3-1.7 times too large. The filter's correlation (a few
    frames) is far shorter than a block (``W`` frames, about 100), so AVAR(block) * block is the
    long-run level to within a few per cent; slow noise (a Gauss-Markov bias) raises the
    per-sample variance more than AVAR(block) * block and never triggers this.
    """
    std = np.asarray(std, dtype=float)
    if allan_sq.shape[0] == 0 or allan_terms[0] <= 0 or block < 2:
        return std
    # EDF of the first level, as recal.detect.noise.inflation_factors counts it (white noise)
    nu = float(edf_simple(allan_terms[0] + 2, 1, 0))
    if not nu > 0:
        return std
    level = allan_sq[0] / allan_terms[0] * block
    limit = stats.chi2.ppf(0.99, nu) / nu
    return np.where(level > std**2 * limit, np.sqrt(np.maximum(level, 0.0)), std)
