"""The static detector's rejections: quiet pieces too short to keep, counted and listed by cause.

A candidate is a run of quiet frames ignoring faults; a fault longer than the detector's
``max_gap_frames`` cuts it into pieces. :class:`RejectionCounts` counts the pieces too short to
keep under ``too_short`` or the fault that cut them, and lists each such stretch in session time.
It is a part of :class:`recal.detect.static_detector.StaticDetector` and works on that
detector's state (its geometry, buffer and report).
"""

from __future__ import annotations

import numpy as np

from recal.detect.static_sums import COL_T, run_edges

#: The fault kinds of the detector's labels, by code (0 is none).
FAULT_NAMES = {1: "invalid_status", 2: "sequence_gap"}


class RejectionCounts:
    """The :class:`~recal.detect.static_detector.StaticDetector` methods that count and list
    the quiet stretches too short to keep."""

    # ---- rejections ---------------------------------------------------------------------------
    def _count_rejections(self, lo: int, vq, q, fault) -> None:
        """Count quiet pieces too short to keep, by why they are short.

        A candidate is a run of quiet frames ignoring faults. If even the whole candidate is too
        short, that is one "too_short". Otherwise each piece cut too short by a fault counts
        under that fault ("invalid_status" or "sequence_gap").
        """
        g = self._geom
        if vq.size == 0:
            return
        need = g.required + 2 * g.trim
        # Runs of q (pieces) that close here, with the fault on their left and right.
        q_st, q_en = run_edges(self._prev_q, q)
        left = np.where(q_st > 0, fault[np.maximum(q_st - 1, 0)], self._prev_fault)
        starts, lefts = q_st + lo, left.astype(np.int64)
        if self._q_open is not None:
            starts = np.concatenate(([self._q_open[0]], starts))
            lefts = np.concatenate(([self._q_open[1]], lefts))
        closed = q_en.shape[0]
        p_start, p_left = starts[:closed], lefts[:closed]
        p_len = q_en + lo - p_start
        p_right = fault[q_en].astype(np.int64)
        self._q_open = (int(starts[-1]), int(lefts[-1])) if starts.shape[0] > closed else None
        short = p_len < need
        cause = np.where(p_left != 0, p_left, p_right)[short]
        p_short_start = p_start[short]
        # Candidates (runs of vq) and which one holds each short piece.
        c_st, c_en = run_edges(self._prev_vq, vq)
        c_starts = c_st + lo
        carried = self._c_open is not None
        if carried:
            c_starts = np.concatenate(([self._c_open], c_starts))
        c_closed = c_en.shape[0]
        c_len = c_en + lo - c_starts[:c_closed]
        owner = np.searchsorted(c_starts, p_short_start, side="right") - 1
        per_c = np.zeros((c_starts.shape[0], 3), dtype=np.int64)
        np.add.at(per_c, (owner, cause), 1)
        if carried:
            per_c[0] += self._c_pending
        rejected = self.report.rejected
        long_c = c_len >= need
        short_len = c_len[~long_c]
        if short_len.size:
            self.report.short_stretches += int(short_len.size)
            longest = max(self.report.longest_short_frames, int(short_len.max()))
            self.report.longest_short_frames = longest
        rejected["too_short"] += int((~long_c).sum()) + int(per_c[:c_closed][long_c, 0].sum())
        for kind, name in FAULT_NAMES.items():
            rejected[name] += int(per_c[:c_closed][long_c, kind].sum())
        if short.any() or (~long_c).any() or self._c_pieces.shape[0]:
            self._list_rejections(lo, q_en[short] + lo - 1, p_short_start, cause, owner,
                                  c_starts, c_en + lo - 1, long_c, carried)  # fmt: skip
        if c_starts.shape[0] > c_closed:
            self._c_open, self._c_pending = int(c_starts[-1]), per_c[-1]
        else:
            self._c_open, self._c_pending = None, np.zeros(3, dtype=np.int64)
        self._prev_vq, self._prev_q, self._prev_fault = bool(vq[-1]), bool(q[-1]), int(fault[-1])

    def _list_rejections(self, lo, p_last, p_first, cause, owner, c_first, c_last, long_c, carried):
        """The stretches behind the counts of :meth:`_count_rejections`, as session times.

        Short pieces wait with their candidate (times taken now, while their frames are held):
        they are listed under their fault once it closes long, else the candidate is one
        too_short stretch.
        """
        rep = self.report
        c_closed = c_last.shape[0]
        short_c = np.flatnonzero(~long_c)
        rep._add_stretches(self._times(c_first[short_c]), self._times(c_last[short_c]), "too_short")
        pieces = np.column_stack((self._times(p_first), self._times(p_last), cause))
        if carried:  # pieces of the candidate open before this call belong to owner 0
            pieces = np.concatenate((self._c_pieces, pieces))
            owner = np.concatenate((np.zeros(self._c_pieces.shape[0], dtype=owner.dtype), owner))
        done = owner < c_closed
        keep = np.zeros_like(done)
        keep[done] = long_c[owner[done]]
        names = np.array(["too_short", *FAULT_NAMES.values()])
        listed = pieces[keep]
        rep._add_stretches(listed[:, 0], listed[:, 1], names[listed[:, 2].astype(int)])
        self._c_pieces = pieces[~done]

    def _times(self, index: np.ndarray) -> np.ndarray:
        """Session times (s) of frame indices; a frame no longer held is placed by the rate."""
        index = np.asarray(index, dtype=np.int64)
        if index.size == 0:
            return np.zeros(0)
        k = np.clip(index - self._base, 0, self._data.shape[0] - 1)
        held = self._data[k, COL_T] - self._t0
        before = self._data[0, COL_T] - self._t0 - (self._base - index) / self._geom.rate
        return np.where(index >= self._base, held, before)
