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

from collections.abc import Callable
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


#: The whitened phase's directions are searched in independent blocks of at most this many, as
#: the seed's phases search a category of 3 to 6 coefficients at a time (see :class:`Phase`).
WHITENED_BLOCK = 3


@dataclass(frozen=True)
class Phase:
    """Directions ``transform`` (D, d) searched from initial Visual ``visual`` ((d,) or (R, d)
    per run). ``blocks`` > 0: the objective is separable into consecutive blocks of at most that
    many directions (no cross terms between blocks, as in whitened coordinates, where a
    Gauss-Newton model's Hessian is the identity), so a solver may search the blocks side by
    side, each as a swarm of its own; 0: search the directions jointly."""

    name: str
    transform: np.ndarray  # (D, d)
    visual: np.ndarray  # (d,) or (R, d) per run
    blocks: int = 0


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
    jacobian_along: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Phase:
    """Joint phase over the observable directions, in coordinates where 1 unit = 1 sigma.

    With J_B the whitened Jacobian along the observable basis, J_B = U S W^T, the swarm searches
    y with theta = theta + (typical * basis) W S^-1 y, so chi^2 ~ chi^2_min + |y - y*|^2.
    The initial Visual is ``visual_sigmas`` x the typical change expressed in those units (s),
    capped per run by the distance the current objective allows: the swarm objective is
    chi^2 / (R - 1) (the least squares; ~chi^2 / (M - 1) for eq. 14,
    :attr:`recal.solve.problem.Problem.objective_dof`), so |y - y*| <= sqrt(dof * objective).
    ``jacobian_along``: the whitened residuals' Jacobian along given directions at ``theta``
    when the caller has a model of them (a swarm's Gauss-Newton model: the phase is then
    whitened for that very model, whose Hessian becomes the identity); default: central
    differences of ``problem``.
    """
    T = typical[:, None] * report.basis
    J = jacobian(problem, theta, T.T) if jacobian_along is None else jacobian_along(T.T)
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
    return Phase("observable (whitened)", transform, visual, WHITENED_BLOCK)
