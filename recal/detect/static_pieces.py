"""The static detector's windows: trimmed quiet runs as running sums, closed into windows.

Runs of quiet frames are eroded by the edge trim; the frames kept are added to running sums
(:class:`recal.detect.static_sums.Piece`, with Allan block sums aligned on the global frame
index), and a run that closes becomes a :class:`~recal.detect.windows.Window`, or is counted as
rejected (``invalid_status``, ``rotating``). :class:`PieceWindows` is a part of
:class:`recal.detect.static_detector.StaticDetector` and works on that detector's state.
"""

from __future__ import annotations

import math

import numpy as np

from recal.detect.noise import allan_sums
from recal.detect.static_sums import (
    BLOCK_FEATS,
    COL_A,
    COL_G,
    COL_T,
    COL_VALID,
    Piece,
    add_blocks,
    allan_window_sem,
    piece_features,
    run_edges,
)
from recal.detect.windows import Window


class PieceWindows:
    """The :class:`~recal.detect.static_detector.StaticDetector` methods that trim the quiet
    runs, keep their running sums and turn the closed ones into windows."""

    # ---- windows ------------------------------------------------------------------------------
    def _trim(self, lo: int, q: np.ndarray, final: bool) -> None:
        """Erode the pieces by the edge trim: frame j is kept when q holds on [j-T, j+T]."""
        T = self._geom.trim
        ext = np.concatenate((self._qhist, q))
        ext_lo = self._next_m - T  # global index of ext[0]
        hi = lo + q.shape[0]
        if final:
            ext = np.concatenate((ext, np.zeros(T, dtype=bool)))  # nothing after the end
        else:
            hi -= T
        if hi <= self._next_m:
            self._qhist = ext
            return
        loud = np.concatenate(([0], np.cumsum(~ext, dtype=np.int64)))
        j = np.arange(self._next_m, hi) - ext_lo
        m = (loud[j + T + 1] - loud[j - T]) == 0
        d0 = self._next_m
        self._next_m = hi
        self._qhist = ext[hi - T - ext_lo : hi + T - ext_lo] if not final else ext[:0]
        self._accumulate(d0, m, final)

    def _accumulate(self, d0: int, m: np.ndarray, final: bool) -> None:
        """Add kept frames [d0, d0 + len(m)) to running sums; finish the windows that close."""
        rows = self._view(d0, d0 + m.shape[0])
        st, en = run_edges(self._prev_m, m)
        piece = self._piece
        if piece is not None and (en.shape[0] and en[0] == 0):
            self._finish(piece)  # closed right at the chunk boundary
            piece = None
            en = en[1:]
        sel = np.flatnonzero(m)
        if sel.size:
            cont = piece is not None  # the first segment continues the open piece
            seg_starts = np.concatenate(([0], st)) if cont else st
            seg_pos = np.searchsorted(sel, seg_starts)
            seg_id = np.searchsorted(seg_starts, sel, side="right") - 1
            first_rows = rows[seg_starts]
            t_first = first_rows[:, COL_T].copy()
            g_ref = first_rows[:, COL_G].copy()
            a_ref = first_rows[:, COL_A].copy()
            bad_ref = first_rows[:, COL_VALID] == 0  # an invalid first frame may hold garbage
            g_ref[bad_ref], a_ref[bad_ref] = self._g_ref, self._a_ref
            if cont:
                t_first[0], g_ref[0], a_ref[0] = piece.t_first, piece.g_ref, piece.a_ref
            prev_in = np.concatenate(([self._prev_m], m[:-1]))[sel]
            feats = piece_features(
                rows[sel],
                prev_in,
                t_first[seg_id],
                g_ref[seg_id],
                a_ref[seg_id],
                0.0 if math.isnan(self._temp_ref) else self._temp_ref,
            )
            sums = np.add.reduceat(feats, seg_pos, axis=0)
            # Block sums for the Allan statistics: blocks aligned on the global frame index, so
            # every chunking cuts them alike; a block counts once all its frames are kept.
            B = self._geom.block
            bid = (d0 + sel) // B
            cut = np.ones(sel.shape[0], dtype=bool)
            cut[1:] = (bid[1:] != bid[:-1]) | (seg_id[1:] != seg_id[:-1])
            g_pos = np.flatnonzero(cut)
            g_sums = np.add.reduceat(feats[:, BLOCK_FEATS], g_pos, axis=0)
            g_len = np.diff(g_pos, append=sel.shape[0])
            g_of_seg = np.searchsorted(seg_id[g_pos], np.arange(seg_starts.shape[0] + 1))
            ends = np.concatenate((en, [m.shape[0]])) if m[-1] else en
            for k in range(seg_starts.shape[0]):
                last = d0 + int(ends[k]) - 1
                if k == 0 and cont:
                    piece.sums = piece.sums + sums[0]
                    piece.last, piece.t_last = last, float(rows[ends[k] - 1, COL_T])
                else:
                    piece = Piece(
                        first=d0 + int(seg_starts[k]),
                        last=last,
                        t_first=float(t_first[k]),
                        t_last=float(rows[ends[k] - 1, COL_T]),
                        g_ref=g_ref[k],
                        a_ref=a_ref[k],
                        sums=sums[k],
                    )
                closes = k < seg_starts.shape[0] - 1 or not m[-1]
                gs = slice(g_of_seg[k], g_of_seg[k + 1])
                add_blocks(piece, bid[g_pos[gs]], g_len[gs], g_sums[gs], B, still_open=not closes)
                if closes:
                    self._finish(piece)
                    piece = None
        if final and piece is not None:
            self._finish(piece)
            piece = None
        self._piece = piece
        if m.size:
            self._prev_m = bool(m[-1])

    def _finish(self, piece: Piece) -> None:
        """Turn a closed trimmed run into a window, or count why it is rejected."""
        g = self._geom
        if piece.last - piece.first + 1 < g.required:
            return  # already counted as a short piece when its quiet run closed
        s = piece.sums
        n = s[0]
        rejected = self.report.rejected
        span = (piece.t_first - self._t0, piece.t_last - self._t0)
        if n < 2:
            rejected["invalid_status"] += 1
            self.report._add_stretches(*span, "invalid_status")
            return
        d_g, d_a = s[1:4] / n, s[7:10] / n
        gyro = piece.g_ref + d_g
        limit = self.config.gyro_rate_max
        if limit is not None and float(np.linalg.norm(gyro - self._gyro_ref)) > limit:
            rejected["rotating"] += 1
            self.report._add_stretches(*span, "rotating")
            return
        var_g = np.maximum(s[4:7] - s[1:4] * d_g, 0.0) / (n - 1)
        var_a = np.maximum(s[10:13] - s[7:10] * d_a, 0.0) / (n - 1)
        kept = piece.last - piece.first + 1
        allan_sq, allan_terms = allan_sums(piece.blocks, g.block)
        nt, st, stt, sv, stv = s[13:18]
        temp, rate = math.nan, math.nan
        if nt > 0:
            temp = sv / nt + self._temp_ref
            den = nt * stt - st * st
            if nt >= 2 and den > 0:
                rate = (nt * stv - st * sv) / den * 3600.0  # degC/s -> degC/h
        t0 = self._t0
        std = np.sqrt(np.concatenate((var_g, var_a)))
        sem = (
            allan_window_sem(int(n), std, allan_sq, allan_terms, g.block) if self._own_sem else None
        )
        self._out.append(
            Window(
                start_s=piece.t_first - t0,
                end_s=piece.t_last - t0,
                start_index=piece.first,
                end_index=piece.last,
                samples=int(n),
                gyro=gyro,
                accel=piece.a_ref + d_a,
                gyro_std=std[:3],
                accel_std=std[3:],
                temperature_c=float(temp),
                temperature_rate_c_per_h=float(rate),
                frames_lost=int(s[19]),
                frames_invalid=int(s[18]),
                accel_mvar=float(s[20] / kept),
                gyro_mvar=float(s[21] / kept),
                block_frames=g.block,
                allan_sq=allan_sq,
                allan_terms=allan_terms,
                gyro_sem=np.full(3, np.nan) if sem is None else sem[:3],  # its own samples
                accel_sem=np.full(3, np.nan) if sem is None else sem[3:],
            )
        )

        self.report.windows_kept += 1
