"""The static detector's configuration: how windows are found (:class:`DetectorConfig`).

Durations in s; thresholds on the moving-variance trace in (input units)^2. The detector itself
is :mod:`recal.detect.static_detector`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from recal.detect.floor import NoiseFloor, default_window_s
from recal.errors import RecalInputError

#: Default max_gap_frames: holes a window bridges (see DetectorConfig).
DEFAULT_MAX_GAP_FRAMES = 5


@dataclass(frozen=True)
class DetectorConfig:
    """How static windows are found. Durations in s; thresholds in (input units)^2.

    Durations left at None follow the sample rate (see :meth:`durations`).

    window_s: length of the centred moving-variance window. Default about 100 frames, between
        0.1 s and 1 s (:func:`default_window_s`): 1 s at 100 Hz, 0.1 s at 1 kHz. The trace of
        white noise then spreads about 8 % at any rate, and the window is short enough for a 1 s
        hold at 1 kHz while a slew is still seen (its rate changes by far more than the gyro
        noise within 0.1 s).
    min_duration_s: shortest window kept, after trimming. Default max(window_s, 0.5 s): a mean
        over at least one moving window (1 s at 100 Hz) and at least 0.5 s, so that a turning
        point of a motion cannot pass for a hold, while a 1 s hold at 1 kHz (0.8 s after the
        window and the trim) is kept.
    edge_trim_s: dropped at both ends of a run (and next to a fault). The run already starts
        half a window after the last loud frame; the trim also drops the settling tail that stays
        below the threshold. Default window_s / 2 (0.5 s at 100 Hz, 0.05 s at 1 kHz): the first
        frame averaged is then a whole moving window after the last loud one.
    accel_threshold, gyro_threshold: explicit limits on the moving-variance trace. Each one not
        given is threshold_k x the noise floor: ``noise_floor`` when given, else learned from the
        initial still period ``init_still_s``. :class:`StaticDetector` needs one of the three;
        :func:`detect_static` estimates the noise floor itself when none is given.
    init_still_s: the recording starts with this long a still period (imu_tk uses 50 s).
    noise_floor: the moving-variance trace of still data, from :func:`estimate_noise_floor` or
        :class:`NoiseFloorEstimator` (a first pass over the recording, or a stored value).
    threshold_k: threshold = k x noise floor. On white noise the trace spreads about 8 %
        (W = 101) and real still periods reach 1.3x the median; poses of the Xsens recording
        reach 3.5x from settling, so 5 leaves headroom while a disturbance of twice the noise
        RMS is already rejected.
    sample_rate_hz: frames per second; derived from the median time step of the first 1024
        frames when not given.
    max_gap_frames: longest hole (consecutive invalid frames, or frames lost in one gap) a
        window may contain; a longer one splits the run. Default 5: a missing frame does not
        bias a static mean (the mean of the others estimates the same constant), it only removes
        one sample, so splitting there throws data away (a capture losing 0.1 % of its frames
        gave 224 windows from 24 holds). 5 frames stay far below the moving window (about 100
        frames), which still sees the motion around a hole.
    gyro_rate_max: when set, reject a window whose mean gyro differs from the reference (the
        still-period mean when learning, else zero) by more than this, in gyro units (vector
        norm). Variance cannot see a steady rotation about the gravity vector; this can.
    accel_only_windows: per-triad stillness (default on). A still stretch of the accelerometer
        in which the gyro never stays under its threshold long enough for a window (hand
        tremor) becomes an accelerometer-only window (``Window.gyro_still`` False) instead of
        being dropped. Off: every window needs both triads still. A gyro_threshold of inf
        lets the gyro veto nothing.
    """

    window_s: float | None = None
    min_duration_s: float | None = None
    edge_trim_s: float | None = None
    accel_threshold: float | None = None
    gyro_threshold: float | None = None
    init_still_s: float | None = None
    threshold_k: float = 5.0
    sample_rate_hz: float | None = None
    max_gap_frames: int = DEFAULT_MAX_GAP_FRAMES
    gyro_rate_max: float | None = None
    noise_floor: NoiseFloor | None = None
    accel_only_windows: bool = True

    def __post_init__(self) -> None:
        if not (math.isfinite(self.threshold_k) and self.threshold_k > 0):
            raise RecalInputError(
                f"detector threshold_k must be a positive number, not {self.threshold_k}"
            )
        optional_positive = {
            "window_s": self.window_s,
            "min_duration_s": self.min_duration_s,
            "init_still_s": self.init_still_s,
            "sample_rate_hz": self.sample_rate_hz,
            "gyro_rate_max": self.gyro_rate_max,
        }
        for name, value in optional_positive.items():
            if value is not None and not (math.isfinite(value) and value > 0):
                raise RecalInputError(f"detector {name} must be a positive number, not {value}")
        for name in ("accel_threshold", "gyro_threshold"):
            value = getattr(self, name)
            if value is not None and (math.isnan(value) or value < 0):
                raise RecalInputError(f"detector {name} must be a number >= 0, not {value}")
        trim = self.edge_trim_s
        if trim is not None and not (math.isfinite(trim) and trim >= 0):
            raise RecalInputError(f"detector edge_trim_s must be >= 0, not {trim}")
        if int(self.max_gap_frames) != self.max_gap_frames or self.max_gap_frames < 0:
            raise RecalInputError(
                f"detector max_gap_frames must be a whole number >= 0, not {self.max_gap_frames}"
            )

    @property
    def has_thresholds(self) -> bool:
        """Whether the thresholds are given or can be learned without a first pass."""
        both = self.accel_threshold is not None and self.gyro_threshold is not None
        return both or self.init_still_s is not None or self.noise_floor is not None

    def durations(self, rate_hz: float) -> tuple[float, float, float]:
        """(window_s, edge_trim_s, min_duration_s) at ``rate_hz``, the defaults filled in."""
        window = default_window_s(rate_hz) if self.window_s is None else self.window_s
        trim = window / 2 if self.edge_trim_s is None else self.edge_trim_s
        shortest = max(window, 0.5) if self.min_duration_s is None else self.min_duration_s
        return window, trim, shortest
