"""Heading creep and anchor swing in a hull's quasi-static window (issue 36, item 3).

A moored or anchored hull turns slowly about the vertical: mooring lines stretch, the tide turns
the ship (0.1-2 deg/h at a berth), and at a single anchor it swings tens of degrees over a tide
(5-20 deg/h in the slow part; ``shared/spec/vessel.md``). Over a window of minutes that is a
steady rate about the local vertical, which a gyro sees exactly as a vertical bias. It does two
things to the window's mean rate ``w`` (deg/h, body axes, the window's mean attitude):

* **along gravity** it adds -c up (c the heading rate, clockwise from north seen from above,
  deg/h; ``up`` the unit specific force): indistinguishable, within the window, from a bias;
* **across gravity** Earth's horizontal rate turns in the body while it is averaged: the mean
  keeps sum_i w_i cos(c (t_i - t_w)) of it (:func:`horizontal_loss`; second order: 4e-5 at
  5 deg/h over 15 min, 7e-4 at 30 deg/h).

What is done with it depends on what else is known:

* **the ship's heading** (``[nav]``: HDT, THS): c is its least-squares slope over the window
  (:func:`heading_rate`), the same weights' slope the gyro mean is; the vertical part is
  corrected and keeps its information, the slope's 1-sigma joins the window's sem along up;
* **no heading**: c cannot be told from the vertical bias. The window's vertical rate is then
  no measurement (``gyro_vertical`` False): the fit uses its rate across gravity only
  (:mod:`recal.solve.problem`), and the rest check allows the vertical part up to
  ``max_creep_dph`` (:meth:`recal.detect.rest.RestReference.judge`). c is estimated from the
  vertical excess over Earth's vertical rate for the loss above only, where its error (the
  vertical bias, a fraction of a deg/h) costs nothing.

Pure numpy.
"""

from __future__ import annotations

import math

import numpy as np

#: The largest creep or swing rate a hold keeps by default, deg/h: an anchored ship's slow swing
#: reaches 5-20 deg/h (shared/spec/vessel.md); a turn is 360 deg/h and more.
MAX_CREEP_DPH = 30.0
#: Batches of the heading's residuals for their long-run variance (:func:`heading_rate`).
BATCHES = 20
#: The least share of a window's samples with a heading for it to count as measured.
MIN_HEADING_SHARE = 0.5


def heading_rate(t_s: np.ndarray, heading_deg: np.ndarray) -> tuple[float, float]:
    """The heading's rate over a window, deg/h (clockwise from north positive), and its 1-sigma.

    The rate is the same average the window's gyro mean is: that mean, with the parabolic
    weights of :mod:`recal.detect.hull`, is the least-squares slope of the integrated rate, and
    the heading is the integrated yaw rate, so the heading's plain least-squares slope (its
    unwrapped angle against time) is the creep the gyro mean holds. Samples where the heading is NaN are left out; with fewer than
    :data:`MIN_HEADING_SHARE` of them, (NaN, NaN). The 1-sigma is the least-squares slope's,
    from the residual scatter about a quadratic (a swing curves within a window), which covers a
    compass's quantisation and noise."""
    t = np.asarray(t_s, float)
    psi = np.asarray(heading_deg, float)
    ok = np.isfinite(psi)
    if ok.sum() < max(4, MIN_HEADING_SHARE * len(psi)):
        return math.nan, math.nan
    t, psi = t[ok], np.unwrap(np.radians(psi[ok]))
    tc = t - t.mean()
    # the quadratic, orthogonal to the line on a symmetric span, leaves the slope as it is and
    # keeps a swing's curvature out of the scatter
    A = np.column_stack([np.ones_like(tc), tc, tc**2 - np.mean(tc**2)])
    coef, *_ = np.linalg.lstsq(A, psi, rcond=None)
    resid = psi - A @ coef
    dof = max(len(psi) - 3, 1)
    # the heading arrives at 1-10 Hz and is held or interpolated onto the frames, quantised
    # to 0.1 deg: its errors are correlated over many frames. Their long-run variance (what a
    # slope feels) comes from batch means (BATCHES contiguous batches), never below the white
    # one
    n_b = len(resid) // BATCHES
    white = float(resid @ resid) / dof
    if n_b >= 2:
        means = resid[: n_b * BATCHES].reshape(BATCHES, n_b).mean(axis=1)
        long_run = n_b * float(means @ means) / (BATCHES - 1)
    else:
        long_run = white
    cov = max(white, long_run) * np.linalg.inv(A.T @ A)
    # a heading quantised to q with less noise than q is a staircase: its error is a sawtooth as
    # long as the time the creep takes to move one quantum, which no batch catches; its slope
    # error is at most 1.5 q / T (a least-squares slope of an error within +-q/2), carried as
    # q / T (the quantum is the output's resolution, :func:`_quantum`)
    q = math.radians(_quantum(np.asarray(heading_deg, float)[np.isfinite(heading_deg)]))
    span = float(np.ptp(t))
    dithered = math.sqrt(white) >= q  # noise of a quantum or more averages the steps out
    quant = (q / span) ** 2 if span > 0 and not dithered else 0.0
    to_dph = math.degrees(1.0) * 3600.0
    return float(coef[1]) * to_dph, math.sqrt(float(cov[1, 1]) + quant) * to_dph


def horizontal_loss(t_s: np.ndarray, weights: np.ndarray, rate_dph: float) -> float:
    """What a weighted mean keeps of a vector that turns at ``rate_dph`` about the axis it is
    averaged across: sum_i w_i cos(c (t_i - t_w)), t_w the weights' centre (the sine part
    cancels about it). 1 for no turn."""
    if not math.isfinite(rate_dph) or rate_dph == 0.0:
        return 1.0
    t = np.asarray(t_s, float)
    w = np.asarray(weights, float)
    tw = float(w @ t)
    c = math.radians(rate_dph) / 3600.0
    return float(w @ np.cos(c * (t - tw)))


def correct_rate(
    rate_dph: np.ndarray, up: np.ndarray, creep_dph: float, loss: float, vertical_known: bool
) -> np.ndarray:
    """The window's mean rate (3,), deg/h, without the creep: the horizontal part divided by the
    averaging ``loss``, and, where the creep is measured (``vertical_known``), ``creep_dph``
    (clockwise heading rate) taken out of the vertical part; otherwise the vertical part is
    left as measured (it is then no measurement: ``gyro_vertical`` False)."""
    w = np.asarray(rate_dph, float)
    u = np.asarray(up, float) / max(float(np.linalg.norm(up)), 1e-300)
    v = float(w @ u)
    h = w - v * u
    if vertical_known and math.isfinite(creep_dph):
        v = v + creep_dph  # the hull's rate about up is -c: add it back
    return h / max(loss, 1e-12) + v * u


def _quantum(values_deg: np.ndarray) -> float:
    """The resolution a heading is given to, deg: the largest of 1, 0.1, ... 1e-4 that every
    value is a multiple of (a compass sends HDT with one or two decimals); 0 for values not
    quantised that coarsely."""
    v = np.asarray(values_deg, float)
    if not v.size:
        return 0.0
    for k in range(5):
        x = v * 10.0**k
        if np.all(np.abs(x - np.round(x)) < 1e-6 * max(1.0, float(np.max(np.abs(x))))):
            return 10.0**-k
    return 0.0
