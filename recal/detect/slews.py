"""The slew invariant: the gyro, integrated over the motion between two static windows, must carry
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

Everything here is numpy on arrays in memory: no I/O (the npz is produced and parsed as bytes).
"""

from __future__ import annotations

import io
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from recal.errors import RecalInputError
from recal.model.error_model import inv3
from recal.model.reference import OMEGA_IE_DEG_H, OMEGA_IE_RAD_S

#: Groups (integration steps) per slew; a power of two for the pairwise quaternion product.
DEFAULT_GROUPS = 64
#: deg/h -> rad/s (the gyro model's input unit to the integration's).
DEG_H_TO_RAD_S = math.radians(1.0) / 3600.0
#: Reasons a slew is dropped, as keys of :attr:`Slews.dropped`.
DROP_REASONS = ("lost_frames", "invalid_frames", "saturated", "too_long")
#: Longest motion between two windows taken as a slew, s. An indexing or fixture rotation lasts
#: seconds; hours of hull motion between two port calls is no slew (the integrated gyro noise and
#: every unmodelled term grow with it), and holding it would make memory grow with the recording.
MAX_SLEW_S = 300.0
#: Bound on P x slews x groups per batched evaluation (bounds the temporaries, ~25 MB each).
_BATCH_ELEMENTS = 1 << 20
_NPZ_VERSION = 1


@dataclass(frozen=True, eq=False)
class Slews:
    """The slews of one recording, as downsampled gyro increments (see the module docstring).

    first / second: (S,) row indices of the windows before and after each slew in the positions.
    period_s: gyro sample period, s. samples: (S,) samples integrated (the slew spans from the
    last frame of window ``first`` to the first frame of window ``second``: ``samples * period_s``
    seconds). reference: (S, 3) window-``first`` mean gyro output, output units.
    group_samples: (S, G) samples per group (0 for padding). sums, weighted, cross: (S, G, 3)
    the sums S_g, W_g (output units x s) and C_g ((output units x s)^2).
    window_start_s / window_end_s: (S, 2) times of the two windows, to check the side file
    against the positions CSV. dropped: reason -> slews dropped (lost or invalid frames, a
    saturated gyro sample): they cannot be integrated; their windows still serve as positions.
    """

    first: np.ndarray
    second: np.ndarray
    period_s: float
    samples: np.ndarray
    reference: np.ndarray
    group_samples: np.ndarray
    sums: np.ndarray
    weighted: np.ndarray
    cross: np.ndarray
    window_start_s: np.ndarray
    window_end_s: np.ndarray
    dropped: Mapping[str, int] = field(default_factory=lambda: dict.fromkeys(DROP_REASONS, 0))

    def __len__(self) -> int:
        return int(self.first.shape[0])

    @property
    def duration_s(self) -> np.ndarray:
        """(S,) time integrated over each slew, s."""
        return self.samples * self.period_s

    @property
    def n_dropped(self) -> int:
        return int(sum(self.dropped.values()))

    def subset(self, keep: np.ndarray) -> Slews:
        keep = np.asarray(keep)
        names = ("first", "second", "samples", "reference", "group_samples", "sums", "weighted")
        arrays = {n: getattr(self, n)[keep] for n in names + ("cross",)}
        return Slews(
            period_s=self.period_s,
            window_start_s=self.window_start_s[keep],
            window_end_s=self.window_end_s[keep],
            dropped=dict(self.dropped),
            **arrays,
        )

    # ---- the side file ---------------------------------------------------------------------
    def to_npz_bytes(self) -> bytes:
        """The side file ``POSITIONS.slews.npz`` (compressed), as bytes."""
        buf = io.BytesIO()
        np.savez_compressed(
            buf,
            version=np.array(_NPZ_VERSION),
            first=self.first.astype(np.int64),
            second=self.second.astype(np.int64),
            period_s=np.array(self.period_s),
            samples=self.samples.astype(np.int64),
            reference=self.reference,
            group_samples=self.group_samples.astype(np.int64),
            sums=self.sums,
            weighted=self.weighted,
            cross=self.cross,
            window_start_s=self.window_start_s,
            window_end_s=self.window_end_s,
            dropped_reasons=np.array(list(self.dropped), dtype=str),
            dropped_counts=np.array(list(self.dropped.values()), dtype=np.int64),
        )
        return buf.getvalue()

    @classmethod
    def from_npz_bytes(cls, data: bytes, source: str = "<slews>") -> Slews:
        try:
            z = np.load(io.BytesIO(data), allow_pickle=False)
            version = int(z["version"])
            if version != _NPZ_VERSION:
                raise RecalInputError(f"{source}: slews file version {version} is not supported")
            out = cls(
                first=z["first"],
                second=z["second"],
                period_s=float(z["period_s"]),
                samples=z["samples"],
                reference=z["reference"],
                group_samples=z["group_samples"],
                sums=z["sums"],
                weighted=z["weighted"],
                cross=z["cross"],
                window_start_s=z["window_start_s"],
                window_end_s=z["window_end_s"],
                dropped=dict(
                    zip(
                        [str(r) for r in z["dropped_reasons"]],
                        [int(c) for c in z["dropped_counts"]],
                        strict=True,
                    )
                ),
            )
        except (OSError, ValueError, KeyError) as exc:
            raise RecalInputError(f"{source}: not a slews file ({exc})") from None
        return out

    def mismatch(self, start_s: np.ndarray, end_s: np.ndarray) -> str | None:
        """Why these slews do not belong to positions with these window times, or None."""
        M = start_s.shape[0]
        if len(self) == 0:
            return None
        if self.first.min() < 0 or self.second.max() >= M:
            return f"the slews refer to window {int(self.second.max())}, the positions have {M}"
        rows = np.stack([self.first, self.second], axis=1)
        tol = 0.5 * self.period_s + 1e-9
        if not (
            np.allclose(start_s[rows], self.window_start_s, rtol=0, atol=tol)
            and np.allclose(end_s[rows], self.window_end_s, rtol=0, atol=tol)
        ):
            return "the window times of the slews file differ from the positions file's"
        return None


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
    return _assemble(reduced, period_s, window_start_s, window_end_s, dropped, groups)


def _assemble(
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


class SlewCollector:
    """Streaming collection of the slews between consecutive static windows.

    Give it the windows (``recal.detect.windows.Window``: start_index, end_index and mean gyro output),
    then feed the recording's frames again in order (the keyword arguments of
    ``StaticDetector.feed``). Only the raw frames of the slew being collected are held: a slew
    is reduced to its group sums as soon as its last frame arrives, and one longer than
    ``max_slew_s`` is never collected, so memory is bounded whatever the recording's length. A
    slew with a lost frame (``lost_before``), an invalid frame or a gyro sample at
    ``gyro_limits`` (the output's saturation values, when known) is dropped and counted.
    """

    def __init__(
        self,
        windows: Sequence,
        period_s: float,
        gyro_limits: tuple[float, float] | None = None,
        groups: int = DEFAULT_GROUPS,
        max_slew_s: float = MAX_SLEW_S,
    ) -> None:
        self._windows = list(windows)
        self._period = float(period_s)
        self._limits = gyro_limits
        self._groups = groups
        # slew j: frames end_index[j] + 1 ... start_index[j + 1] (the first frame of window j+1)
        self._lo = np.array([w.end_index + 1 for w in self._windows[:-1]], dtype=np.int64)
        self._hi = np.array([w.start_index + 1 for w in self._windows[1:]], dtype=np.int64)
        self._parts: list[list[np.ndarray]] = [[] for _ in self._lo]
        self._held = np.zeros(len(self._lo), dtype=np.int64)  # raw frames held per slew
        too_long = (self._hi - self._lo) * self._period > max_slew_s
        self._bad: list[str | None] = ["too_long" if t else None for t in too_long]
        self._reduced: dict[int, tuple] = {}  # slew -> (first, second, ref, samples, sums)
        self._index = 0  # global index of the next frame fed
        for j in np.flatnonzero(self._hi == self._lo):  # back-to-back windows: an empty slew
            self._reduce(int(j))

    @property
    def held_frames(self) -> int:
        """Raw frames held now (at most those of the slews in progress)."""
        return int(self._held.sum())

    def feed(self, time_s, gyro, accel=None, temperature_c=None, valid=None, lost_before=None):
        g = np.asarray(gyro, dtype=np.float64)
        n = g.shape[0]
        a, b = self._index, self._index + n
        self._index = b
        # the slews this piece touches (a loop over slews, not samples)
        for j in np.flatnonzero((self._lo < b) & (self._hi > a)):
            lo, hi = max(self._lo[j], a) - a, min(self._hi[j], b) - a
            if self._bad[j] is not None:
                continue
            part = g[lo:hi]
            if lost_before is not None and np.any(np.asarray(lost_before)[lo:hi] > 0):
                self._bad[j] = "lost_frames"
            elif not np.isfinite(part).all() or (
                valid is not None and not np.asarray(valid)[lo:hi].astype(bool).all()
            ):
                self._bad[j] = "invalid_frames"
            elif self._limits is not None and (
                np.any(part <= self._limits[0]) or np.any(part >= self._limits[1])
            ):
                self._bad[j] = "saturated"
            else:
                self._parts[j].append(part.copy())
                self._held[j] += part.shape[0]
                if self._held[j] == self._hi[j] - self._lo[j]:
                    self._reduce(int(j))
                continue
            self._parts[j], self._held[j] = [], 0

    def _reduce(self, j: int) -> None:
        """The slew's last frame arrived: keep its group sums, drop its frames."""
        samples = np.concatenate(self._parts[j]) if self._parts[j] else np.zeros((0, 3))
        ref = np.asarray(self._windows[j].gyro, float)
        sums = group_increments(samples, self._period, ref, self._groups)
        self._reduced[j] = (j, j + 1, ref, samples.shape[0], sums)
        self._parts[j], self._held[j] = [], 0

    def result(self) -> Slews:
        dropped = dict.fromkeys(DROP_REASONS, 0)
        reduced = []
        for j, bad in enumerate(self._bad):
            if bad is not None:
                dropped[bad] += 1
            elif j in self._reduced:
                reduced.append(self._reduced[j])
            else:
                dropped["lost_frames"] += 1  # the recording ended before the slew did
        start = np.array([w.start_s for w in self._windows], dtype=float)
        end = np.array([w.end_s for w in self._windows], dtype=float)
        return _assemble(reduced, self._period, start, end, dropped, self._groups)


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


class ReducedSlew(NamedTuple):
    """One slew reduced to its groups (see :class:`Slews` for the arrays), or a drop reason.

    ``first`` / ``second`` are the two windows (as given to :meth:`SlewTracker.window`).
    """

    first: Any
    second: Any
    reference: np.ndarray  # (3,) window-first mean gyro output
    samples: int
    groups: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None  # counts, S, W, C
    dropped: str | None = None


class SlewTracker:
    """Live collection of slews, for a stream whose windows are found as it goes (the daemon).

    :class:`SlewCollector` needs the windows before the frames; a live detector closes a window
    only after it ended. The tracker therefore reduces *every* frame, as it arrives, to blocks
    of ``block`` frames (the :func:`group_increments` sums with reference 0, 10 numbers per
    block), keeps the blocks of the last ``lag_s`` seconds and, once a window has closed, those
    from its end on for at most ``max_slew_s``. When the next window closes, the blocks between
    the two are joined into ``groups`` groups (:func:`compose_groups`) and shifted to the first
    window's mean (:func:`shift_reference`). Both steps are exact: the only approximation is
    that the slew starts and ends on a block boundary, so up to ``block - 1`` frames of each
    window's static end are integrated with it (Earth rate over them is handled as over the
    rest of the slew). Memory is bounded by (lag_s + max_slew_s) * rate / block blocks: 3.6 MB
    at 1 kHz with the defaults, whatever the length of the stream or of a hold.

    Call :meth:`feed` with each batch of frames (in order, the frames given to the detector),
    then :meth:`window` with each window the detector closed on that batch, in order.
    """

    def __init__(
        self,
        period_s: float,
        gyro_limits: tuple[float, float] | None = None,
        groups: int = DEFAULT_GROUPS,
        max_slew_s: float = MAX_SLEW_S,
        block: int = 8,
        lag_s: float = 60.0,
        start_index: int = 0,
    ) -> None:
        self._dt = float(period_s)
        self._limits = gyro_limits
        self._groups = groups
        self._block = int(block)
        self._max_frames = int(math.ceil(max_slew_s / self._dt))
        self._lag_blocks = int(math.ceil(lag_s / self._dt / self._block)) + 1
        # global index of the next frame; frames before start_index were never seen: those of
        # its block are stand-ins flagged lost, so no slew is integrated across them
        self._index = int(start_index)
        self._raw = np.zeros((self._index % self._block, 3))  # frames of the incomplete block
        self._raw_bad = 1 if self._raw.shape[0] else 0  # first non-zero flag among them
        # reduced blocks: global block index -> row, kept as parallel arrays
        self._idx = np.zeros(0, dtype=np.int64)
        self._data = np.zeros((0, 10))  # count, S(3), W(3), C(3)
        self._bad = np.zeros(0, dtype=np.int8)  # 0 ok, else 1 + DROP_REASONS index
        self._prev: Any = None  # the last window closed
        self._lo: int | None = None  # first frame of the slew after it

    @property
    def period_s(self) -> float:
        return self._dt

    @property
    def held_bytes(self) -> int:
        return int(self._data.nbytes + self._idx.nbytes + self._bad.nbytes + self._raw.nbytes)

    def feed(self, gyro: np.ndarray, valid=None, lost_before=None) -> None:
        g = np.asarray(gyro, dtype=np.float64).reshape(-1, 3)
        flag = np.zeros(g.shape[0], dtype=np.int8)
        if self._limits is not None:
            flag[np.any((g <= self._limits[0]) | (g >= self._limits[1]), axis=1)] = 3
        bad = ~np.isfinite(g).all(axis=1)
        if valid is not None:
            bad |= ~np.asarray(valid).astype(bool)
        flag[bad] = 2
        if lost_before is not None:
            flag[np.asarray(lost_before) > 0] = 1
        g = np.where(flag[:, None] == 2, 0.0, g)  # keep the sums finite; the flag drops the slew
        raw = np.concatenate([self._raw, g])
        first_block = (self._index - self._raw.shape[0]) // self._block
        flags = np.concatenate([np.full(self._raw.shape[0], self._raw_bad, np.int8), flag])
        self._index += g.shape[0]
        full = raw.shape[0] // self._block
        if full:
            n = full * self._block
            counts, S, W, C = group_increments(raw[:n], self._dt, np.zeros(3), full)
            worst = _first_flag(flags[:n].reshape(full, self._block))
            self._idx = np.append(self._idx, first_block + np.arange(full))
            self._data = np.concatenate([self._data, np.column_stack([counts, S, W, C])])
            self._bad = np.append(self._bad, worst)
        self._raw = raw[full * self._block :]
        rest = flags[full * self._block :]
        self._raw_bad = int(_first_flag(rest[None])[0]) if rest.size else 0
        self._prune()

    def _prune(self) -> None:
        now = self._index // self._block
        keep = self._idx >= now - self._lag_blocks
        if self._lo is not None:
            lo_b = self._lo // self._block
            keep |= (self._idx >= lo_b) & (self._idx <= lo_b + self._max_frames // self._block + 1)
        if not keep.all():
            self._idx, self._data, self._bad = self._idx[keep], self._data[keep], self._bad[keep]

    def window(self, w: Any) -> ReducedSlew | None:
        """Window ``w`` (start_index, end_index, gyro) closed; returns the slew from the previous
        window to it (or why it was dropped), None for the first window."""
        prev, self._prev = self._prev, w
        lo, self._lo = self._lo, int(w.end_index) + 1
        hi = int(w.start_index) + 1
        ref = np.asarray(prev.gyro, float) if prev is not None else None
        out = None
        if prev is not None:
            out = self._reduce(prev, w, ref, lo, hi)
        self._prune()
        return out

    def _reduce(self, prev: Any, w: Any, ref: np.ndarray, lo: int, hi: int) -> ReducedSlew:
        def drop(reason: str) -> ReducedSlew:
            return ReducedSlew(prev, w, ref, 0, None, reason)

        if hi - lo > self._max_frames:
            return drop("too_long")
        B = self._block
        lo_b, hi_b = lo // B, -(-hi // B)
        rows = (self._idx >= lo_b) & (self._idx < hi_b)
        idx, data, bad = self._idx[rows], self._data[rows], self._bad[rows]
        if hi_b * B > self._index - self._raw.shape[0]:  # ends in the incomplete block
            tail = self._raw[: hi_b * B - (self._index - self._raw.shape[0])]
            counts, S, W, C = group_increments(tail, self._dt, np.zeros(3), 1)
            idx = np.append(idx, hi_b - 1)
            data = np.concatenate([data, np.column_stack([counts, S, W, C])])
            bad = np.append(bad, self._raw_bad)
        if idx.shape[0] != hi_b - lo_b or not np.array_equal(idx, np.arange(lo_b, hi_b)):
            return drop("lost_frames")  # blocks no longer held (cannot happen within lag_s)
        if bad.any():
            return drop(DROP_REASONS[int(bad[bad > 0][0]) - 1])
        K, G = idx.shape[0], self._groups
        starts = np.unique((np.arange(G) * K) // G) if K else np.zeros(1, dtype=np.int64)
        counts = data[:, 0].astype(np.int64)
        parts = compose_groups(counts, data[:, 1:4], data[:, 4:7], data[:, 7:10], starts)
        parts = shift_reference(*parts, ref * self._dt)
        pad = G - parts[0].shape[0]  # fewer blocks than groups: pad with empty groups
        padded = tuple(np.concatenate([p, np.zeros((pad,) + p.shape[1:], p.dtype)]) for p in parts)
        return ReducedSlew(prev, w, ref, int(counts.sum()), padded)  # type: ignore[arg-type]


def _first_flag(flags: np.ndarray) -> np.ndarray:
    """Per row of flags (rows, n): the first non-zero flag (the slew's drop reason), else 0."""
    nz = flags != 0
    first = np.argmax(nz, axis=1)
    return np.where(nz.any(axis=1), flags[np.arange(flags.shape[0]), first], 0).astype(np.int8)


def slews_from_reduced(
    reduced: Sequence[tuple[int, int, ReducedSlew]],
    period_s: float,
    window_start_s: np.ndarray,
    window_end_s: np.ndarray,
    groups: int = DEFAULT_GROUPS,
) -> Slews:
    """:class:`Slews` from ``(first row, second row, ReducedSlew)``; dropped ones are counted."""
    dropped = dict.fromkeys(DROP_REASONS, 0)
    kept = []
    for a, b, r in reduced:
        if r.dropped is not None:
            dropped[r.dropped] = dropped.get(r.dropped, 0) + 1
        else:
            kept.append((a, b, r.reference, r.samples, r.groups))
    return _assemble(kept, period_s, window_start_s, window_end_s, dropped, groups)


def in_accel_frame(theta: np.ndarray, layout: Any) -> np.ndarray:
    """Coefficients (flat, ``layout``: a ParameterLayout) with both triads' frames turned
    together until the accelerometer's antisymmetric misalignment is zero.

    That common rotation is invisible without an outside reference, so a fit with slews holds
    it (the accelerometer frame is the reference, its antisymmetric part held at a zero prior):
    compare a simulated truth with such a fit in this gauge. Exact (a fixed-point on the
    rotation), with each row's diagonal returned to the scale factor and bias.
    """
    from scipy.linalg import expm

    from recal.model.terms import MISALIGNMENT_INDEX

    th, sl = np.array(theta, float), layout.term_slices()
    rows, cols = zip(*MISALIGNMENT_INDEX, strict=True)
    A = {}
    for s in ("gyro", "accel"):
        E = np.zeros((3, 3))
        E[rows, cols] = th[sl[f"{s}.misalignment"]]
        A[s] = np.eye(3) + E
    Rc = np.eye(3)
    for _ in range(8):
        Aa = A["accel"] @ Rc
        Ea = Aa / np.diag(Aa)[:, None]
        W = 0.5 * (Ea - Ea.T)
        w = np.array([W[2, 1], W[0, 2], W[1, 0]])
        Rc = Rc @ expm(-np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]))
    for s in ("gyro", "accel"):
        Ap = A[s] @ Rc
        d = np.diag(Ap)
        th[sl[f"{s}.misalignment"]] = (Ap / d[:, None])[rows, cols]
        th[sl[f"{s}.scale"]] *= d
        th[sl[f"{s}.bias"]] /= d
    return th


#: Default 1-sigma of a commanded rotation, deg, when the file does not give one: an indexing
#: mechanism's encoder is good to arc-seconds; 0.01 deg leaves room for its mounting.
KNOWN_ROTATION_SIGMA_DEG = 0.01


@dataclass(frozen=True, eq=False)
class KnownRotations:
    """Commanded rotations of some slews (an indexing mechanism, a fixture of known angles).

    slew: (K,) the slews they belong to, as the row of the slew's first window in the positions
    (the slew from window ``slew[k]`` to the next one). rotvec: (K, 3) the rotation from the
    body frame at the end of that window to the one at the start of the next, as a rotation
    vector in the first frame (rad; the case's axes, i.e. the nominal sensor axes). sigma_rad:
    (K,) its 1-sigma per component.
    """

    slew: np.ndarray
    rotvec: np.ndarray
    sigma_rad: np.ndarray

    def __len__(self) -> int:
        return int(self.slew.shape[0])

    @classmethod
    def from_csv_text(cls, text: str, source: str = "<known rotations>") -> KnownRotations:
        """Parse ``axis_x,axis_y,axis_z,angle_deg[,sigma_deg][,window]``: one row per slew in
        order (row k: the slew after window k, unless a ``window`` column names it), the axis in
        the first window's body frame (any length), the angle right-handed in degrees. An empty
        angle marks a slew whose rotation is not known."""
        import csv

        rows = [r for r in csv.reader(io.StringIO(text)) if r and any(c.strip() for c in r)]
        if not rows:
            raise RecalInputError(f"{source}: empty (expected axis_x,axis_y,axis_z,angle_deg)")
        head = [c.strip() for c in rows[0]]
        need = ["axis_x", "axis_y", "axis_z", "angle_deg"]
        missing = [c for c in need if c not in head]
        if missing:
            raise RecalInputError(f"{source}: no column {', '.join(missing)} in the header")
        col = {c: head.index(c) for c in head}
        slew, rot, sig = [], [], []
        for n, r in enumerate(rows[1:], start=2):

            def cell(name: str, r=r, n=n) -> float | None:
                if name not in col or col[name] >= len(r) or not r[col[name]].strip():
                    return None
                try:
                    v = float(r[col[name]])
                except ValueError:
                    raise RecalInputError(
                        f"{source}: line {n}: {name} {r[col[name]]!r} is not a number"
                    ) from None
                if not math.isfinite(v):
                    raise RecalInputError(f"{source}: line {n}: {name} is not finite")
                return v

            angle = cell("angle_deg")
            if angle is None:
                continue
            axis = np.array([cell(c) or 0.0 for c in need[:3]])
            if np.linalg.norm(axis) == 0:
                raise RecalInputError(f"{source}: line {n}: the rotation axis is zero")
            sigma = cell("sigma_deg")
            if sigma is not None and sigma <= 0:
                raise RecalInputError(f"{source}: line {n}: sigma_deg must be positive")
            window = cell("window")
            slew.append(n - 2 if window is None else int(window))
            rot.append(axis / np.linalg.norm(axis) * math.radians(angle))
            sig.append(math.radians(KNOWN_ROTATION_SIGMA_DEG if sigma is None else sigma))
        if not slew:
            raise RecalInputError(f"{source}: no rotation with an angle")
        return cls(np.array(slew, dtype=np.int64), np.array(rot), np.array(sig))


def rotation_residuals(
    slews: Slews,
    known: KnownRotations,
    gain: np.ndarray,
    A: np.ndarray,
    offset: np.ndarray,
    earth_rate: bool,
    zero_rate: np.ndarray | None = None,
) -> np.ndarray:
    """Known-rotation residuals (P, 3 K), rad: the integrated gyro rotation against the
    commanded one, ``2 vec(q_pred* q_gyro)`` in the first window's frame.

    The gyro measures the rotation in inertial space: the commanded one after Earth's turn over
    the slew, q_pred = q(w_b T) q_cmd with w_b the Earth rate in the first window's body frame
    (``earth_rate``: the calibrated rest rate). A gyro blind to Earth rate (``zero_rate``, see
    :func:`slew_rotations`) leaves that turn in the noise. ``known.slew`` must all be in
    ``slews.first``; the model arrays are those of :func:`slew_rotations` for all the slews.
    """
    pick = np.searchsorted(slews.first, known.slew)
    sub = slews.subset(pick)
    g = gain if gain.shape[1] == 1 else gain[:, pick]
    o = offset if offset.shape[1] == 1 else offset[:, pick]
    z = None if zero_rate is None else np.asarray(zero_rate)[pick]
    q, rest = slew_rotations(sub, g, A, o, z)
    q_cmd = quat_from_rotvec(known.rotvec)[None]  # (1, K, 4)
    if earth_rate:
        q_cmd = quat_multiply(quat_from_rotvec(rest * sub.duration_s[None, :, None]), q_cmd)
    conj = q_cmd * np.array([1.0, -1.0, -1.0, -1.0])
    d = quat_multiply(conj, q)
    d = d * np.sign(d[..., :1] + 1e-300)  # the short way round
    return (2.0 * d[..., 1:]).reshape(q.shape[0], -1)


def rotation_sigma(
    slews: Slews,
    known: KnownRotations,
    gyro_std_in: np.ndarray,
    gyro_sem_in: np.ndarray | None,
    earth_rate: bool,
) -> np.ndarray:
    """1-sigma (3 K,) of the known-rotation residuals, rad: the gyro's angle random walk over
    the slew, the commanded rotation's own sigma and the Earth-rate term (its noise when taken
    out, the whole turn Omega T / sqrt(3) per component when left in)."""
    pick = np.searchsorted(slews.first, known.slew)
    i, j = slews.first[pick], slews.second[pick]
    dt, n, T = slews.period_s, slews.samples[pick], slews.duration_s[pick]
    s_rate = 0.5 * (np.mean(gyro_std_in[i] ** 2, axis=1) + np.mean(gyro_std_in[j] ** 2, axis=1))
    var = (DEG_H_TO_RAD_S * dt) ** 2 * s_rate * n + known.sigma_rad**2
    if earth_rate and gyro_sem_in is not None:
        var = var + (DEG_H_TO_RAD_S * T) ** 2 * np.mean(gyro_sem_in[i] ** 2, axis=1)
    elif not earth_rate:
        var = var + (OMEGA_IE_RAD_S * T) ** 2 / 3.0
    return np.repeat(np.sqrt(var), 3)


# ---- integration, batched over parameter vectors ----------------------------------------------
def cofactor3(M: np.ndarray) -> np.ndarray:
    """Cofactor matrices det(M) M^-T of a batch (..., 3, 3): (M a) x (M b) = cof(M) (a x b)."""
    c = np.empty_like(M)
    for i in range(3):
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        for j in range(3):
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            c[..., i, j] = M[..., i1, j1] * M[..., i2, j2] - M[..., i1, j2] * M[..., i2, j1]
    return c


def quat_from_rotvec(phi: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3), rad -> unit quaternions (..., 4) [w, x, y, z]."""
    angle = np.sqrt(np.einsum("...i,...i->...", phi, phi))
    half = 0.5 * angle
    # sin(a/2)/a, with its series near 0
    small = angle < 1e-6
    k = np.where(small, 0.5 - angle**2 / 48, np.sin(half) / np.where(small, 1.0, angle))
    return np.concatenate([np.cos(half)[..., None], phi * k[..., None]], axis=-1)


def quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product p q of quaternion arrays (..., 4)."""
    pw, pv = p[..., :1], p[..., 1:]
    qw, qv = q[..., :1], q[..., 1:]
    w = pw * qw - np.sum(pv * qv, axis=-1, keepdims=True)
    v = pw * qv + qw * pv + np.cross(pv, qv)
    return np.concatenate([w, v], axis=-1)


def rotate_back(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """C(q)^T v for quaternions (..., 4) and vectors (..., 3): a vector of the start frame in the
    end frame, when C(q) maps end-frame coordinates to start-frame ones."""
    w, u = q[..., :1], q[..., 1:]
    t = np.cross(u, v)
    return v - 2.0 * w * t + 2.0 * np.cross(u, t)


def rodrigues(phi: np.ndarray, v: np.ndarray) -> np.ndarray:
    """exp([phi]x) v for rotation vectors and vectors (..., 3)."""
    return rotate_back(quat_from_rotvec(-phi), v)


def _chain_components(w, x, y, z):
    """Ordered Hamilton product over the last axis of quaternion components (..., G): pairwise,
    log2(G) vectorised steps. Returns the four components (...,)."""
    while w.shape[-1] > 1:
        if w.shape[-1] % 2:
            pad = [(0, 0)] * (w.ndim - 1) + [(0, 1)]
            w = np.pad(w, pad, constant_values=1.0)
            x, y, z = (np.pad(a, pad) for a in (x, y, z))
        aw, ax, ay, az = w[..., 0::2], x[..., 0::2], y[..., 0::2], z[..., 0::2]
        bw, bx, by, bz = w[..., 1::2], x[..., 1::2], y[..., 1::2], z[..., 1::2]
        w, x, y, z = (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        )
    return w[..., 0], x[..., 0], y[..., 0], z[..., 0]


def _group_rotvecs(
    slews: Slews,
    gain: np.ndarray,
    A: np.ndarray,
    offset: np.ndarray,
    zero_rate: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-group rotation vectors (P, S, 3, G), rad, and the rest rate (P, S, 3), rad/s, of
    :func:`slew_rotations` (see there for the arguments)."""
    P, S = A.shape[0], len(slews)
    Ainv = inv3(A)[:, None]  # (P, 1, 3, 3)
    Mm = DEG_H_TO_RAD_S * Ainv / gain[:, :, None, :]  # (P, S|1, 3, 3): column j / gain_j
    rest = (Ainv @ (slews.reference[None] / gain - offset)[..., None])[..., 0]
    rest = DEG_H_TO_RAD_S * np.broadcast_to(rest, (P, S, 3))  # (P, S, 3) rad/s
    Mb = np.broadcast_to(Mm, (P, S, 3, 3))
    if zero_rate is None:
        c = (rest * slews.period_s)[..., None]  # per-sample rest increment, rad, (P, S, 3, 1)
    else:
        rho = (np.asarray(zero_rate, float) - slews.reference) * slews.period_s  # (S, 3)
        c = -(Mb @ rho[None, :, :, None])  # (P, S, 3, 1)
        rest = np.zeros_like(rest)
    phi = Mb @ slews.sums.transpose(0, 2, 1)  # (P, S, 3, G)
    phi += slews.group_samples[None, :, None, :] * c
    mw = Mb @ slews.weighted.transpose(0, 2, 1)
    phi[:, :, 0] += 0.5 * (mw[:, :, 1] * c[:, :, 2] - mw[:, :, 2] * c[:, :, 1])
    phi[:, :, 1] += 0.5 * (mw[:, :, 2] * c[:, :, 0] - mw[:, :, 0] * c[:, :, 2])
    phi[:, :, 2] += 0.5 * (mw[:, :, 0] * c[:, :, 1] - mw[:, :, 1] * c[:, :, 0])
    phi += cofactor3(Mb) @ slews.cross.transpose(0, 2, 1)
    return phi, rest


def slew_rotations(
    slews: Slews,
    gain: np.ndarray,
    A: np.ndarray,
    offset: np.ndarray,
    zero_rate: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Integrated rotation and rest rate per parameter vector and slew.

    The gyro model N = gain * (A w + offset) (w in deg/h) with gain and offset of shape (P, 1, 3)
    or (P, S, 3) (per slew: the context of its first window) and A (P, 3, 3). Returns the
    quaternions (P, S, 4) of the rotation from the body frame at the end of window ``first`` to
    the one at the start of window ``second`` (C(q) maps the latter's coordinates to the
    former's), and the calibrated rest rate of window ``first`` (P, S, 3) in rad/s.

    ``zero_rate`` (S, 3), output units: the output taken as zero rate over each slew instead of
    the model's bias (for a gyro blind to Earth rate, whose bias wanders between windows by more
    than the model's constant bias can follow: the mean output of the slew's two windows is the
    best estimate of the bias during it). The increments are then shifted exactly to that
    reference (``c = -M rho``, rho = (zero_rate - reference) dt) and the rest rate is zero.
    Component-major inside: three (P x S) batches of 3x3 by 3xG matrix products, then
    elementwise work on (P, S, G) arrays.
    """
    phi, rest = _group_rotvecs(slews, gain, A, offset, zero_rate)
    angle = np.sqrt(np.einsum("psig,psig->psg", phi, phi))
    small = angle < 1e-6
    k = np.where(small, 0.5 - angle**2 / 48, np.sin(0.5 * angle) / np.where(small, 1.0, angle))
    w, x, y, z = _chain_components(np.cos(0.5 * angle), *(phi[:, :, i] * k for i in range(3)))
    return np.stack([w, x, y, z], axis=-1), rest


def horizontal_basis(up: np.ndarray) -> np.ndarray:
    """(S, 2, 3) two unit vectors orthogonal to each direction ``up`` (S, 3) and to each other."""
    u = up / np.linalg.norm(up, axis=1, keepdims=True)
    helper = np.eye(3)[np.argmin(np.abs(u), axis=1)]
    e1 = np.cross(u, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return np.stack([e1, np.cross(u, e1)], axis=1)


def slew_residuals(
    slews: Slews,
    gain: np.ndarray,
    A: np.ndarray,
    offset: np.ndarray,
    f_first: np.ndarray,
    f_second: np.ndarray,
    basis: np.ndarray,
    earth_rate: bool,
    zero_rate: np.ndarray | None = None,
    same_gyro: np.ndarray | None = None,
) -> np.ndarray:
    """Slew residuals (P, 2 S), rad: the gravity direction the integrated gyro predicts at
    window ``second`` against the measured one, ``u_meas x u_pred`` on ``basis`` (S, 2, 3).

    f_first / f_second: (P, S, 3) calibrated specific force of the two windows. With
    ``earth_rate`` the Earth's rotation over the slew is taken out, with the calibrated rest rate
    of window ``first`` as the Earth rate in its body frame (a gyro that sees Earth rate):
    u_(k+1) = C^T exp([w_k T]x) u_k. Without it, that rotation (Omega cos(lat) T, about north)
    is left in the noise budget (:func:`slew_sigma`); ``zero_rate`` is then the output taken as
    zero rate over each slew (:func:`slew_rotations`).
    ``same_gyro`` (P,): for each row, a row with the same gyro parameters (the integration is
    done once per distinct row: a Jacobian along accelerometer coefficients needs none); None:
    every row its own.
    Evaluated in batches over P so the temporaries stay bounded.
    """
    P, S = A.shape[0], len(slews)
    out = np.empty((P, S, 2))
    step = max(1, _BATCH_ELEMENTS // max(S * slews.sums.shape[1], 1))
    need, back = np.unique(np.arange(P) if same_gyro is None else same_gyro, return_inverse=True)
    back = back.reshape(-1)
    for a in range(0, need.size, step):  # a loop over batches of parameter vectors, not samples
        i = need[a : a + step]
        q_all, rest_all = slew_rotations(slews, gain[i], A[i], offset[i], zero_rate)
        rows = np.flatnonzero((back >= a) & (back < a + step))
        for c in range(0, rows.size, step):  # the rows that share these gyro parameters
            r = rows[c : c + step]
            q, rest = q_all[back[r] - a], rest_all[back[r] - a]
            u1 = f_first[r] / np.linalg.norm(f_first[r], axis=-1, keepdims=True)
            if earth_rate:
                u1 = rodrigues(rest * slews.duration_s[None, :, None], u1)
            pred = rotate_back(q, u1)
            u2 = f_second[r] / np.linalg.norm(f_second[r], axis=-1, keepdims=True)
            err = np.cross(u2, pred)
            out[r] = np.einsum("psi,sji->psj", err, basis)
    return out.reshape(P, 2 * S)


def slew_sigma(
    slews: Slews,
    gyro_std_in: np.ndarray | None,
    gyro_sem_in: np.ndarray | None,
    accel_sem_in: np.ndarray | None,
    f_first: np.ndarray,
    f_second: np.ndarray,
    basis: np.ndarray,
    earth_rate: bool,
    latitude_deg: float,
    excess_rad: float = 0.0,
) -> np.ndarray | None:
    """1-sigma (2 S,) of the slew residuals, rad, from the windows' noise; None without it.

    * gyro angle random walk: the per-sample gyro std (deg/h, mean of the two windows and of the
      axes) integrated over the slew's n samples: (u sigma dt)^2 n;
    * the two gravity directions: window-mean accel noise / |f|, window ``second`` projected on
      the residual basis, window ``first`` (seen through the rotation) its mean over axes;
    * Earth rate: with ``earth_rate`` the noise of the rest rate used for it, (u sem T)^2; without,
      the rotation left in, Omega cos(lat) T about an unknown north: (Omega cos(lat) T)^2 / 2
      per component.

    * ``excess_rad``: an unmodelled error per slew residual, estimated from the slews' own
      misfit (:func:`recal.solve.slew_fit.slew_excess`), 0 when they fit to their noise.

    gyro_std_in, gyro_sem_in, accel_sem_in: (M, 3) per window in input units.
    """
    if gyro_std_in is None or accel_sem_in is None:
        return None
    i, j = slews.first, slews.second
    dt, n, T = slews.period_s, slews.samples, slews.duration_s
    s_rate = 0.5 * (np.mean(gyro_std_in[i] ** 2, axis=1) + np.mean(gyro_std_in[j] ** 2, axis=1))
    var = (DEG_H_TO_RAD_S * dt) ** 2 * s_rate * n
    g1 = np.linalg.norm(f_first, axis=1)
    g2 = np.linalg.norm(f_second, axis=1)
    var = var + np.mean(accel_sem_in[i] ** 2, axis=1) / g1**2
    var2 = var[:, None] + np.einsum("sji,si->sj", basis**2, accel_sem_in[j] ** 2) / g2[:, None] ** 2
    var2 += excess_rad**2  # the unmodelled per-slew error, when the slews show one
    if earth_rate:
        if gyro_sem_in is not None:
            var2 += ((DEG_H_TO_RAD_S * T) ** 2 * np.mean(gyro_sem_in[i] ** 2, axis=1))[:, None]
    else:
        horizontal = OMEGA_IE_RAD_S * math.cos(math.radians(latitude_deg)) * T
        var2 += (horizontal**2 / 2.0)[:, None]
        if gyro_sem_in is not None:  # the zero-rate reference: the mean of the two windows
            ref = 0.25 * (
                np.mean(gyro_sem_in[i] ** 2, axis=1) + np.mean(gyro_sem_in[j] ** 2, axis=1)
            )
            var2 += ((DEG_H_TO_RAD_S * T) ** 2 * ref)[:, None]
    return np.sqrt(var2).reshape(-1)


def integrate_samples(rates_rad_s: np.ndarray, period_s: float) -> np.ndarray:
    """Reference integration of one slew at the full rate, for tests and checks: rates (n, 3) in
    rad/s, each sample held for one period, composed sample by sample (a sequential loop: slow,
    never on a hot path). Returns the quaternion (4,) of C(start <- end)."""
    q = np.array([1.0, 0.0, 0.0, 0.0])
    for r in quat_from_rotvec(np.asarray(rates_rad_s, float) * period_s):
        q = quat_multiply(q, r)
    return q


# ---- closed turns ------------------------------------------------------------------------------
#: A slew is a candidate closed turn when the gravity direction returns to within this angle, deg ...
CLOSED_TURN_TILT_DEG = 1.0
#: ... the gyro integrates within this of a whole, non-zero number of turns about the vertical,
#: deg (room for a prior scale a few % off) ...
CLOSED_TURN_SLACK_DEG = 30.0
#: ... and off the vertical by less than this, deg (a turn, not a tumble that ends where it began).
CLOSED_TURN_OFF_AXIS_DEG = 20.0
#: A candidate is taken as closed, checked, when its two windows' Earth-rate headings agree within
#: this many 1-sigma of their difference ...
HEADING_AGREEMENT_SIGMA = 3.0
#: ... and the heading is observable: the gyro bias's prior 1-sigma across the horizontal Earth
#: rate below this fraction of it (a bias as large as Earth rate turns the measured north with the
#: body, and two windows a turn apart would then agree whatever the turn).
HEADING_BIAS_MAX = 0.1
#: How a closed turn was decided (:attr:`TurnCandidate.how`).
CHECKED = "checked by Earth rate"
DECLARED = "declared"


@dataclass(frozen=True, eq=False)
class ClosedTurns:
    """Slews taken as whole turns about the vertical (gravity returns to where it was while the
    gyro integrates close to k x 360 deg about it). Their rotation is then known: k x 360 deg
    plus ``target_rad`` about the vertical, with the 1-sigma ``sigma_rad``. That pins the scale
    factor along the vertical, which the gravity directions alone cannot see.

    index: (C,) positions in the :class:`Slews` arrays. turns: (C,) signed whole turns k.
    axis: (C, 3) the vertical (unit gravity direction) in window ``first``'s body frame.
    sigma_rad: (C,) 1-sigma of the closure (the Earth-rate heading check's, or the declared one).
    target_rad: (C,) the heading change beyond k whole turns, as a rotation about ``axis``: the
    Earth-rate headings' for a checked turn, 0 for a declared one. checked: (C,) bool.
    """

    index: np.ndarray
    turns: np.ndarray
    axis: np.ndarray
    sigma_rad: np.ndarray
    target_rad: np.ndarray | None = None
    checked: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.index.shape[0])


class HeadingCheck(NamedTuple):
    """What the Earth-rate heading check needs beyond the slews, at the prior (or the current
    estimate). rate_dph / force_g: (M, 3) each window's calibrated mean rate (deg/h) and specific
    force (g); rate_sem_dph: (M, 3) the standard error of the window's mean rate, deg/h, or None
    (no noise columns); latitude_deg; bias_sigma_dph (3,) and scale_sigma_rel (3,): the gyro's
    prior 1-sigma (bias, deg/h; scale factor, relative); earth_rate: whether the gyro resolves
    Earth rate in a window (:func:`recal.solve.slew_fit._slews_see_earth_rate`)."""

    rate_dph: np.ndarray
    force_g: np.ndarray
    rate_sem_dph: np.ndarray | None
    latitude_deg: float
    bias_sigma_dph: np.ndarray
    scale_sigma_rel: np.ndarray
    earth_rate: bool = True


class TurnCandidate(NamedTuple):
    """A slew that integrates close to whole turns about the vertical, and what was decided.

    slew: position in the :class:`Slews` arrays; first / second: its windows; turns: k;
    integrated_deg: the gyro's angle about the vertical at the prior; closed; how:
    :data:`CHECKED`, :data:`DECLARED` or "" (not closed); reason: why. heading_first_deg /
    heading_second_deg: the azimuth of a body reference axis in each window from the horizontal
    Earth rate (NaN where the heading is not observable); heading_change_deg: the turn the two
    headings show beyond whole turns, about the vertical (right-handed about up); sigma_deg: its
    1-sigma (for a closed turn: the closure's 1-sigma).
    """

    slew: int
    first: int
    second: int
    turns: int
    integrated_deg: float
    closed: bool
    how: str
    reason: str
    heading_first_deg: float = float("nan")
    heading_second_deg: float = float("nan")
    heading_change_deg: float = float("nan")
    sigma_deg: float = float("nan")

    def to_json_dict(self) -> dict[str, Any]:
        def num(v: float) -> float | None:
            return float(v) if math.isfinite(v) else None

        return {
            "slew": self.slew, "windows": [self.first, self.second], "turns": self.turns,
            "integrated_deg": round(self.integrated_deg, 4), "closed": self.closed,
            "how": self.how or None, "reason": self.reason,
            "heading_first_deg": num(self.heading_first_deg),
            "heading_second_deg": num(self.heading_second_deg),
            "heading_change_deg": num(self.heading_change_deg), "sigma_deg": num(self.sigma_deg),
        }  # fmt: skip


def earth_rate_headings(
    rate: np.ndarray, up: np.ndarray, ref: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(heading (N,), rad, cross-track unit vectors (N, 3)) from the horizontal Earth rate.

    rate (N, 3): the window's calibrated mean rate; up (N, 3): its gravity direction (the
    specific force, unit); ref (N, 3): a body axis not along ``up``. The horizontal part of the
    rate points north; the heading is the azimuth (clockwise from north, seen from above) of
    ``ref`` projected on the horizontal plane: atan2 of north's components along (e1, up x e1).
    The cross-track direction ``up x north`` is the one whose rate noise moves the heading.
    """
    u = up / np.linalg.norm(up, axis=1, keepdims=True)
    e1 = ref - np.sum(ref * u, axis=1, keepdims=True) * u
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(u, e1)
    h = rate - np.sum(rate * u, axis=1, keepdims=True) * u
    north = h / np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-300)
    psi = np.arctan2(np.sum(h * e2, axis=1), np.sum(h * e1, axis=1))
    return psi, np.cross(u, north)


def _wrap(a: np.ndarray) -> np.ndarray:
    return (np.asarray(a) + math.pi) % (2 * math.pi) - math.pi


def integrated_rotvec(
    slews: Slews,
    gain: np.ndarray,
    A: np.ndarray,
    offset: np.ndarray,
    zero_rate: np.ndarray | None = None,
) -> np.ndarray:
    """(P, S, 3) sum of the group rotation vectors over each slew, rad: the rotation vector of a
    turn about a fixed axis with its whole revolutions kept (a quaternion forgets them)."""
    phi, _ = _group_rotvecs(slews, gain, A, offset, zero_rate)
    return phi.sum(axis=-1)


def turn_candidates(
    slews: Slews,
    rotvec: np.ndarray,
    up_first: np.ndarray,
    up_second: np.ndarray,
    declared_sigma_deg: float = 0.0,
    exclude: np.ndarray | None = None,
    check: HeadingCheck | None = None,
) -> list[TurnCandidate]:
    """The slews that may be whole turns about the vertical, each decided closed or not.

    A candidate: gravity returns to within :data:`CLOSED_TURN_TILT_DEG` while the gyro
    (``rotvec`` (S, 3), :func:`integrated_rotvec` at the prior) integrates within
    :data:`CLOSED_TURN_SLACK_DEG` of k x 360 deg (k != 0) about the vertical and less than
    :data:`CLOSED_TURN_OFF_AXIS_DEG` off it. up_first / up_second: (S, 3) gravity directions of
    each slew's two windows. exclude: (S,) bool, slews not to consider (a commanded rotation).

    Closed, checked, when the heading is observable (``check``: a gyro that resolves Earth rate,
    a bias prior well below the horizontal Earth rate, noise columns), the check can tell a
    closed turn from one the gyro scale could hide (the headings' 1-sigma difference at most
    the scale's prior 1-sigma x 360 deg x |k|) and the two windows' Earth-rate headings agree
    within :data:`HEADING_AGREEMENT_SIGMA` sigma: its target is the heading change they show,
    its 1-sigma theirs (the same orientation twice: the coefficients' errors cancel in the
    difference). Where the check cannot decide, closed only when declared
    (``declared_sigma_deg`` > 0, target 0). A check that shows the turn is not closed wins
    over a declaration.
    """
    if len(slews) == 0:
        return []
    u1 = up_first / np.linalg.norm(up_first, axis=1, keepdims=True)
    u2 = up_second / np.linalg.norm(up_second, axis=1, keepdims=True)
    tilt = np.arccos(np.clip(np.sum(u1 * u2, axis=1), -1.0, 1.0))
    about = np.sum(rotvec * u1, axis=1)  # signed angle about the vertical, rad
    off = np.linalg.norm(rotvec - about[:, None] * u1, axis=1)
    k = np.round(about / (2 * math.pi))
    ok = (
        (k != 0)
        & (tilt < math.radians(CLOSED_TURN_TILT_DEG))
        & (np.abs(about - 2 * math.pi * k) < math.radians(CLOSED_TURN_SLACK_DEG))
        & (off < math.radians(CLOSED_TURN_OFF_AXIS_DEG))
    )
    if exclude is not None:
        ok &= ~np.asarray(exclude, bool)
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return []
    i, j = slews.first[idx], slews.second[idx]
    declare = (
        f"declared (--turn-closure {declared_sigma_deg:g} deg)" if declared_sigma_deg > 0 else ""
    )
    unseen = _heading_unseen(check)
    out = []
    psi1 = psi2 = change = sd = np.full(idx.size, np.nan)
    sd_bias = np.zeros(idx.size)
    if unseen is None:
        assert check is not None and check.rate_sem_dph is not None
        ref = np.eye(3)[np.argmin(np.abs(u1[idx]), axis=1)]  # the body axis most horizontal
        horizontal = OMEGA_IE_DEG_H * math.cos(math.radians(check.latitude_deg))
        psi1, c1 = earth_rate_headings(check.rate_dph[i], check.force_g[i], ref)
        psi2, c2 = earth_rate_headings(check.rate_dph[j], check.force_g[j], ref)
        sem = check.rate_sem_dph
        noise = np.sqrt(np.sum((c1 * sem[i]) ** 2, 1) + np.sum((c2 * sem[j]) ** 2, 1))
        sd = noise / horizontal  # rad, the difference's
        b = np.asarray(check.bias_sigma_dph, float)
        sd_bias = np.sqrt(np.maximum(np.sum((c1 * b) ** 2, 1), np.sum((c2 * b) ** 2, 1)))
        sd_bias = sd_bias / horizontal
        change = -_wrap(psi2 - psi1)  # the body turns one way, north the other
        # a turn about u integrates sum u_i^2 (1 + dK_i / K_i): the scales' share along u
        ks = np.sqrt(np.sum((u1[idx] ** 2 * np.asarray(check.scale_sigma_rel, float)) ** 2, 1))
        hidden = ks * 2 * math.pi * np.abs(k[idx])  # what a 1-sigma scale error hides, rad
    for n, s in enumerate(idx):
        base = dict(slew=int(s), first=int(i[n]), second=int(j[n]), turns=int(k[s]),
                    integrated_deg=math.degrees(float(about[s])),
                    heading_first_deg=math.degrees(float(psi1[n])) % 360.0,
                    heading_second_deg=math.degrees(float(psi2[n])) % 360.0,
                    heading_change_deg=math.degrees(float(change[n])))  # fmt: skip
        why = unseen
        if why is None and sd_bias[n] > HEADING_BIAS_MAX:
            why = (
                f"the heading is not observable: the gyro bias's prior 1-sigma moves it by "
                f"{math.degrees(sd_bias[n]):.3g} deg"
            )
        if why is None and sd[n] > hidden[n]:
            why = (
                f"the Earth-rate headings differ by {base['heading_change_deg']:+.3g} +- "
                f"{math.degrees(sd[n]):.3g} deg: too noisy to tell a closed turn from one that "
                f"a gyro scale 1-sigma of {ks[n] * 1e6:.3g} ppm hides ({math.degrees(hidden[n]):.3g} deg)"
            )
        if why is None:
            agree = abs(change[n]) <= HEADING_AGREEMENT_SIGMA * sd[n]
            text = (
                f"the Earth-rate headings differ by {base['heading_change_deg']:+.3g} +- "
                f"{math.degrees(sd[n]):.3g} deg"
            )
            if agree:
                out.append(TurnCandidate(**base, closed=True, how=CHECKED, reason=text,
                                         sigma_deg=math.degrees(float(sd[n]))))  # fmt: skip
            else:
                out.append(TurnCandidate(
                    **base, closed=False, how="", sigma_deg=math.degrees(float(sd[n])),
                    reason=f"{text}: not a closed turn" + (" (Earth rate overrules the "
                                                           "declaration)" if declare else ""),
                ))  # fmt: skip
            continue
        if declare:
            out.append(TurnCandidate(**base, closed=True, how=DECLARED,
                                     reason=f"{declare}: {why}", sigma_deg=declared_sigma_deg))  # fmt: skip
        else:
            out.append(TurnCandidate(**base, closed=False, how="",
                                     reason=f"{why}; not assumed closed unless declared "
                                     "(--turn-closure DEG)"))  # fmt: skip
    return out


def _heading_unseen(check: HeadingCheck | None) -> str | None:
    """Why no window's heading can be seen from Earth rate, or None."""
    if check is None:
        return "no Earth-rate heading check"
    if not check.earth_rate:
        return "the heading is not observable: Earth rate is below the gyro's window-mean noise"
    if check.rate_sem_dph is None:
        return "the heading check needs the windows' gyro noise (std or sem columns)"
    horizontal = OMEGA_IE_DEG_H * math.cos(math.radians(check.latitude_deg))
    if horizontal < 1e-3 * OMEGA_IE_DEG_H:
        return f"the heading is not observable at latitude {check.latitude_deg:g} deg"
    return None


def closed_turns_of(
    candidates: Sequence[TurnCandidate], up_first: np.ndarray
) -> ClosedTurns | None:
    """The :class:`ClosedTurns` of the candidates decided closed (``up_first`` (S, 3)), or None."""
    closed = [c for c in candidates if c.closed]
    if not closed:
        return None
    idx = np.array([c.slew for c in closed], dtype=np.int64)
    u1 = up_first[idx] / np.linalg.norm(up_first[idx], axis=1, keepdims=True)
    checked = np.array([c.how == CHECKED for c in closed])
    target = np.where(checked, np.radians([c.heading_change_deg for c in closed]), 0.0)
    return ClosedTurns(
        idx,
        np.array([c.turns for c in closed], dtype=np.int64),
        u1,
        np.radians([c.sigma_deg for c in closed]),
        target,
        checked,
    )


def closure_residuals(
    slews: Slews,
    turns: ClosedTurns,
    gain: np.ndarray,
    A: np.ndarray,
    offset: np.ndarray,
    earth_rate: bool,
    zero_rate: np.ndarray | None = None,
) -> np.ndarray:
    """Closed-turn residuals (P, C), rad: the integrated rotation's component about the
    vertical after k whole turns (the heading misclosure) less the turn's target (the Earth-rate
    headings' change for a checked turn, 0 for a declared one), Earth's turn over the slew taken
    out as in :func:`rotation_residuals` with ``earth_rate``."""
    pick = turns.index
    sub = slews.subset(pick)
    g = gain if gain.shape[1] == 1 else gain[:, pick]
    o = offset if offset.shape[1] == 1 else offset[:, pick]
    z = None if zero_rate is None else np.asarray(zero_rate)[pick]
    q, rest = slew_rotations(sub, g, A, o, z)
    if earth_rate:
        conj = quat_from_rotvec(rest * sub.duration_s[None, :, None])
        conj = conj * np.array([1.0, -1.0, -1.0, -1.0])
        q = quat_multiply(conj, q)
    q = q * np.sign(q[..., :1] + 1e-300)  # whole turns: q = -1 is no rotation
    r = np.einsum("psi,si->ps", 2.0 * q[..., 1:], turns.axis)
    return r if turns.target_rad is None else r - turns.target_rad[None]


def closure_sigma(
    slews: Slews, turns: ClosedTurns, gyro_std_in: np.ndarray, earth_rate: bool
) -> np.ndarray:
    """1-sigma (C,) of the closed-turn residuals, rad: the closure's own (the Earth-rate heading
    check's, or the declared one), the gyro's angle random walk over the slew (per-sample std in
    deg/h, (M, 3)) and, when Earth's turn is left in, its vertical part at most Omega T."""
    pick = turns.index
    i, j = slews.first[pick], slews.second[pick]
    dt, n, T = slews.period_s, slews.samples[pick], slews.duration_s[pick]
    s_rate = 0.5 * (np.mean(gyro_std_in[i] ** 2, axis=1) + np.mean(gyro_std_in[j] ** 2, axis=1))
    var = (DEG_H_TO_RAD_S * dt) ** 2 * s_rate * n + turns.sigma_rad**2
    if not earth_rate:
        var = var + (OMEGA_IE_RAD_S * T) ** 2 / 3.0
    return np.sqrt(var)
