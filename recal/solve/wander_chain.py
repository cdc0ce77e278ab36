"""The windows as a Markov chain (:mod:`recal.solve.wander`): the window residuals' sensitivity
to each triad's output (:class:`WanderSensitivity`), the windows in order of (session, time) with
their gaps (:class:`WindowChain`), the Gauss-Markov transition between consecutive windows
(:func:`gm_phi`), the state's axes of a model (:func:`wander_state`) and the standardised
residuals' observation of them (:func:`observation_matrix`). The whitening
(:mod:`recal.solve.wander_covariance`) and the restricted likelihood
(:mod:`recal.solve.wander_likelihood`) both run on it."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from recal.errors import RecalInputError
from recal.solve.wander_model import TriadWander


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
class WindowChain:
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


def window_chain(
    sens: WanderSensitivity, t: np.ndarray | None, sessions: np.ndarray | None
) -> WindowChain:
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
    return WindowChain(pos, slot, int(slot.max()) + 1 if R else 1, gap)


def gm_phi(gap: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """(..., M, n) exp(-gap / tau) for tau (..., n): the correlation of consecutive windows; 0
    at a session's start and for tau 0 (independent windows), 1 for an infinite tau."""
    g = gap[:, None]
    tb = np.asarray(tau, float)[..., None, :]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        phi = np.exp(-g / tb)
    return np.where((tb > 0) & np.isfinite(g), np.nan_to_num(phi, nan=1.0), 0.0)


def wander_state(
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


def observation_matrix(
    sens: WanderSensitivity, sigma: np.ndarray, chain: WindowChain, axes: Sequence[tuple[str, int]]
) -> np.ndarray:
    """(M, q, n) each window slot's sensitivity to the state's axes, over the residual's own
    1-sigma (the standardised residuals' observation matrix)."""
    cols = [sens.rows[s][:, a] / sigma for s, a in axes]
    H = np.stack(cols, axis=1) if cols else np.zeros((sens.n_residuals, 0))
    return chain.pad(H)
