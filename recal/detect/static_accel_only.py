"""Per-triad stillness: the accelerometer-only windows of the static detector.

A stretch where the accelerometer is quiet but the gyro is not (a unit held by hand: the tremor
shows on the gyro, far less on gravity) is still a pose for the accelerometer. The detector runs a
second track that judges the accelerometer alone; :class:`AccelOnlyWindows` folds that track's
decisions into the both-triad track's windows and report: each of its runs in which the
both-triad track kept no window becomes an *accelerometer-only* window (``Window.gyro_still``
False). It is a part of :class:`recal.detect.static_detector.StaticDetector` and works on that
detector's state (its report, its windows and its accel track).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from recal.detect.static_sums import allan_window_sem
from recal.detect.windows import Window

#: An accelerometer-only window needs the gyro loud through the pose (tremor): when one quiet
#: stretch of both triads covers this share of the accelerometer's still run, the gyro was
#: still and only the edges moved (a short pose whose slews the accelerometer cannot see yet),
#: and the run stays rejected as the both-triad detector found it. Tremor leaves the gyro quiet
#: for a few tenths of a second at a time (at most 0.32 of a pose in the hand-held simulations),
#: a 0.6 s hold between turns of a FOG for about 0.75 of the accelerometer's run.
GYRO_QUIET_SHARE = 0.5


class AccelOnlyWindows:
    """The :class:`~recal.detect.static_detector.StaticDetector` methods that merge its
    accelerometer-only track (``_accel_track``) into its own windows and report."""

    # ---- per-triad stillness ----------------------------------------------------------------
    def _merge_accel(self, accel_windows: list[Window]) -> None:
        """Fold the accel track's decisions into this (both-triad) track's windows and report.

        Both-triad quiet frames are a subset of the accel's, and both tracks trim alike, so
        every both-triad window or rejection inside an accel run is decided no later than the
        run itself: by now this track has decided all that overlaps what the accel track
        returns. An accel window that overlaps a both-triad window is that pose seen again
        (dropped); one that does not becomes an accelerometer-only window, and the both-triad
        rejections inside it (tremor cut the gyro's quiet frames short) give way to one
        "gyro_not_still" stretch, unless one both-triad quiet stretch covers GYRO_QUIET_SHARE
        of the run (a still gyro, moving edges: the pose stays rejected as this track found
        it). An accel-track rejection overlapping nothing of this track is a pose the gyro hid
        from it (listed); otherwise this track has listed it already.
        """
        rep, track = self.report, self._accel_track.report
        own = rep.rejected_stretches
        self._covered += [(w.start_s, w.end_s, None) for w in self._out]
        self._covered += [(a, b, st) for st in own[self._stretches_seen :] for a, b in [st[:2]]]
        drop: set[int] = set()
        # a window is its quiet run trimmed: the run's both-triad rejections reach T frames out
        reach = (self._geom.trim + 0.5) / self._geom.rate if self._geom is not None else 0.0
        for w in accel_windows:
            hit = self._overlapping(w.start_s - reach, w.end_s + reach)
            rep.still_stretches += 1
            if any(c[2] is None for c in hit):  # the both-triad windows use this pose
                rep.still_stretches_used += 1
                parts = [c[2] for c in hit if c[2] is not None and c[2][:2] not in rep.in_used_pose]
                rep.in_used_pose.update(st[:2] for st in parts)
                self._short_seen(-sum(st[2] == "too_short" for st in parts), 0.0)
                continue
            run = (w.start_s - reach, w.end_s + reach)
            longest = max((min(b, run[1]) - max(a, run[0]) for a, b, _ in hit), default=0.0)
            if longest >= GYRO_QUIET_SHARE * (run[1] - run[0]):
                continue  # a short pose with motion at its edges, not tremor: as rejected
            for _, _, st in hit:
                if id(st) not in drop:
                    drop.add(id(st))
                    rep.rejected[st[2]] -= 1
            std = np.concatenate((w.gyro_std, w.accel_std))
            sem = allan_window_sem(w.samples, std, w.allan_sq, w.allan_terms, w.block_frames)
            self._out.append(replace(w, gyro_still=False, gyro_sem=sem[:3], accel_sem=sem[3:]))
            rep.still_stretches_used += 1
            rep.windows_kept += 1
            rep.accel_only_windows += 1
            rep.rejected["gyro_not_still"] += 1
            rep._add_stretches(w.start_s, w.end_s, "gyro_not_still")
        for a, b, why in track.rejected_stretches[self._track_seen :]:
            hit = self._overlapping(a, b)
            rep.still_stretches += 1
            if any(c[2] is None for c in hit):
                rep.still_stretches_used += 1  # e.g. a turn inside it: both sides kept
            elif not hit:  # the gyro hid this pose from the both-triad track: list it
                rep.rejected[why] += 1
                rep._add_stretches(a, b, why)
                if why == "too_short":
                    self._short_seen(1, b - a)
        self._track_seen = len(track.rejected_stretches)
        if drop:
            gone = [st for st in own if id(st) in drop]
            rep.rejected_stretches = [st for st in own if id(st) not in drop]
            self._covered = [c for c in self._covered if c[2] is None or id(c[2]) not in drop]
            self._short_seen(-sum(st[2] == "too_short" for st in gone), 0.0)
        self._stretches_seen = len(rep.rejected_stretches)
        self._out.sort(key=lambda w: w.start_index)
        self._prune_covered()

    def _short_seen(self, count: int, span_s: float) -> None:
        """Keep the too-short tally right: tremor fragments absorbed by an accelerometer-only
        window, or part of a pose other windows use, are no pose lost; a short pose only the
        accel track saw is one."""
        rep = self.report
        rep.short_stretches = max(rep.short_stretches + count, 0)
        rate = self._geom.rate
        if count > 0:
            frames = round(span_s * rate) + 1
            rep.longest_short_frames = max(rep.longest_short_frames, frames)
        elif count < 0:  # the longest left, from the listed stretches
            left = [b - a for a, b, why in rep.rejected_stretches
                    if why == "too_short" and (a, b) not in rep.in_used_pose]  # fmt: skip
            rep.longest_short_frames = round(max(left) * rate) + 1 if left else 0

    def _overlapping(self, start_s: float, end_s: float) -> list[tuple]:
        return [c for c in self._covered if c[0] <= end_s and c[1] >= start_s]

    def _prune_covered(self) -> None:
        """Forget what ends before the accel track's first undecided frame."""
        track = self._accel_track
        if track is None or track._geom is None or track._learning:
            return
        open_at = [track._next_m]
        if track._c_open is not None:
            open_at.append(track._c_open)
        if track._q_open is not None:
            open_at.append(track._q_open[0])
        if track._piece is not None:
            open_at.append(track._piece.first)
        first = min(open_at)
        if first >= track._received:
            self._covered = []
            return
        t = float(track._times(np.array([first]))[0])
        self._covered = [c for c in self._covered if c[1] >= t]
