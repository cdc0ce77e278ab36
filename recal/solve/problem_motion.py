"""The motion invariants of a calibration problem (:class:`recal.solve.problem.Problem`): the
slews between windows (the gyro integrated over the motion carries one window's gravity
direction onto the next's, :mod:`recal.detect.slew_gravity`), the known rotations
(:mod:`recal.detect.known_rotations`) and the closed turns about the vertical
(:mod:`recal.detect.closed_turns`): their residuals, batched over parameter vectors, their
noise, and what the closed turns' Earth-rate heading check needs."""

from __future__ import annotations

from collections.abc import Mapping
from functools import cached_property

import numpy as np

from recal.detect.closed_turns import HeadingCheck, closure_residuals
from recal.detect.known_rotations import rotation_residuals, rotation_sigma
from recal.detect.slew_gravity import slew_residuals, slew_sigma
from recal.model.positions import GYRO_STD_COLUMNS


class MotionInvariants:
    """The slew, known-rotation and closed-turn parts of :class:`recal.solve.problem.Problem`
    (a base of it: these methods read the problem's fields, models and layout)."""

    def _heading_check(
        self, theta: np.ndarray, force: np.ndarray, prior_sigma: Mapping[str, np.ndarray] | None
    ) -> HeadingCheck:
        """What the Earth-rate heading check of the closed turns needs, at ``theta``."""
        sl = self.layout.term_slices()
        rate = self.physical(theta[None])["gyro"][0]
        scale = np.maximum(np.abs(theta[sl["gyro.scale"]]), 1e-300)
        sem = self.positions.std_of_mean("gyro")
        sigma = dict(prior_sigma or {})
        typical = self.layout.typical(theta)
        bias = np.asarray(sigma.get("gyro.bias", typical[sl["gyro.bias"]]), float)
        rel = np.asarray(sigma.get("gyro.scale", typical[sl["gyro.scale"]]), float) / scale
        return HeadingCheck(rate, force, None if sem is None else sem / scale,
                            self.latitude_deg, bias, rel, self.slew_earth_rate)  # fmt: skip

    @cached_property
    def _slew_ctx(self) -> dict[str, np.ndarray]:
        """The context of each slew's first window (temperature, time, specific force)."""
        assert self.slews is not None
        return {k: np.asarray(v)[self.slews.first] for k, v in self.ctx.items()}

    def _slew_values(self, theta: np.ndarray, x: dict[str, np.ndarray]) -> np.ndarray:
        """Slew residuals (P, 2 S), rad (:func:`recal.detect.slew_gravity.slew_residuals`)."""
        assert self.slews is not None and self.slew_basis is not None
        gain, A, offset = self._gyro_parts(theta)
        f = x["accel"]  # (3, P, M)
        f1 = np.moveaxis(f[:, :, self.slews.first], 0, -1)
        f2 = np.moveaxis(f[:, :, self.slews.second], 0, -1)
        return slew_residuals(
            self.slews, gain, A, offset, f1, f2, self.slew_basis, self.slew_earth_rate,
            self._zero_rate, self._same_gyro(theta),
        )  # fmt: skip

    def _same_gyro(self, theta: np.ndarray) -> np.ndarray | None:
        """For each row of theta (P, D), the first row with the same gyro parameters, or None
        when all differ: the slews are integrated once per distinct gyro (a Jacobian along the
        accelerometer's coefficients, a swarm's accelerometer phase, needs no integration)."""
        theta = np.atleast_2d(theta)
        if theta.shape[0] < 2:
            return None
        g = np.ascontiguousarray(theta[:, self._slices["gyro"]])
        _, first, inverse = np.unique(g, axis=0, return_index=True, return_inverse=True)
        if first.size == theta.shape[0]:
            return None
        return first[inverse.reshape(-1)]

    @cached_property
    def _zero_rate(self) -> np.ndarray | None:
        """A gyro blind to Earth rate: the output taken as zero rate over each slew, the mean of
        its two windows (its bias wanders between windows; :func:`recal.detect.slew_rotation.slew_rotations`)."""
        if self.slew_earth_rate or self.slews is None:
            return None
        g = self.positions.gyro
        return 0.5 * (g[self.slews.first] + g[self.slews.second])

    def _gyro_parts(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The gyro model's gain, matrix and offset in the context of each slew's first window."""
        theta = np.atleast_2d(theta)
        gain, A, offset, _ = self.model("gyro")._parts(
            theta[:, self._slices["gyro"]], self._slew_ctx
        )
        return gain, A, offset

    def _rotation_values(self, theta: np.ndarray) -> np.ndarray:
        """Known-rotation residuals (P, 3 K), rad (:func:`recal.detect.known_rotations.rotation_residuals`)."""
        assert self.slews is not None and self.known_rotations is not None
        gain, A, offset = self._gyro_parts(theta)
        return rotation_residuals(
            self.slews, self.known_rotations, gain, A, offset, self.slew_earth_rate,
            self._zero_rate,
        )  # fmt: skip

    def _closure_values(self, theta: np.ndarray) -> np.ndarray:
        """Closed-turn residuals (P, C), rad (:func:`recal.detect.closed_turns.closure_residuals`)."""
        assert self.slews is not None and self.closed_turns is not None
        gain, A, offset = self._gyro_parts(theta)
        return closure_residuals(
            self.slews, self.closed_turns, gain, A, offset, self.slew_earth_rate, self._zero_rate
        )

    def _rotation_sigma(
        self, sd_in: dict[str, np.ndarray | None], gains: dict[str, np.ndarray]
    ) -> np.ndarray:
        """Known-rotation noise (3 K,), rad (:func:`recal.detect.known_rotations.rotation_sigma`)."""
        assert self.slews is not None and self.known_rotations is not None
        std_in = self.positions.stack(GYRO_STD_COLUMNS) / gains["gyro"]
        return rotation_sigma(
            self.slews, self.known_rotations, std_in, sd_in["gyro"], self.slew_earth_rate
        )

    def _slew_sigma(
        self,
        x: dict[str, np.ndarray],
        sd_in: dict[str, np.ndarray | None],
        gains: dict[str, np.ndarray],
    ) -> np.ndarray | None:
        """Slew noise (2 S,), rad, from the windows' gyro std and sem and accel sem."""
        assert self.slews is not None and self.slew_basis is not None
        if sd_in["gyro"] is None or sd_in["accel"] is None:
            return None
        if not all(c in self.positions.columns for c in GYRO_STD_COLUMNS):
            return None
        # per-sample gyro std to input units through the local gain, like the window noise
        std_in = self.positions.stack(GYRO_STD_COLUMNS) / gains["gyro"]
        i, j = self.slews.first, self.slews.second
        return slew_sigma(
            self.slews, std_in, sd_in["gyro"], sd_in["accel"], x["accel"][i], x["accel"][j],
            self.slew_basis, self.slew_earth_rate, self.latitude_deg, self.slew_excess_rad,
        )  # fmt: skip
