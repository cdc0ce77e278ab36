"""What the static detector saw and decided: :class:`DetectionReport` (counts, thresholds,
rejected stretches and their reasons, the plain-words summary) and :class:`DetectionResult`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from recal.detect.windows import Window

#: Reasons a static run is rejected, as keys of :attr:`DetectionReport.rejected`.
#: "gyro_not_still": the gyro was never quiet long enough in a still stretch of the accelerometer,
#: which is kept as an accelerometer-only window (rejected for the gyro, used for the accel).
REJECT_REASONS = ("too_short", "invalid_status", "sequence_gap", "rotating", "gyro_not_still")
#: Each reason in plain words, for summaries and reports.
REASON_TEXT = {
    "too_short": "too short",
    "invalid_status": "cut by invalid frames",
    "sequence_gap": "cut by a sequence gap",
    "rotating": "rotating (mean gyro off the reference)",
    "gyro_not_still": "gyro not still (used for the accelerometer only)",
    # the rest check in physics (recal.detect.rest)
    "turning": "turning (mean rate above Earth's rate, along gravity)",
    "swinging": "swinging (mean rate above Earth's rate, about a horizontal axis)",
    "rate_low": "mean rate below Earth's rate (a unit or rate setting, or not at rest)",
    "accelerating": "accelerating (mean specific force is not gravity)",
    # the ship's sensors (recal.detect.underway)
    "underway": "under way (the ship's mean speed over ground above the threshold)",
}
#: Rejected stretches listed in :attr:`DetectionReport.rejected_stretches` at most (the counts in
#: ``rejected`` stay complete): a plot needs them, and a noisy recording can have very many.
MAX_REJECTED_STRETCHES = 10_000
#: Rejected stretches the summary lists one by one (the rest are counted by reason).
MAX_LISTED_REJECTIONS = 20


@dataclass
class DetectionReport:
    """What the detector saw and decided; counts accumulate as frames are fed."""

    frames: int = 0
    invalid_frames: int = 0
    lost_frames: int = 0
    gaps: int = 0
    windows_kept: int = 0
    rejected: dict[str, int] = field(default_factory=lambda: dict.fromkeys(REJECT_REASONS, 0))
    sample_rate_hz: float | None = None
    window_samples: int | None = None
    accel_threshold: float | None = None
    gyro_threshold: float | None = None
    thresholds_learned: bool = False
    threshold_source: str = ""
    gyro_reference: np.ndarray | None = None
    duration_s: float = 0.0
    short_stretches: int = 0  # quiet stretches too short to give a window (no fault involved)
    longest_short_frames: int = 0  # the longest of them, quiet frames
    edge_trim_frames: int = 0
    required_frames: int = 0
    #: (start_s, end_s, reason) of rejected quiet stretches, times from the session start, in the
    #: order they were decided, at most MAX_REJECTED_STRETCHES. A quiet run too short as a whole
    #: is one "too_short" stretch; a piece of a long run cut short by a fault is listed under that
    #: fault; "rotating" and "invalid_status" give the trimmed run's first and last frame;
    #: "gyro_not_still" an accelerometer-only window's first and last frame.
    rejected_stretches: list[tuple[float, float, str]] = field(default_factory=list)
    #: Per-triad stillness: still stretches of the accelerometer (the poses seen), how many of
    #: them gave a window (for both triads or for the accelerometer only), and the windows kept
    #: for the accelerometer only (gyro not still). 0 with ``accel_only_windows`` off.
    still_stretches: int = 0
    still_stretches_used: int = 0
    accel_only_windows: int = 0
    #: (start_s, end_s) of rejected stretches that are part of a pose other windows use.
    in_used_pose: set[tuple[float, float]] = field(default_factory=set)

    def _add_stretches(self, start_s, end_s, reason) -> None:
        """List rejected stretches (scalars or arrays; reason one name or one per stretch)."""
        room = MAX_REJECTED_STRETCHES - len(self.rejected_stretches)
        start = np.atleast_1d(np.asarray(start_s, dtype=float))[:room]
        if room <= 0 or start.size == 0:
            return
        end = np.atleast_1d(np.asarray(end_s, dtype=float))[:room]
        why = np.broadcast_to(np.asarray(reason), (np.atleast_1d(start_s).shape[0],))[:room]
        self.rejected_stretches.extend(zip(start.tolist(), end.tolist(), why.tolist(), strict=True))

    def accepting_min_duration_s(self) -> float | None:
        """The largest min_duration_s that would keep the longest too-short quiet stretch, s
        (None when even 0 would not, because the edge trim eats it all)."""
        if not self.short_stretches or not self.sample_rate_hz:
            return None
        keep = self.longest_short_frames - 2 * self.edge_trim_frames
        return keep / self.sample_rate_hz if keep >= 2 else None

    def add_rest_rejections(self, windows: Sequence[Window], reasons: Sequence[str]) -> None:
        """Count the windows the rest check (:func:`recal.detect.rest.rest_filter`) rejected."""
        rejected = [(w, r) for w, r in zip(windows, reasons, strict=True) if r]
        for _w, r in rejected:
            self.rejected[r] = self.rejected.get(r, 0) + 1
        if rejected:
            self._add_stretches([w.start_s for w, _ in rejected], [w.end_s for w, _ in rejected],
                                np.array([r for _, r in rejected], dtype=object))  # fmt: skip
            self.windows_kept -= len(rejected)
            self.accel_only_windows -= sum(1 for w, _ in rejected if not w.gyro_still)

    def rejection_lines(self, limit: int = MAX_LISTED_REJECTIONS) -> list[str]:
        """One line per rejected stretch, in time order, saying why (at most ``limit``; then
        the count of the rest by reason)."""
        stretches = sorted(self.rejected_stretches)
        rate = self.sample_rate_hz
        need = (self.required_frames + 2 * self.edge_trim_frames) / rate if rate else None
        lines = []
        for a, b, why in stretches[:limit]:
            text = REASON_TEXT.get(why, why)
            if why == "too_short" and need:
                text += f" (a window needs {need:.3g} s of still frames)"
            if (a, b) in self.in_used_pose:
                text += "; part of a pose another window uses"
            lines.append(f"  {a:.2f}-{b:.2f} s ({b - a:.2f} s): {text}")
        rest = stretches[limit:]
        if rest:
            by = {}
            for _, _, why in rest:
                by[why] = by.get(why, 0) + 1
            more = ", ".join(f"{REASON_TEXT.get(k, k)} {v}" for k, v in by.items())
            lines.append(f"  ... and {len(rest)} more stretches: {more}")
        return (["rejected stretches (start-end, length: why):", *lines]) if lines else []

    def summary_lines(self) -> list[str]:
        """Plain-words summary, a few lines, for a log or the command line."""
        rate = f"{self.sample_rate_hz:.6g} Hz" if self.sample_rate_hz else "rate unknown"
        lines = [
            f"frames: {self.frames} ({self.duration_s:.1f} s at {rate}); "
            f"invalid status {self.invalid_frames}, lost {self.lost_frames} in {self.gaps} gaps"
        ]
        if self.accel_threshold is not None and self.gyro_threshold is not None:
            how = self.threshold_source or ("learned" if self.thresholds_learned else "given")
            lines.append(
                f"thresholds on the moving-variance trace over {self.window_samples} frames "
                f"({how}): accel {self.accel_threshold:.4g}, gyro {self.gyro_threshold:.4g}"
            )
        reasons = ", ".join(f"{k} {v}" for k, v in self.rejected.items())
        kept = f"{self.windows_kept} kept"
        if self.accel_only_windows:
            both = self.windows_kept - self.accel_only_windows
            kept += (
                f" ({both} with both triads still, {self.accel_only_windows} for the "
                "accelerometer only: gyro not still)"
            )
        lines.append(f"windows: {kept}; rejected: {reasons}")
        if self.still_stretches:
            lines.append(
                f"poses: {self.still_stretches} still stretches of the accelerometer seen, "
                f"{self.still_stretches_used} used, "
                f"{self.still_stretches - self.still_stretches_used} without any window"
            )
        lines += self.rejection_lines()
        if self.short_stretches and self.sample_rate_hz:
            rate = self.sample_rate_hz
            need = (self.required_frames + 2 * self.edge_trim_frames) / rate
            line = (
                f"{self.short_stretches} quiet stretches too short to keep (longest "
                f"{self.longest_short_frames / rate:.3g} s of quiet frames; a window needs "
                f"{need:.3g} s: min_duration_s + 2 x edge_trim_s)"
            )
            shortest = self.accepting_min_duration_s()
            if shortest is not None:
                line += f"; min_duration_s {math.floor(shortest * 1000) / 1000:g} would keep it"
            else:
                line += "; lower edge_trim_s and min_duration_s to keep it"
            lines.append(line)
        return lines


@dataclass
class DetectionResult:
    windows: list[Window]
    report: DetectionReport
