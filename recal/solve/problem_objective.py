"""What a swarm minimises over a calibration problem (:class:`recal.solve.problem.Problem`): the
least squares LM minimises, chi^2 / (R - 1), or seed 000 eq. (14) per invariant over its noise
floor (``--paper``), with the squared residuals and the indicator eq. (14) is made of, and the
whitened offsets of perturbed data (:func:`recal.solve.surrogate.data_noise`)."""

from __future__ import annotations

from collections.abc import Mapping
from functools import cached_property

import numpy as np

#: Invariants whose residual is linear in the estimated inputs (no squared form in eq. 14).
LINEAR_INVARIANTS = frozenset({"dot", "slew", "rotation", "closure"})


class ProblemObjective:
    """The objective and eq. (14) indicator of :class:`recal.solve.problem.Problem` (a base of it:
    these methods read the problem's residuals, references and sigma)."""

    def squared_residuals(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        """Seed eq. (13): |x_hat|^2 - ref^2 per position (P, M); the dot product stays linear."""
        vals = self._invariant_values(theta, squared=True)
        return {
            n: v - (self.reference(n) if n in LINEAR_INVARIANTS else self.reference(n) ** 2)
            for n, v in vals.items()
        }

    def indicator(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        """Seed 000 eq. (14) per invariant: sqrt(sum((|x|^2 - ref^2)^2) / (M - 1)), shape (P,)."""
        return {
            n: np.sqrt(np.sum(r * r, axis=1) / max(self.n_of(n) - 1, 1))
            for n, r in self.squared_residuals(theta).items()
        }

    @cached_property
    def _floor(self) -> dict[str, float]:
        return self.indicator_floor()

    def indicator_floor(self) -> dict[str, float]:
        """Expected eq. (14) value from window noise alone, per invariant."""
        out = {}
        for n, s in self.sigma.items():
            scale = 1.0 if n in LINEAR_INVARIANTS else 2.0 * self.reference(n)
            out[n] = float(np.sqrt(np.mean((scale * s) ** 2)))
        return out

    @property
    def objective_dof(self) -> int:
        """chi^2 = :meth:`objective` x this, near the minimum: R - 1 for the least squares; for
        eq. (14) (one noise floor per invariant) about M - 1."""
        return max((self.M if self.paper_objective else self.n_residuals) - 1, 1)

    def objective(
        self, theta: np.ndarray, offsets: Mapping[str, np.ndarray] | None = None
    ) -> np.ndarray:
        """The swarm objective (P,).

        Default: the least squares LM minimises, sum of squared :meth:`residuals` over (R - 1)
        (~chi2_red), so a swarm and LM share their minimum. With ``paper_objective``: the sum
        over invariants of (eq. 14 indicator / its noise floor)^2 -- with one triad eq. (14)
        squared up to a constant, with both it weighs the invariants by their noise, but each
        invariant by one floor, so with slews its minimum is not the least-squares one.

        ``offsets``: invariant -> (P, n) perturbation of the data of each row
        (:func:`recal.solve.surrogate.data_noise`'s form: sigma eps for a linear invariant, 2 ref
        sigma eps for a norm); the least squares adds the eps to the whitened residuals.
        """
        if not self.paper_objective:
            r = self.residuals(theta)
            if offsets is not None:
                r = r + self.whitened_offsets(offsets)
            return self.least_squares(r)
        floor = self._floor
        if offsets is None:
            ind = self.indicator(theta)
            total = sum((ind[n] / floor[n]) ** 2 for n in self.invariant_names)
            return np.where(np.isfinite(total), total, np.inf)
        total = 0.0
        for n, sq in self.squared_residuals(theta).items():
            sq = sq + offsets[n]
            total = total + np.einsum("pm,pm->p", sq, sq) / (
                max(self.n_of(n) - 1, 1) * floor[n] ** 2
            )
        return np.where(np.isfinite(total), total, np.inf)

    def least_squares(self, r: np.ndarray) -> np.ndarray:
        """The least-squares objective of whitened residuals ``r`` (P, R): their squared sum over
        (R - 1), +inf where it is not finite."""
        total = np.einsum("pr,pr->p", r, r) / max(self.n_residuals - 1, 1)
        return np.where(np.isfinite(total), total, np.inf)

    def whitened_offsets(self, offsets: Mapping[str, np.ndarray]) -> np.ndarray:
        """(P, R) the eps of data perturbations in :func:`recal.solve.surrogate.data_noise`'s form,
        in the order of :meth:`residuals` (each N(0, 1) whitened residual's offset)."""
        parts = []
        for n in self.invariant_names:
            scale = 1.0 if n in LINEAR_INVARIANTS else 2.0 * self.reference(n)
            parts.append(offsets[n] / (scale * self.sigma[n]))
        return np.concatenate(parts, axis=1)
