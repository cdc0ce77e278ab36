"""The static-window detector: finds the still periods of an IMU recording and averages them.

This module keeps the detector's names importable from one place; each piece lives in a module
of its own (issue 27):

* :mod:`recal.detect.static_config`: :class:`DetectorConfig` (how windows are found) and
  :data:`DEFAULT_MAX_GAP_FRAMES`;
* :mod:`recal.detect.static_report`: :class:`DetectionReport` (what the detector saw and
  decided), :class:`DetectionResult`, the rejection reasons (:data:`REJECT_REASONS`,
  :data:`REASON_TEXT`) and the listing limits;
* :mod:`recal.detect.static_sums`: the buffer's row layout and the chunk-independent sums
  (moving variance, window sums, Allan block sums) the detector decides from;
* :mod:`recal.detect.static_detector`: :class:`StaticDetector` (the streaming detector, with the
  method described in its module docstring) and :func:`detect_static` (a whole recording);
* :mod:`recal.detect.static_accel_only`: per-triad stillness, the part of the detector that
  keeps accelerometer-only windows, and :data:`GYRO_QUIET_SHARE`.

The noise floor the thresholds follow is :mod:`recal.detect.floor`, the window table
:mod:`recal.detect.windows`, the noise model :mod:`recal.detect.noise`.
"""

from __future__ import annotations

# imported here before the split too (``as``: re-exported)
from recal.detect.floor import NoiseFloor as NoiseFloor
from recal.detect.floor import default_window_s as default_window_s
from recal.detect.floor import estimate_noise_floor as estimate_noise_floor
from recal.detect.static_accel_only import GYRO_QUIET_SHARE
from recal.detect.static_config import DEFAULT_MAX_GAP_FRAMES, DetectorConfig
from recal.detect.static_detector import StaticDetector, detect_static
from recal.detect.static_report import (
    MAX_LISTED_REJECTIONS,
    MAX_REJECTED_STRETCHES,
    REASON_TEXT,
    REJECT_REASONS,
    DetectionReport,
    DetectionResult,
)
from recal.detect.windows import Window as Window

#: The names ``from recal.detect.static import *`` gives (those it defined before the split).
__all__ = [
    "REJECT_REASONS",
    "GYRO_QUIET_SHARE",
    "REASON_TEXT",
    "MAX_REJECTED_STRETCHES",
    "MAX_LISTED_REJECTIONS",
    "DEFAULT_MAX_GAP_FRAMES",
    "DetectorConfig",
    "DetectionReport",
    "DetectionResult",
    "StaticDetector",
    "detect_static",
]
