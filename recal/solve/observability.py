"""What a set of static positions can show: rank, condition and held directions of the Jacobian.

A norm is unchanged by any rotation of a triad's frame, so norms alone cannot see the
antisymmetric part of E (docs/reference.md#norms); a hull-fixed IMU turning only in heading cannot
separate the vertical axis's scale from its bias. Neither is decided by counting positions
(docs/reference.md#norms: rank decides): this module takes the whitened Jacobian J (R x D), each
parameter scaled by its typical change (:attr:`recal.model.terms.Term.typical`), and calls a direction
observable when

* its singular value is above ``rcond`` x the largest (not structurally null), and
* it is at least ``info_min``: the data pin the direction down better than its typical change.
  This needs the real noise; before it is known, :func:`analyze` is called with
  ``info_min=0`` and judges structural rank only.

Where coefficient groups trade off, the earlier group wins (:data:`PRIORITY`): scale and bias
first, then misalignment, then quadratic, then every other effect. Each group's columns are
projected onto the orthogonal complement of the residual-space span already claimed by earlier
groups before their SVD. On six faces, for instance, b and K2 enter a norm identically, so the
bias is estimated and K2 held at the prior. On rich designs the observable span is the same as
the plain SVD's (the complement of the rotational nulls).

The Jacobian is taken with misalignment terms at zero (``Term.linearize_at_zero``), where the
rotational null directions are exact; at E != 0 they are only null to O(E). Cost and memory are
O(R D^2) and O(R D): only economy SVDs, never an R x R matrix.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from recal.model.error_model import ParameterLayout
from recal.solve.problem import Problem

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


#: Coefficient groups in priority order; terms of any other group (the effects) come last.
PRIORITY: tuple[tuple[str, ...], ...] = (("scale", "bias"), ("misalignment",), ("quadratic",))
PRIORITY_NAMES = ("scale and bias", "misalignment", "quadratic", "effects")


def priority_groups(layout: ParameterLayout) -> list[tuple[str, np.ndarray]]:
    """(group label, flat parameter indices) in priority order, both triads together, empty
    groups dropped."""
    rank = np.array(
        [next((i for i, g in enumerate(PRIORITY) if t.group in g), len(PRIORITY))
         for t in layout.term_of()]
    )  # fmt: skip
    return [
        (PRIORITY_NAMES[i], np.flatnonzero(rank == i))
        for i in range(len(PRIORITY) + 1)
        if np.any(rank == i)
    ]


@dataclass(frozen=True)
class ObservabilityReport:
    """Result of :func:`analyze`.

    ``basis`` (D, k) spans the observable directions in typical-scaled coordinates
    (theta = theta_ref + typical * (basis @ z)); ``null`` (D, D - k) the held ones, with
    ``held_reasons`` saying why each is held. ``singular_values`` are the priority-ordered ones
    (each group's after projecting out the earlier groups), sorted. ``redundancy`` = R - rank:
    0 means exactly determined (the residual cannot check the fit). ``noise_decided`` is False
    when only structural rank was judged (noise not known yet or not estimable).
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
    held_reasons: list[str] = field(default_factory=list)
    redundancy: int = 0
    noise_decided: bool = True

    def to_json_dict(self) -> dict:
        criterion = (
            "typical-scaled whitened Jacobian at the solution with misalignment at zero, groups "
            "in priority order (scale and bias, misalignment, quadratic, effects; each projected "
            f"off the earlier groups' span); observable when s >= {INFO_MIN} and "
            f"s >= {RCOND:g} * s_max"
        )
        if not self.noise_decided:
            criterion += (
                f"; noise unknown and not estimable, so only structural rank was judged "
                f"(s >= {RCOND:g} * s_max)"
            )
        return {
            "verdict": self.verdict,
            "message": self.message,
            "rank": self.rank,
            "parameters": len(self.names),
            "redundancy": self.redundancy,
            "exactly_determined": self.redundancy == 0,
            "condition": self.condition,
            "singular_values": [float(s) for s in self.singular_values],
            "held_directions": self.held_directions,
            "held": [
                {"direction": d, "reason": r}
                for d, r in zip(self.held_directions, self.held_reasons, strict=True)
            ],
            "partially_held": [
                n for n, e, sh in zip(self.names, self.estimated, self.share) if e and sh < 0.99
            ],
            "criterion": criterion,
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


def _group_svd(Jp: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Economy SVD of an (R, k) block with a complete (k, k) right basis even when R < k."""
    R, k = Jp.shape
    if R < k:  # zero rows add nothing but give V its missing (null) rows
        Jp = np.vstack([Jp, np.zeros((k - R, k))])
    U, s, Vt = np.linalg.svd(Jp, full_matrices=False)
    return U[:R], s, Vt


#: Held-direction reason for a rotation of a triad's frame, which no norm can see.
ROTATION_REASON = "a rotation of the frame: no norm can see it (docs/reference.md#norms)"
#: With slews: the rotation of both triads together relative to the case, which no invariant
#: sees without an outside reference; the accelerometer frame is the reference.
COMMON_ROTATION_REASON = (
    "a rotation of both triads together relative to the case: no invariant sees it without an "
    "outside reference; held with the accelerometer frame as the reference"
)
_ANTISYMMETRIC_PAIRS = (("Exz", "Eyz"), ("Exy", "Ezy"), ("Eyx", "Ezx"))


def _weak_rotation_reason(seen: float) -> str:
    """Why a frame rotation the slews do see (``seen``: whitened change per typical change,
    beyond the directions estimated before it) is still held."""
    return (
        "a rotation of the gyro frame relative to the accelerometer frame: only the slews see "
        f"it, and they pin it down only to {1 / max(seen, 1e-300):.2g}x its typical change "
        "(needs 1x or better)"
    )


def rotation_span(layout: ParameterLayout) -> np.ndarray:
    """Orthonormal (D, 3 per triad) span of the antisymmetric misalignments, to first order the
    rotations of each triad's frame."""
    names = layout.names
    cols = []
    for m in layout.models:
        for a, b in _ANTISYMMETRIC_PAIRS:
            ia, ib = f"{m.sensor}.misalignment.{a}", f"{m.sensor}.misalignment.{b}"
            if ia in names and ib in names:
                c = np.zeros(layout.size)
                c[names.index(ia)], c[names.index(ib)] = 1.0, -1.0
                cols.append(c / np.sqrt(2.0))
    return np.array(cols).T if cols else np.zeros((layout.size, 0))


def accel_rotation_span(layout: ParameterLayout) -> np.ndarray:
    """The accelerometer's columns of :func:`rotation_span`: with slews, the common rotation of
    both triads is held there (the accelerometer frame is the reference)."""
    span = rotation_span(layout)
    names = layout.names
    accel = np.array([n.startswith("accel.") for n in names])
    cols = [c for c in span.T if np.all(c[~accel] == 0)] if span.size else []
    return np.array(cols).T if cols else np.zeros((layout.size, 0))


def _split_rotations(held: np.ndarray, rotations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split an orthonormal held basis (D, h) into its part inside the rotation span and the
    rest, each varimax-rotated to readable combinations."""
    if held.shape[1] == 0 or rotations.shape[1] == 0:
        return held[:, :0], varimax(held)
    u, c, _ = np.linalg.svd(held.T @ rotations, full_matrices=True)
    c = np.concatenate([c, np.zeros(held.shape[1] - c.size)])
    inside = c > 1 - 1e-6
    return varimax(held @ u[:, inside]), varimax(held @ u[:, ~inside])


def _held_reason(
    earlier: list[str],
    alone: float,
    projected: float,
    structural: float,
    info_min: float,
    no_equations_left: bool,
    n_equations: int,
) -> str:
    """Why a direction is held (other than a rotation): invisible on these positions, no
    equations left, traded off against an earlier group, or pinned down less well than its
    typical change."""
    if alone < structural:
        return "no invariant changes along it on these positions"
    if projected < structural and no_equations_left:
        return (
            f"all {n_equations} invariant equations are taken by the directions estimated "
            "before it; more positions would show it"
        )
    if projected < structural or (projected < info_min <= alone):
        return f"on these positions it acts like {' and '.join(earlier)}, which are preferred"
    return (
        f"the data pin it down only to {1 / max(projected, 1e-300):.2g}x its typical change "
        "(needs 1x or better)"
    )


def analyze(
    problem: Problem,
    theta: np.ndarray,
    typical: np.ndarray,
    rcond: float = RCOND,
    info_min: float = INFO_MIN,
) -> ObservabilityReport:
    """Observability of every parameter of ``problem`` at ``theta`` (D,).

    ``info_min=0`` judges structural rank only (what any noise level would allow): use it
    before the noise is known, never decide on a provisional sigma.
    """
    layout = problem.layout
    names = layout.names
    D = layout.size
    theta_lin = np.where(layout.linearization_mask(), layout.neutral(), theta)
    J = jacobian(problem, theta_lin, np.diag(typical))  # (R, D)
    R = J.shape[0]
    s_max = float(np.linalg.svd(J, compute_uv=False)[0]) if D and R else 0.0
    structural = max(rcond * s_max, 1e-300)
    threshold = max(structural, info_min)
    rotations = rotation_span(layout)
    # with slews the relative rotation of the triads is seen, their common rotation is not: hold
    # it in the accelerometer's antisymmetric misalignment (rows of the forced-held columns)
    # (known rotations, an outside reference, show it: nothing is forced then)
    relative_only = "slew" in problem.invariant_names and "rotation" not in problem.invariant_names
    motion = bool({"slew", "rotation", "closure"} & set(problem.invariant_names))
    forced = accel_rotation_span(layout) if relative_only else np.zeros((D, 0))
    Q = np.zeros((R, 0))  # orthonormal residual-space span claimed so far
    basis_cols, null_cols, reasons, s_kept, s_held = [], [], [], [], []
    earlier: list[str] = []
    for label, idx in priority_groups(layout):
        Jg = J[:, idx]
        fixed = forced[idx][:, np.any(forced[idx] != 0, axis=0)] if forced.size else forced[idx]
        if fixed.shape[1]:
            # search only the complement of the forced-held columns within the group
            C = np.linalg.svd(fixed, full_matrices=True)[0][:, fixed.shape[1] :]
            U, s, Vt = _group_svd((Jg - Q @ (Q.T @ Jg)) @ C)
            Vg = C @ Vt.T
            held = np.zeros((D, fixed.shape[1]))
            held[idx] = fixed
            null_cols.append(held)
            reasons += [COMMON_ROTATION_REASON] * fixed.shape[1]
            s_held.append(np.zeros(fixed.shape[1]))  # held by construction
        else:
            U, s, Vt = _group_svd(Jg - Q @ (Q.T @ Jg))
            Vg = Vt.T
        keep = s >= threshold
        Q = np.hstack([Q, U[:, keep]])
        V = np.zeros((D, Vg.shape[1]))
        V[idx] = Vg
        basis_cols.append(V[:, keep])
        s_kept.append(s[keep])
        rot, other = _split_rotations(V[:, ~keep], rotations)
        null_cols += [rot, other]
        s_held.append(s[~keep])
        for v in rot.T:  # with slews a frame rotation is seen, only perhaps too weakly
            seen = float(np.linalg.norm(Jg @ v[idx] - Q @ (Q.T @ (Jg @ v[idx]))))
            reasons.append(
                _weak_rotation_reason(seen) if motion and seen >= structural else ROTATION_REASON
            )
        full = Q.shape[1] >= R  # every equation already taken
        for v in other.T:
            alone = float(np.linalg.norm(Jg @ v[idx]))
            projected = float(np.linalg.norm(Jg @ v[idx] - Q @ (Q.T @ (Jg @ v[idx]))))
            reasons.append(_held_reason(earlier, alone, projected, structural, info_min, full, R))
        earlier.append(label)
    basis = np.hstack(basis_cols) if basis_cols else np.zeros((D, 0))
    null = np.hstack(null_cols) if null_cols else np.zeros((D, 0))
    kept = np.concatenate(s_kept) if s_kept else np.zeros(0)
    s_all = np.sort(np.concatenate([kept, *s_held]))[::-1] if D else np.zeros(0)
    share = np.sum(basis**2, axis=1)
    estimated = share >= ESTIMATED_SHARE
    held = [_label(null[:, j], names) for j in range(null.shape[1])]
    rank = basis.shape[1]
    cond = float(s_max / kept.min()) if rank else float("inf")
    # scale and bias must be seen: without them there is nothing to recalibrate
    core = np.array([t.group in PRIORITY[0] for t in layout.term_of()])
    blind = [f"{n} ({100 * sh:.0f} % seen)"
             for n, c, sh in zip(names, core, share, strict=True) if c and sh < 1 - 0.1]  # fmt: skip
    if blind:
        verdict = "insufficient"
        message = (
            f"the positions cannot fully separate {', '.join(blind)} "
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
        names, s_all, rank, cond, basis, null, estimated, share, held, verdict, message,
        reasons, R - rank, info_min > 0,
    )  # fmt: skip
