"""Downsampling a slew: its gyro samples reduced to group sums (S_g, W_g, C_g) that keep the
second-order rotation exact, and the exact algebra on those sums (joining consecutive groups,
shifting the reference). Vectorised over the samples.

The method (the slew invariant; the pieces: :mod:`recal.detect.slew_data` the data and its side
file, :mod:`recal.detect.slew_collect` collection from a stream, :mod:`recal.detect.quaternions`
and :mod:`recal.detect.slew_rotation` the integration, :mod:`recal.detect.slew_gravity` the
residuals, :mod:`recal.detect.known_rotations`, :mod:`recal.detect.closed_turns`,
:mod:`recal.detect.slew_gauge`).

The slew invariant: the gyro, integrated over the motion between two static windows, must carry
the gravity direction measured in the first window onto the one measured in the next.

Norms cannot see a rotation of a triad's frame (docs/reference.md#norms). Integrating the gyro over
each slew (the samples between two consecutive windows) can: the integrated rotation, applied to
the calibrated accelerometers' gravity direction of window k, predicts the direction of window
k + 1, and the two must agree (Tedaldi et al., ICRA 2014, the method of imu_tk). The residual has
2 degrees of freedom per slew (a rotation about the vertical moves no gravity direction).

Data (what ``recal positions`` keeps beside the CSV, :meth:`Slews.to_npz_bytes`): per slew the
indices of its two windows, the sample period, the window-k gyro output ``N_ref`` and, over ``G``
groups of consecutive samples (G = :data:`DEFAULT_GROUPS`, padded with empty groups), three sums
of the output increments ``n_i = (N_i - N_ref) dt`` (output units x s):

    S_g = sum_i n_i,   W_g = sum_i (m_g - 1 - 2 i) n_i,   C_g = 1/2 sum_{i<j} n_i x n_j

Because the gyro model is affine in its output (``alpha_i = M n_i + c``, with
``M = u A^-1 diag(1/K)``, ``c = u A^-1 (N_ref / K - b) dt`` and ``u`` = deg/h -> rad/s), the
second-order (Bortz / BCH) rotation vector of a group, ``sum alpha_i + 1/2 sum_{i<j} alpha_i x
alpha_j``, is exactly

    phi_g = M S_g + m_g c + 1/2 (M W_g) x c + cof(M) C_g,    cof(M) = det(M) M^-T

for every parameter vector: the per-sample coning correction survives the downsampling, and the
engine integrates ``G`` increments per slew instead of every sample. The groups' quaternions are
multiplied by a pairwise (tree) product: log2(G) vectorised steps for all P parameter vectors and
all slews at once.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from recal.detect.slew_data import DEFAULT_GROUPS, DROP_REASONS, Slews


# ---- downsampling ----------------------------------------------------------------------------
def group_increments(
    gyro: np.ndarray, period_s: float, reference: np.ndarray, groups: int = DEFAULT_GROUPS
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One slew's samples (n, 3) -> (group_samples (G,), S (G, 3), W (G, 3), C (G, 3)).

    ``n_i = (gyro_i - reference) * period_s``; the samples are cut into ``groups`` runs of
    nearly equal length (empty groups when n < groups). Vectorised over the samples.
    """
    g = np.asarray(gyro, dtype=np.float64)
    n = g.shape[0]
    inc = (g - np.asarray(reference, float)) * period_s
    starts = (np.arange(groups) * n) // groups
    counts = np.diff(np.append(starts, n))
    gid = np.repeat(np.arange(groups), counts)
    local = np.arange(n) - starts[gid]  # index i within its group
    sums = np.zeros((groups, 3))
    weighted = np.zeros((groups, 3))
    cross = np.zeros((groups, 3))
    if n == 0:
        return counts, sums, weighted, cross
    np.add.at(sums, gid, inc)
    np.add.at(weighted, gid, (counts[gid] - 1 - 2 * local)[:, None] * inc)
    # sum over i<j inside the group of n_i x n_j = sum_j (exclusive in-group prefix) x n_j
    prefix = np.cumsum(inc, axis=0) - inc
    prefix -= (np.cumsum(inc, axis=0) - inc)[starts[gid]]
    np.add.at(cross, gid, 0.5 * np.cross(prefix, inc))
    return counts, sums, weighted, cross


def build_slews(
    pieces: Sequence[tuple[int, int, np.ndarray, np.ndarray]],
    period_s: float,
    window_start_s: np.ndarray,
    window_end_s: np.ndarray,
    dropped: Mapping[str, int] | None = None,
    groups: int = DEFAULT_GROUPS,
) -> Slews:
    """:class:`Slews` from ``(first, second, reference (3,), gyro samples (n, 3))`` per slew.

    ``window_start_s`` / ``window_end_s`` are the (M,) times of all windows.
    """
    reduced = [
        (a, b, ref, g.shape[0], group_increments(g, period_s, ref, groups))
        for a, b, ref, g in pieces
    ]
    return assemble_groups(reduced, period_s, window_start_s, window_end_s, dropped, groups)


def assemble_groups(
    reduced: Sequence[tuple[int, int, np.ndarray, int, tuple]],
    period_s: float,
    window_start_s: np.ndarray,
    window_end_s: np.ndarray,
    dropped: Mapping[str, int] | None,
    groups: int,
) -> Slews:
    """:class:`Slews` from ``(first, second, reference, samples, group_increments(...))``."""
    out = [r[4] for r in reduced]
    first = np.array([r[0] for r in reduced], dtype=np.int64)
    second = np.array([r[1] for r in reduced], dtype=np.int64)
    rows = np.stack([first, second], axis=1)

    def stack(i: int, shape: tuple[int, ...]) -> np.ndarray:
        return np.array([o[i] for o in out], dtype=float).reshape((len(reduced),) + shape)

    return Slews(
        first=first,
        second=second,
        period_s=float(period_s),
        samples=np.array([r[3] for r in reduced], dtype=np.int64),
        reference=np.array([r[2] for r in reduced], dtype=float).reshape(-1, 3),
        group_samples=stack(0, (groups,)).astype(np.int64),
        sums=stack(1, (groups, 3)),
        weighted=stack(2, (groups, 3)),
        cross=stack(3, (groups, 3)),
        window_start_s=np.asarray(window_start_s, float)[rows].reshape(-1, 2),
        window_end_s=np.asarray(window_end_s, float)[rows].reshape(-1, 2),
        dropped={**dict.fromkeys(DROP_REASONS, 0), **(dropped or {})},
    )


def compose_groups(
    counts: np.ndarray,
    sums: np.ndarray,
    weighted: np.ndarray,
    cross: np.ndarray,
    starts: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Join runs of consecutive groups into larger groups, exactly.

    counts (K,), sums / weighted / cross (K, 3): the :func:`group_increments` of K consecutive
    groups; ``starts`` (G,) the first of them in each new group (ascending, starts[0] = 0).
    Joining a group a with the group b after it:

        m = m_a + m_b,  S = S_a + S_b,  W = W_a + m_b S_a + W_b - m_a S_b,
        C = C_a + C_b + 1/2 S_a x S_b

    (the weights m - 1 - 2 i of W shift by the samples on either side). For a run this is
    W = sum_k W_k + (m - m_k - 2 o_k) S_k with o_k the samples before group k in the run, and
    C = sum_k C_k + 1/2 sum_k P_k x S_k with P_k the sum of S before k in the run. Vectorised.
    """
    counts = np.asarray(counts, dtype=np.int64)
    K, G = counts.shape[0], starts.shape[0]
    run = np.repeat(np.arange(G), np.diff(np.append(starts, K)))  # new group of each old one
    m = np.add.reduceat(counts, starts) if K else np.zeros(G, dtype=np.int64)
    before = np.cumsum(counts) - counts  # samples before each old group, overall
    offset = before - before[starts][run]  # ... inside its run
    csum = np.cumsum(sums, axis=0) - sums
    prefix = csum - csum[starts][run]  # S of the run before each old group
    S = np.add.reduceat(sums, starts, axis=0)
    W = np.add.reduceat(weighted + (m[run] - counts - 2 * offset)[:, None] * sums, starts, axis=0)
    C = np.add.reduceat(cross + 0.5 * np.cross(prefix, sums), starts, axis=0)
    return m, S, W, C


def shift_reference(
    counts: np.ndarray, sums: np.ndarray, weighted: np.ndarray, cross: np.ndarray, rho: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Group sums of the increments ``n_i - rho`` from those of ``n_i``, exactly.

    S' = S - m rho,  W' = W (the weights m - 1 - 2 i sum to zero),  C' = C - 1/2 W x rho.
    """
    rho = np.asarray(rho, float)
    return counts, sums - counts[:, None] * rho, weighted, cross - 0.5 * np.cross(weighted, rho)
