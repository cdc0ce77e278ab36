"""What a set of static positions can show: Jacobian SVD, rank, condition, held directions.

A norm is unchanged by any rotation of a triad's frame, so norms alone cannot see the
antisymmetric part of E (conventions section 3); a hull-fixed IMU turning only in heading cannot
separate the vertical axis's scale from its bias. Neither is decided by counting positions: this
module takes the SVD of the whitened Jacobian, with each parameter scaled by its typical change
(:attr:`recal.terms.Term.typical`), and calls a direction observable when

* its singular value is above ``rcond`` x the largest (not structurally null), and
* it is at least ``info_min``: the data pin the direction down better than its typical change.

The Jacobian is taken with misalignment terms at zero (``Term.linearize_at_zero``), where the
rotational null directions are exact; at E != 0 they are only null to O(E).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recal.problem import Problem

#: Relative singular-value threshold for a structurally null direction.
RCOND = 1e-7
#: A direction is estimated when the data determine it to within its typical change (s >= 1).
INFO_MIN = 1.0
#: A parameter counts as estimated when this share of it lies in the observable subspace.
ESTIMATED_SHARE = 0.25
#: Finite-difference step in units of the typical change (the residuals are near-linear).
FD_STEP = 1e-3


def jacobian(problem: Problem, theta: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Whitened residual Jacobian along ``directions`` (k, D) in parameter space, shape (R, k).

    Central differences, all 2k points evaluated in one batched call.
    """
    k = directions.shape[0]
    pts = np.concatenate([theta + FD_STEP * directions, theta - FD_STEP * directions])
    r = problem.residuals(pts)
    return (r[:k] - r[k:]).T / (2.0 * FD_STEP)


@dataclass(frozen=True)
class ObservabilityReport:
    """Result of :func:`analyze`.

    ``basis`` (D, k) spans the observable directions in typical-scaled coordinates
    (theta = theta_ref + typical * (basis @ z)); ``null`` (D, D - k) the held ones.
    """

    names: list[str]
    singular_values: np.ndarray
    rank: int
    condition: float
    basis: np.ndarray
    null: np.ndarray
    estimated: np.ndarray  # (D,) bool
    share: np.ndarray  # (D,) fraction of each parameter inside the observable subspace
    held_directions: list[str]
    verdict: str  # "full", "partial" or "insufficient"
    message: str

    def to_json_dict(self) -> dict:
        return {
            "verdict": self.verdict,
            "message": self.message,
            "rank": self.rank,
            "parameters": len(self.names),
            "condition": self.condition,
            "singular_values": [float(s) for s in self.singular_values],
            "held_directions": self.held_directions,
            "partially_held": [
                n for n, e, sh in zip(self.names, self.estimated, self.share) if e and sh < 0.99
            ],
            "criterion": (
                f"typical-scaled whitened Jacobian SVD at the solution with misalignment at zero; "
                f"observable when s >= {INFO_MIN} and s >= {RCOND:g} * s_max"
            ),
        }


def varimax(basis: np.ndarray, iterations: int = 50) -> np.ndarray:
    """Rotate an orthonormal basis (D, n) within its span towards sparse columns (varimax), so
    held directions read as simple combinations such as ``Exz - Eyz``."""
    D, n = basis.shape
    if n < 2:
        return basis
    R = np.eye(n)
    for _ in range(iterations):
        L = basis @ R
        u, _, vt = np.linalg.svd(basis.T @ (L**3 - L @ np.diag(np.sum(L**2, axis=0)) / D))
        R_new = u @ vt
        if np.allclose(R_new, R, atol=1e-12):
            break
        R = R_new
    return basis @ R


def _label(vec: np.ndarray, names: list[str]) -> str:
    idx = np.argsort(-np.abs(vec))
    big = [i for i in idx if abs(vec[i]) >= 0.1 * np.abs(vec).max()][:4]
    sign = 1.0 if vec[big[0]] > 0 else -1.0
    return " ".join(f"{sign * vec[i]:+.2f}*{names[i]}" for i in big)


def analyze(
    problem: Problem,
    theta: np.ndarray,
    typical: np.ndarray,
    rcond: float = RCOND,
    info_min: float = INFO_MIN,
) -> ObservabilityReport:
    """Observability of every parameter of ``problem`` at ``theta`` (D,)."""
    layout = problem.layout
    names = layout.names
    D = layout.size
    theta_lin = np.where(layout.linearization_mask(), layout.neutral(), theta)
    J = jacobian(problem, theta_lin, np.diag(typical))
    _, s, Vt = np.linalg.svd(J, full_matrices=True)
    s_full = np.zeros(D)
    s_full[: len(s)] = s
    s_max = s_full.max() if D else 0.0
    keep = (s_full >= max(rcond * s_max, info_min)) & (s_full > 0)
    basis, null = Vt[keep].T, varimax(Vt[~keep].T)
    share = np.sum(basis**2, axis=1)
    estimated = share >= ESTIMATED_SHARE
    held = [_label(null[:, j], names) for j in range(null.shape[1])]
    rank = int(keep.sum())
    cond = float(s_max / s_full[keep].min()) if rank else float("inf")
    # scale and bias must be seen: without them there is nothing to recalibrate
    core = np.array([t.group in ("scale", "bias") for t in layout.term_of()])
    blind = [n for n, c, sh in zip(names, core, share, strict=True) if c and sh < 1 - 0.1]
    if blind:
        verdict = "insufficient"
        message = (
            f"the positions cannot separate {', '.join(blind)} "
            f"(rank {rank} of {D}); add orientations that tilt those axes"
        )
    elif rank == D:
        verdict, message = "full", f"all {D} coefficients observable"
    else:
        verdict = "partial"
        message = (
            f"{rank} of {D} directions observable; {D - rank} held at the prior: " + "; ".join(held)
        )
    return ObservabilityReport(
        names, s_full, rank, cond, basis, null, estimated, share, held, verdict, message
    )


def generic_rank(problem: Problem) -> int:
    """Identifiable directions for a rich design: 3 rotational nulls per triad, the dot product
    leaving only the common rotation."""
    nulls = 3 * len(problem.models)
    if "dot" in problem.invariant_names:
        nulls -= 3
    return problem.layout.size - nulls
