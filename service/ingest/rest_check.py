"""The rest check of the ingest (:class:`RestCheck`): the static detector's windows that are at
rest in physics too (recal.detect.rest: a steady turn has a quiet moving variance but not Earth's
rate), the reference rebuilt at the ship's latitude, and a ``device`` event when every window
fails it alike (a wrong rate or unit setting)."""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from recal.detect.rest import RestReference, rest_filter
from recal.detect.windows import Window
from service.events import Events

#: The rest reference is rebuilt at the ship's latitude when it has moved by more than this, deg.
REST_LATITUDE_STEP_DEG = 0.05


class RestCheck:
    """Judges windows against ``reference`` (None: no rest check, every window passes), counts
    those it refuses by reason in the detector's report, and follows the ship's latitude
    through ``rest_at(latitude)`` (which builds the reference there). ``rate_hz`` is the
    configured sample rate, named in the ``device`` event."""

    def __init__(
        self,
        reference: RestReference | None,
        events: Events,
        rest_at: Callable[[float], RestReference | None] | None = None,
        rate_hz: float | None = None,
    ) -> None:
        self.reference = reference
        self._events = events
        self._rest_at = rest_at
        self._rate_hz = rate_hz or 0.0
        self._latitude: float | None = None  # the newest latitude given, not yet applied
        self._built_at: float | None = None  # the latitude the reference is built at
        self.seen = self.refused = 0  # static windows judged / refused
        self._refused_norms: deque[tuple[float, float]] = deque(maxlen=50)  # deg/h, g
        self._warned: list[str] = []

    @property
    def source(self) -> str | None:
        """Where the reference comes from (``/health`` detector.rest_check), None without one."""
        return None if self.reference is None else self.reference.source

    def nav_latitude(self, latitude_deg: float) -> None:
        """The ship's sensors give this latitude (any thread; returns at once): the reference
        is rebuilt at it by :meth:`follow_latitude`, when it has moved by more than
        :data:`REST_LATITUDE_STEP_DEG` (gravity moves by 0.1 mg a degree, Earth's vertical rate
        by 0.26 deg/h)."""
        self._latitude = float(latitude_deg)

    def follow_latitude(self) -> RestReference | None:
        """Rebuild the reference at the latitude given last, if it moved enough; the new
        reference, or None when it is unchanged."""
        lat = self._latitude
        if lat is None or self._rest_at is None:
            return None
        if self._built_at is not None and abs(lat - self._built_at) <= REST_LATITUDE_STEP_DEG:
            return None
        ref = self._rest_at(lat)
        if ref is None:
            return None
        first = self._built_at is None
        self._built_at = lat
        self.reference = ref
        if first:
            self._events.emit("nav", f"the ship's sensors give latitude {lat:.4f} deg: the rest "
                              "check uses it from now on", {"latitude_deg": round(lat, 6)})  # fmt: skip
        return ref

    def check(self, windows: list[Window], report: Any) -> list[Window]:
        """The windows at rest in physics; the others counted by reason in the detector's
        ``report``. When every window so far failed it, the windows' norms may say a
        ``[device]`` setting is wrong (as the scheduler would say of stored ones): a ``device``
        event."""
        if not windows or self.reference is None:
            return windows
        kept, reasons = rest_filter(windows, self.reference)
        report.add_rest_rejections(windows, reasons)
        refused = [w for w, r in zip(windows, reasons, strict=True) if r]
        self.seen += len(windows)
        self.refused += len(refused)
        if refused:
            ref = self.reference
            rate = np.linalg.norm(ref.rate_dph(np.array([w.gyro for w in refused])), axis=1)
            force = np.linalg.norm(ref.force_g(np.array([w.accel for w in refused])), axis=1)
            self._refused_norms.extend(zip(rate.tolist(), force.tolist(), strict=True))
            if self.refused == self.seen >= 4:
                self._warn_units()
        return kept

    def _warn_units(self) -> None:
        """A ``device`` event when the refused windows agree on norms far from Earth's rate or
        gravity (a wrong rate or unit setting scales them all alike; motion scatters them)."""
        from recal.detect.plausibility import MAX_FACTOR, UnitCheck
        from recal.model.reference import OMEGA_IE_DEG_H

        ref = self.reference
        rate, force = np.array(self._refused_norms).T
        for norms in (rate, force):
            if not (np.all(norms > 0) and norms.max() <= MAX_FACTOR * norms.min()):
                return
        check = UnitCheck(float(np.median(rate)) / OMEGA_IE_DEG_H,
                          float(np.median(force)) / ref.gravity_g)  # fmt: skip
        problems = check.problems(
            "[device] rate_hz", self._rate_hz, "[device] gyro_output / gyro_units"
        )
        if problems and problems != self._warned:
            self._events.emit("device", "every window so far fails the rest check: "
                              + "; ".join(problems), level=logging.WARNING)  # fmt: skip
        self._warned = problems
