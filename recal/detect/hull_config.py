"""The hull detector's settings and what it returns: :class:`HullConfig`, :class:`HullReport`,
:class:`HullWindow` (the detector is :mod:`recal.detect.hull`)."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from recal.detect.creep import MAX_CREEP_DPH
from recal.detect.rest import REST_REASONS
from recal.detect.windows import Window
from recal.errors import RecalInputError

#: Longest wave period the segmentation allows for (s): roll of a large hull at anchor.
LONGEST_WAVE_S = 20.0


@dataclass(frozen=True)
class HullConfig:
    """Settings of the hull detector; times in s, angles in deg, lengths in m."""

    block_s: float = 0.5
    turn_window_s: float = 60.0
    max_swing_deg: float = 1.0
    trim_s: float = 30.0
    min_window_s: float = 120.0
    max_window_s: float = 900.0
    lever_arm_max_m: float = 10.0
    max_gap_frames: int = 5
    #: the largest heading creep or anchor swing (deg/h) a window keeps where the ship's heading
    #: is unknown (recal.detect.creep): its vertical rate is then no measurement
    max_creep_dph: float = MAX_CREEP_DPH

    def __post_init__(self) -> None:
        for name in ("block_s", "turn_window_s", "min_window_s", "max_window_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise RecalInputError(f"hull detector {name} must be positive, not {v}")
        if self.min_window_s > self.max_window_s:
            raise RecalInputError("hull detector min_window_s exceeds max_window_s")
        if self.turn_window_s < 2 * LONGEST_WAVE_S:
            raise RecalInputError(
                f"turn_window_s {self.turn_window_s:g} s must span at least two of the longest "
                f"wave periods ({2 * LONGEST_WAVE_S:g} s)"
            )


@dataclass
class HullReport:
    """What the hull detector saw: blocks by state, windows kept and rejected by reason."""

    frames: int = 0
    sample_rate_hz: float | None = None
    blocks: int = 0
    blocks_turning: int = 0
    blocks_accelerating: int = 0
    blocks_fault: int = 0
    rejected: Counter = field(default_factory=Counter)
    rejected_stretches: list[tuple[float, float, str]] = field(default_factory=list)
    kept: int = 0

    def summary_lines(self) -> list[str]:
        rej = ", ".join(f"{r} {self.rejected.get(r, 0)}" for r in ("too_short", *REST_REASONS))
        lines = [
            f"hull detector: {self.kept} window(s) kept; rejected: {rej}",
            f"blocks: {self.blocks} ({self.blocks_turning} turning, {self.blocks_accelerating} "
            f"accelerating, {self.blocks_fault} with faults)",
        ]
        for a, b, why in self.rejected_stretches[:20]:
            lines.append(f"  {a:.1f}-{b:.1f} s ({b - a:.1f} s): {why}")
        return lines


@dataclass(frozen=True)
class HullWindow:
    """A quasi-static window and what its estimate rests on (the per-axis motion terms)."""

    window: Window
    gyro_motion_sem: np.ndarray  # (3,) output units: the waves' residual in the slope
    accel_motion_sem: np.ndarray  # (3,) output units: residual, lever arm, 2nd-order correction
    tilt_rms_deg: float  # RMS of the attitude oscillation about the mean, deg
    period_s: float  # effective period of that oscillation, s
