"""Phases: which parameter directions a swarm searches, and in which order.

Seed 000 section 3.3.2 and seed 002 section 5.3.2 search one category at a time -- scale, then
bias, then misalignment (then quadratic) -- with the other categories preset from a prior
coefficient set, and repeat the phases until the indicator threshold, the iteration cap or a
stall. A :class:`Phase` is a set of directions in parameter space (``transform`` (D, d), so
theta = base + transform @ x) and the swarm's initial per-dimension Visual (d,).

* :func:`paper_phases`: the seed's categories in raw parameter coordinates, Visual from seed 000
  Table 1 for the gyro (typical changes elsewhere). Every misalignment is searched, including the
  three rotational directions no norm can see.
* :func:`whitened_phase`: the project default -- one joint phase over the observable directions
  only, rotated and scaled so the objective's Hessian is ~identity (noise-whitened). The held
  directions stay at the prior.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recal.model.error_model import ParameterLayout
from recal.solve.observability import ObservabilityReport, jacobian
from recal.solve.problem import Problem

#: Seed 000 Table 1, the per-dimension Visual of each FOG category (scale in counts per deg/h,
#: bias in deg/h, misalignment dimensionless).
SEED_000_TABLE1_VISUAL = {
    "gyro.scale": np.array([5.0, 2.0, 0.1]),
    "gyro.bias": np.array([0.005, 0.002, 0.0001]),
    "gyro.misalignment": np.array([0.0005, 0.0002, 0.00001, 0.000005, 0.000002, 0.000001]),
}
#: The seed's phase order.
CATEGORY_ORDER = ("scale", "bias", "misalignment", "quadratic")


@dataclass(frozen=True)
class Phase:
    name: str
    transform: np.ndarray  # (D, d)
    visual: np.ndarray  # (d,) or (R, d) per run


def paper_phases(layout: ParameterLayout, typical: np.ndarray) -> list[Phase]:
    """One phase per category in the seed's order, then each extra effect; triads interleaved."""
    D = layout.size
    slices = layout.term_slices()
    terms = [t for m in layout.models for t in m.terms]
    order = {c: i for i, c in enumerate(CATEGORY_ORDER)}
    groups: dict[str, list] = {}
    for t in terms:
        groups.setdefault(t.group, []).append(t)
    phases = []
    for group in sorted(groups, key=lambda g: order.get(g, len(order))):
        for t in groups[group]:
            sl = slices[t.name]
            idx = np.arange(sl.start, sl.stop)
            transform = np.zeros((D, idx.size))
            transform[idx, np.arange(idx.size)] = 1.0
            visual = SEED_000_TABLE1_VISUAL.get(t.name, typical[sl])
            phases.append(Phase(t.name, transform, np.asarray(visual, float)))
    return phases


def whitened_phase(
    problem: Problem,
    theta: np.ndarray,
    typical: np.ndarray,
    report: ObservabilityReport,
    objective_now: np.ndarray | None = None,
    visual_sigmas: float = 3.0,
) -> Phase:
    """Joint phase over the observable directions, in coordinates where 1 unit = 1 sigma.

    With J_B the whitened Jacobian along the observable basis, J_B = U S W^T, the swarm searches
    y with theta = theta + (typical * basis) W S^-1 y, so chi^2 ~ chi^2_min + |y - y*|^2.
    The initial Visual is ``visual_sigmas`` x the typical change expressed in those units (s),
    capped per run by the distance the current objective allows: the swarm objective is
    chi^2 / (R - 1) (the least squares; ~chi^2 / (M - 1) for eq. 14,
    :attr:`recal.solve.problem.Problem.objective_dof`), so |y - y*| <= sqrt(dof * objective).
    """
    T = typical[:, None] * report.basis
    J = jacobian(problem, theta, T.T)
    _, s, Wt = np.linalg.svd(J, full_matrices=False)
    s = np.maximum(s, 1e-12 * s.max())
    transform = T @ Wt.T / s
    # each direction's sign fixed (largest entry in typical units positive), so the search
    # does not depend on how the observable span happens to be spanned
    lead = np.argmax(np.abs(transform / typical[:, None]), axis=0)
    transform *= np.sign(transform[lead, np.arange(transform.shape[1])])
    visual = visual_sigmas * np.maximum(s, 1.0)
    if objective_now is not None:
        radius = 1.5 * np.sqrt(problem.objective_dof * np.asarray(objective_now, float))
        visual = np.minimum(visual[None, :], np.maximum(radius, 1.0)[:, None])
    return Phase("observable (whitened)", transform, visual)
