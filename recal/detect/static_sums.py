"""The static detector's buffer rows and the chunk-independent sums taken over them.

Frames are held as rows of :data:`NCOL` columns (time, gyro, accel, temperature, validity,
frames lost before, and the moving-variance traces once computed). A window's means, variances,
temperature slope and fault counts are sums of per-frame terms (:func:`piece_features`); the
moving variance is a van Herk sum over blocks aligned on the global frame index
(:func:`window_sums`); the Allan statistics take block sums (:func:`add_blocks`). None of these
depends on how the stream was chunked. Internal to :mod:`recal.detect.static_detector`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from recal.detect.noise import standard_errors as _standard_errors
from recal.detect.window_sem import static_white_std

# Raw row layout kept in the buffer.
COL_T, COL_G, COL_A, COL_TEMP, COL_VALID, COL_LOST = 0, slice(1, 4), slice(4, 7), 7, 8, 9
COL_TRA, COL_TRG = 10, 11  # the moving-variance traces, once computed (centre frames)
NCOL = 12
NFEAT = 22  # per-frame terms summed over a window (see piece_features)


@dataclass
class Piece:
    """A trimmed run being summed: frame range, first/last times, value reference, sums."""

    first: int
    last: int
    t_first: float
    t_last: float
    g_ref: np.ndarray
    a_ref: np.ndarray
    sums: np.ndarray
    blocks: list[np.ndarray] = field(default_factory=list)  # (k, 7) complete block sums
    partial: tuple[int, np.ndarray] | None = None  # (block id, [frames, 7 sums]) still open


def allan_window_sem(n: int, std: np.ndarray, allan_sq, allan_terms, block: int) -> np.ndarray:
    """(6,) standard errors of one window's means (gyro x y z, accel x y z) from its own
    samples, correlated noise included (recal.detect.noise). The white level is the per-sample
    variance unless the first Allan level shows a larger long-run level: a sensor's own low-pass
    (:func:`recal.detect.window_sem.static_white_std`)."""
    white = static_white_std(std, allan_sq, allan_terms, block)
    return _standard_errors(np.array([n]), white[None], [(allan_sq, allan_terms)], block)[0]


def run_edges(prev: bool, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Local indices where runs of True start, and where they end (first False after)."""
    d = np.diff(mask.astype(np.int8), prepend=np.int8(prev))
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


def window_sums(f: np.ndarray, starts: tuple[int, int], W: int) -> np.ndarray:
    """Sums of f over windows [a, a + W) for a in range(*starts), f starting block-aligned.

    van Herk: blocks of W frames aligned on the global index; a window is the suffix sum of one
    block plus the prefix sum of the next. The result depends only on the data of those two
    blocks, never on how the stream was chunked, and never accumulates rounding over the stream.
    """
    nb = -(-f.shape[0] // W)
    blocks = np.zeros((nb * W, f.shape[1]))
    blocks[: f.shape[0]] = f
    blocks = blocks.reshape(nb, W, f.shape[1])
    prefix = np.cumsum(blocks, axis=1)
    suffix = np.cumsum(blocks[:, ::-1], axis=1)[:, ::-1]
    a = np.arange(*starts)
    k, o = np.divmod(a, W)
    out = suffix[k, o]
    split = o > 0
    out[split] += prefix[k[split] + 1, o[split] - 1]
    return out


def piece_features(rows, prev_in, t_first, g_ref, a_ref, temp_ref: float) -> np.ndarray:
    """Per kept frame, the terms whose sums give a window's means, variances and slope."""
    w = rows[:, COL_VALID] > 0
    f = np.zeros((rows.shape[0], NFEAT))
    dg = np.where(w[:, None], rows[:, COL_G] - g_ref, 0.0)
    da = np.where(w[:, None], rows[:, COL_A] - a_ref, 0.0)
    f[:, 0] = w
    f[:, 1:4], f[:, 4:7] = dg, dg * dg
    f[:, 7:10], f[:, 10:13] = da, da * da
    temp = rows[:, COL_TEMP]
    wt = w & np.isfinite(temp)
    tau = np.where(wt, rows[:, COL_T] - t_first, 0.0)  # time from the window start, s
    theta = np.where(wt, temp - temp_ref, 0.0)
    f[:, 13], f[:, 14], f[:, 15] = wt, tau, tau * tau
    f[:, 16], f[:, 17] = theta, tau * theta
    f[:, 18] = ~w
    f[:, 19] = np.where(prev_in, rows[:, COL_LOST], 0.0)  # a gap between two kept frames
    f[:, 20], f[:, 21] = rows[:, COL_TRA], rows[:, COL_TRG]  # finite: every kept frame was quiet
    return f


#: Columns of piece_features summed per block: valid count, gyro and accel relative values.
BLOCK_FEATS = [0, 1, 2, 3, 7, 8, 9]


def add_blocks(piece: Piece, bid, count, sums, block: int, still_open: bool) -> None:
    """Add one call's block groups (block ids, kept frames, summed BLOCK_FEATS) to a piece."""
    if bid.size == 0:
        return
    count = count.copy()
    sums = sums.copy()
    if piece.partial is not None and piece.partial[0] == bid[0]:
        count[0] += int(piece.partial[1][0])
        sums[0] += piece.partial[1][1:]
    piece.partial = None
    complete = count == block
    if still_open and not complete[-1]:
        piece.partial = (int(bid[-1]), np.concatenate(([count[-1]], sums[-1])))
    if complete.any():
        piece.blocks.append(sums[complete])
