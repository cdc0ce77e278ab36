"""Bias wander in a calibration problem (:class:`recal.solve.problem.Problem`): the window
invariants (gyro norm, accel norm, dot) whose residuals the wander correlates, their sensitivity
to each triad's output, and their whitening by the wander's Kalman innovations
(:mod:`recal.solve.wander_covariance`)."""

from __future__ import annotations

from dataclasses import replace
from functools import cached_property
from typing import Self

import numpy as np

from recal.solve.wander_chain import WanderSensitivity
from recal.solve.wander_covariance import WanderCovariance, Whitening
from recal.solve.wander_model import WanderModel, window_sessions, window_times


class WanderWhitening:
    """The window residuals' bias wander in :class:`recal.solve.problem.Problem` (a base of it:
    these methods read the problem's fields, sigma and gains)."""

    @property
    def window_invariants(self) -> tuple[str, ...]:
        """The invariants with one residual per window (gyro norm, accel norm, dot product)."""
        return tuple(n for n in self.invariant_names if n in ("gyro_norm", "accel_norm", "dot"))

    def window_sigma(self) -> np.ndarray:
        """(Rw,) the window residuals' own 1-sigma, in the order of :meth:`residuals`."""
        return np.concatenate([self.sigma[n] for n in self.window_invariants])

    @cached_property
    def _whitener(self) -> Whitening | None:
        """The window residuals' whitening for their current sigma (shared by copies of this
        problem with other fields changed: :class:`recal.solve.wander_covariance.WanderCovariance`)."""
        if self.wander_cov is None:
            return None
        return self.wander_cov.whitening(self.window_sigma())

    def wander_sensitivity(self, theta: np.ndarray) -> WanderSensitivity:
        """d (window residual) / d (output of its window's axes) at ``theta``: per residual, in
        the order of :meth:`residuals`' window part, its window and per triad a 3-vector (input
        units per output unit; zeros where the residual does not involve the triad)."""
        x = {k: v[0] for k, v in self.physical(np.atleast_2d(theta)).items()}
        gains = self._output_gains(np.asarray(theta, float), x)
        windows: list[np.ndarray] = []
        blocks: dict[str, list[np.ndarray]] = {s: [] for s in self.sensors}
        for n in self.window_invariants:
            rows = self.rows_of(n)
            windows.append(rows)
            grads = self.norm_gradients(n, x) if n.endswith("_norm") else {}
            for s in self.sensors:
                d = np.zeros((len(rows), 3))
                if s in grads:
                    d = grads[s][rows]
                elif n == "dot":
                    d = x["accel" if s == "gyro" else "gyro"][rows]
                blocks[s].append(d / gains[s][rows])
        if not windows:
            return WanderSensitivity(
                np.zeros(0, int), {s: np.zeros((0, 3)) for s in blocks}, self.M
            )
        return WanderSensitivity(
            np.concatenate(windows), {s: np.concatenate(b) for s, b in blocks.items()}, self.M
        )

    def with_wander(self, model: WanderModel | None, theta: np.ndarray) -> Self:
        """The problem with ``model``'s bias wander between windows (at ``theta``'s gains);
        None or an empty model: windows independent again."""
        if model is None or model.empty or not self.window_invariants:
            return replace(self, wander=None, wander_cov=None)
        t = window_times(self.positions.columns, self.M)
        sessions = window_sessions(self.positions.columns, self.M)
        cov = WanderCovariance(model, self.wander_sensitivity(theta), t, sessions)
        return replace(self, wander=model, wander_cov=cov)
