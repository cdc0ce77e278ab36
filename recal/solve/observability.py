"""What a set of static positions can show: rank, condition and held directions of the Jacobian.

A norm is unchanged by any rotation of a triad's frame, so norms alone cannot see the
antisymmetric part of E (docs/reference.md#norms); a hull-fixed IMU turning only in heading cannot
separate the vertical axis's scale from its bias. Neither is decided by counting positions
(docs/reference.md#norms: rank decides): this module takes the whitened Jacobian J (R x D), each
parameter scaled by its typical change (:attr:`recal.model.terms.Term.typical`), and calls a direction
observable when

* its singular value is above ``rcond`` x the largest (not structurally null), and
* it is at least ``info_min``: the data pin the direction down better than its typical change
  (for a scale factor or bias: better than the larger of its typical change and a stated
  prior's 1-sigma, ``bar``; data that beat a loose prior improve on holding it).
  This needs the real noise; before it is known, :func:`analyze` is called with
  ``info_min=0`` and judges structural rank only.

What is estimated is decided per coefficient, and a coefficient no estimated direction touches
is "held": it stays exactly at its prior, and its prior uncertainty reaches the estimated ones
through the consider covariance (:mod:`recal.solve.consider`). Where coefficients trade off, the
earlier group wins (:data:`PRIORITY`): scale and bias first, then misalignment, then quadratic,
then every other effect; each group is projected off the residual-space span the earlier ones
claimed. Scale factors and biases, what a navigator asks about, are held one at a time (a
backward elimination): while one of them, estimated with the others, is pinned down less well
than ``info_min``, the one the data improve least on its prior (its prior 1-sigma over the
data's) is held, as a whole. A hull-fixed gyro's vertical bias is thus estimated and its
vertical scale factor held (before, both moved along their one visible combination while the
scale factor was reported "held"). The other groups keep directions, by the SVD of their block
in :func:`coordinates` (each misalignment pair as its sum, which a norm sees, and difference, to
first order a rotation of the frame, which only the dot product or the slews see): two triads'
common rotation is one direction, slews see sums and rotations together, a g-sensitivity matrix
shows combinations. A coefficient there is "estimated" when an estimated direction touches it
(partly, ``share`` < 1), else held. On six faces, for instance, b and K2 enter a norm
identically, so the bias is estimated and K2 held. On rich designs the observable span is the
plain SVD's (the complement of the rotational nulls).

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
    ``held_reasons`` saying why each is held. A coefficient whose row of ``basis`` is zero is
    held (``estimated`` False) and stays exactly at the prior. ``singular_values`` are the
    priority-ordered ones (each coordinate's or rotation's after projecting out what was
    estimated before it), sorted. ``redundancy`` = R - rank:
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
            "typical-scaled whitened Jacobian at the solution with misalignment at zero, per "
            "coordinate (each coefficient; misalignment pairs as sum and frame rotation) in "
            "priority order (scale and bias, misalignment, quadratic, effects; each projected "
            f"off what was estimated before it); observable when s >= {INFO_MIN} and "
            f"s >= {RCOND:g} * s_max; a held coefficient stays exactly at the prior"
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


def _split_rotations(held: np.ndarray, rotations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split an orthonormal held basis (D, h) into its part inside the rotation span (D, r) and
    the rest, each varimax-rotated to readable combinations."""
    if held.shape[1] == 0 or rotations.shape[1] == 0:
        return held[:, :0], varimax(held)
    u, c, _ = np.linalg.svd(held.T @ rotations, full_matrices=True)
    c = np.concatenate([c, np.zeros(held.shape[1] - c.size)])
    inside = c > 1 - 1e-6
    return varimax(held @ u[:, inside]), varimax(held @ u[:, ~inside])


def _coordinate_name(v: np.ndarray, names: list[str]) -> str:
    """A coordinate of :func:`coordinates` by name: one coefficient, or a misalignment pair's
    sum ``accel.misalignment.Exz+Eyz`` or difference ``...Exz-Eyz``."""
    nz = np.flatnonzero(v)
    if nz.size == 1:
        return names[int(nz[0])]
    a, b = (int(i) for i in nz[:2])
    return f"{names[a]}{'+' if v[a] * v[b] > 0 else '-'}{names[b].rsplit('.', 1)[1]}"


def _held_reason(
    earlier: list[str],
    alone: float,
    projected: float,
    before_group: float,
    structural: float,
    info_min: float,
    no_equations_left: bool,
    n_equations: int,
    partners: list[str],
) -> str:
    """Why a coordinate is held (other than a rotation): invisible on these positions, no
    equations left, traded off against an earlier group (``before_group``: what is left of it
    beyond the earlier groups) or against ``partners`` of its own group estimated in its place,
    or pinned down less well than its typical change."""
    threshold = max(structural, info_min)
    if alone < structural:
        return "no invariant changes along it on these positions"
    if projected < structural and no_equations_left:
        return (
            f"all {n_equations} invariant equations are taken by the directions estimated "
            "before it; more positions would show it"
        )
    if alone >= threshold > projected:
        if earlier and before_group < threshold:
            return f"on these positions it acts like {' and '.join(earlier)}, which are preferred"
        if partners:
            return (
                f"on these positions it acts like {' and '.join(partners)}, estimated in its "
                "place (the one whose prior uncertainty shows more in the invariants)"
            )
        if earlier:
            return f"on these positions it acts like {' and '.join(earlier)}, which are preferred"
    return (
        f"the data pin it down only to {1 / max(projected, 1e-300):.2g}x its typical change "
        "(needs 1x or better)"
    )


def coordinates(layout: ParameterLayout) -> tuple[np.ndarray, np.ndarray]:
    """(D, D) orthonormal coordinates in which the coefficients are estimated or held, and (D,)
    True where a coordinate is a rotation of a frame.

    Every coefficient is its own coordinate, except a triad's misalignment pairs (Exz, Eyz),
    (Exy, Ezy), (Eyx, Ezx): their sum, which a norm sees, replaces the first and their
    difference, to first order a rotation of the frame (:func:`rotation_span`), the second.
    Column k belongs to coefficient k's term, so it has that term's priority group."""
    D = layout.size
    C = np.eye(D)
    rot = np.zeros(D, dtype=bool)
    names = layout.names
    h = np.sqrt(0.5)
    for m in layout.models:
        for a, b in _ANTISYMMETRIC_PAIRS:
            ia, ib = f"{m.sensor}.misalignment.{a}", f"{m.sensor}.misalignment.{b}"
            if ia in names and ib in names:
                i, j = names.index(ia), names.index(ib)
                C[i, i] = C[j, i] = C[i, j] = h
                C[j, j] = -h
                rot[j] = True
    return C, rot


def _conditional_information(P: np.ndarray, structural: float) -> np.ndarray:
    """(n,) for the columns of P (R, n), estimated together: 1 / each one's 1-sigma, i.e.
    1 / sqrt(diag((P^T P)^-1)) in typical units; about 0 for a column the others make
    dependent (singular values below ``structural`` count as that)."""
    if not P.shape[1]:
        return np.zeros(0)
    _, s, Vt = _group_svd(P)
    var = np.sum(Vt**2 / np.maximum(s, structural)[:, None] ** 2, axis=0)
    var = np.where(np.any((s < structural)[:, None] & (np.abs(Vt) > 1e-9), axis=0), np.inf, var)
    return 1.0 / np.sqrt(var)


def _orthonormal_columns(V: np.ndarray) -> np.ndarray:
    """Orthonormal columns spanning V (n, a) as linear combinations of its columns, so a row of
    V that is exactly zero stays exactly zero (a Householder QR would fill it in by rounding)."""
    if not V.shape[1]:
        return V
    _, s, Wt = np.linalg.svd(V, full_matrices=False)
    return (V @ Wt.T) / s


def _readmit(
    cand: list[int],
    dropped: list[tuple[int, float]],
    off,
    JC: np.ndarray,
    structural: float,
    threshold: float,
    bar_coord: np.ndarray,
) -> tuple[list[int], list[tuple[int, float]]]:
    """Give back, one at a time, what the backward elimination held but the data show beside
    what it kept (a forward step after the backward ones).

    The elimination drops one coefficient at a time while many are still in, and a coefficient
    that trades off with ones dropped later is lost for good: two poses, x up and x down, show
    the accelerometer's x scale and bias apart (the two norms move together with the scale and
    oppositely with the bias), but with the gyro's and the other axes' coefficients still in,
    the x scale was dropped first, and the answer lost half its estimated part (issue 36). A
    held coefficient comes back when, estimated with the kept ones, every one of them still
    passes; the best-determined first."""
    cand, dropped = list(cand), list(dropped)
    while dropped:
        best = None
        for pos, (k, _) in enumerate(dropped):
            trial = [*cand, k]
            info = _conditional_information(off(JC[:, trial]), structural)
            if np.all(info >= structural) and np.all(info * bar_coord[trial] >= threshold):
                if best is None or info[-1] > best[1]:
                    best = (pos, float(info[-1]))
        if best is None:
            break
        cand.append(dropped.pop(best[0])[0])
    return cand, dropped


#: Coefficients whose gains (prior 1-sigma over the data's) lie within this fraction of the
#: least are held in a fixed order (scale factors before biases, the layout's last first): a
#: near tie, such as a hull-fixed accelerometer's vertical scale against its bias without a
#: prior, is then decided the same way on every data set rather than by noise.
TIE = 0.1
#: Entries of an estimated rotation direction below this are finite-difference noise: they are
#: zeroed, so a coefficient the direction does not touch stays exactly at the prior.
CLEAN = 1e-6


def typical_jacobian(problem: Problem, theta: np.ndarray, typical: np.ndarray) -> np.ndarray:
    """The Jacobian :func:`analyze` judges, (R, D): along every parameter's typical change, at
    ``theta`` with the terms linearised about neutral put there (``layout.linearization_mask``)."""
    layout = problem.layout
    theta_lin = np.where(layout.linearization_mask(), layout.neutral(), theta)
    return jacobian(problem, theta_lin, np.diag(typical))


def analyze(
    problem: Problem,
    theta: np.ndarray,
    typical: np.ndarray,
    rcond: float = RCOND,
    info_min: float = INFO_MIN,
    weights: np.ndarray | None = None,
    bar: np.ndarray | None = None,
    J: np.ndarray | None = None,
) -> ObservabilityReport:
    """Observability of every parameter of ``problem`` at ``theta`` (D,).

    ``info_min=0`` judges structural rank only (what any noise level would allow): use it
    before the noise is known, never decide on a provisional sigma. ``weights`` (D,): the
    prior's 1-sigma over the typical change per parameter; where scale factors and biases trade
    off, the one the data improve least on its prior (weight x information) is held (None: all
    1). ``bar`` (D,), at least 1: a stated prior's 1-sigma over the typical change where it is
    looser (None: all 1); a scale factor or bias the data pin down better than that prior is
    estimated even when they do not reach its typical change (holding it would leave more).
    Structural rank and the other groups are decided on the typical-scaled Jacobian alone.
    ``J``: :func:`typical_jacobian` at ``theta`` when the caller has it (one analysis of a
    solution shares it with the next).
    """
    layout = problem.layout
    names = layout.names
    D = layout.size
    if J is None:
        J = typical_jacobian(problem, theta, typical)  # (R, D)
    R = J.shape[0]
    s_max = float(np.linalg.svd(J, compute_uv=False)[0]) if D and R else 0.0
    structural = max(rcond * s_max, 1e-300)
    threshold = max(structural, info_min)
    C, rot = coordinates(layout)
    JC = J @ C
    w = np.ones(D) if weights is None else np.asarray(weights, float)
    w_coord = np.sqrt((C**2).T @ np.square(w))
    b = np.ones(D) if bar is None else np.maximum(np.asarray(bar, float), 1.0)
    bar_coord = np.sqrt((C**2).T @ np.square(b))
    prefer = np.array([0 if t.group == "bias" else 1 for t in layout.term_of()])
    # with slews the relative rotation of the triads is seen, their common rotation is not: hold
    # it in the accelerometer's frame rotations (known rotations, an outside reference, show
    # it: nothing is forced then)
    relative_only = "slew" in problem.invariant_names and "rotation" not in problem.invariant_names
    motion = bool({"slew", "rotation", "closure"} & set(problem.invariant_names))
    Q = np.zeros((R, 0))  # orthonormal residual-space span claimed so far

    def off(X: np.ndarray) -> np.ndarray:  # X projected off Q (twice: Gram-Schmidt stability)
        X = X - Q @ (Q.T @ X)
        return X - Q @ (Q.T @ X)

    basis_cols, null_cols, reasons, s_kept, s_held = [], [], [], [], []
    earlier: list[str] = []
    for label, idx in priority_groups(layout):
        q0 = Q.shape[1]
        rk = [int(k) for k in idx if rot[k]]
        if label != PRIORITY_NAMES[0]:
            # misalignment, quadratic, effects: directions, by the SVD of the group's
            # coordinates (two triads' common rotation is one direction, slews see a rotation
            # and a sum together, a g-sensitivity matrix shows combinations); forced-held
            # rotations left out
            forced = [k for k in rk if relative_only and names[k].startswith("accel.")]
            free = [int(k) for k in idx if k not in forced]
            for k in forced:
                null_cols.append(C[:, [k]])
                reasons.append(COMMON_ROTATION_REASON)
                s_held.append(0.0)  # held by construction
            _, s, Vt = _group_svd(off(JC[:, free]))
            keep = s >= threshold
            Vk = Vt.T[:, keep].copy()
            Vk[np.abs(Vk) < CLEAN] = 0.0
            Vk = _orthonormal_columns(Vk)
            Vh = np.linalg.svd(Vk, full_matrices=True)[0][:, Vk.shape[1] :] if Vk.shape[1] else (
                np.eye(len(free)))  # fmt: skip
            Cf = C[:, free]
            if Vk.shape[1]:
                Q = np.hstack([Q, _orthonormal_columns(off(JC[:, free] @ Vk))])
            basis_cols.append(Cf @ Vk)
            s_kept.extend(float(v) for v in s[keep])
            s_held.extend(float(v) for v in s[~keep])
            turn, other = _split_rotations(Cf @ Vh, C[:, rk])
            null_cols += [turn, other]
            for v in turn.T:  # with slews a frame rotation is seen, only perhaps too weakly
                seen = float(np.linalg.norm(off((J @ v)[:, None])))
                reasons.append(
                    _weak_rotation_reason(seen)
                    if motion and seen >= structural
                    else ROTATION_REASON
                )
            full = Q.shape[1] >= R
            Qe = Q[:, :q0]
            for v in other.T:
                x = J @ v
                alone = float(np.linalg.norm(x))
                projected = float(np.linalg.norm(off(x[:, None])))
                before = float(np.linalg.norm(x - Qe @ (Qe.T @ x)))
                reasons.append(_held_reason(earlier, alone, projected, before, structural,
                                            info_min, full, R, []))  # fmt: skip
            earlier.append(label)
            continue
        # scale factors and biases one at a time: while one is pinned down less well than its
        # typical change (estimated with the others), hold the one the data improve least on
        # its prior
        cand = [int(k) for k in idx]
        dropped: list[tuple[int, float]] = []  # (coordinate, its information when dropped)
        while cand:
            info = _conditional_information(off(JC[:, cand]), structural)
            # where a stated prior is looser than the typical change, data that beat the prior
            # improve on holding it: the bar is the larger of the two (never below structural)
            if np.all(info >= structural) and np.all(info * bar_coord[cand] >= threshold):
                break
            gain = info * w_coord[cand]
            near = np.flatnonzero(gain <= gain.min() / (1.0 - TIE))
            j = int(max(near, key=lambda i: (prefer[cand[i]], cand[i])))
            dropped.append((cand.pop(j), float(info[j])))
        cand, dropped = _readmit(cand, dropped, off, JC, structural, threshold, bar_coord)
        basis_cols.append(C[:, cand])
        if cand:
            s_kept.extend(float(v) for v in _conditional_information(off(JC[:, cand]), structural))
            Q = np.hstack([Q, _orthonormal_columns(off(JC[:, cand]))])
        full = Q.shape[1] >= R  # every equation already taken
        Qe = Q[:, :q0]
        for k, info_k in dropped:
            x = JC[:, k]
            alone = float(np.linalg.norm(x))
            before = float(np.linalg.norm(x - Qe @ (Qe.T @ x)))
            cos = [abs(float(x @ JC[:, c])) / max(alone * np.linalg.norm(JC[:, c]), 1e-300)
                   for c in cand]  # fmt: skip
            partners = [_coordinate_name(C[:, c], names) for c, v in zip(cand, cos, strict=True)
                        if v >= 0.5 * max(cos)] if cos else []  # fmt: skip
            null_cols.append(C[:, [k]])
            s_held.append(info_k)
            reasons.append(_held_reason(earlier, alone, info_k, before, structural, info_min,
                                        full, R, partners))  # fmt: skip
        earlier.append(label)
    basis = np.hstack(basis_cols) if basis_cols else np.zeros((D, 0))
    null = np.hstack(null_cols) if null_cols else np.zeros((D, 0))
    kept = np.array(s_kept)
    s_all = np.sort(np.concatenate([kept, np.array(s_held)]))[::-1] if D else np.zeros(0)
    share = np.sum(basis**2, axis=1)
    # a coefficient no estimated coordinate touches stays exactly at the prior: "held"
    estimated = np.any(basis != 0.0, axis=1)
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
