"""Collecting the slews of a stream of frames: :class:`SlewCollector` (a recording whose windows
are known before its frames are fed again) and :class:`SlewTracker` (a live stream whose windows
close as it goes, the daemon), both reducing each slew to its group sums as it arrives so memory
stays bounded; :func:`slews_from_reduced` turns the tracker's slews into :class:`Slews`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from recal.detect.slew_data import DEFAULT_GROUPS, DROP_REASONS, MAX_SLEW_S, Slews
from recal.detect.slew_groups import (
    assemble_groups,
    compose_groups,
    group_increments,
    shift_reference,
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
        return assemble_groups(reduced, self._period, start, end, dropped, self._groups)


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
    return assemble_groups(kept, period_s, window_start_s, window_end_s, dropped, groups)
