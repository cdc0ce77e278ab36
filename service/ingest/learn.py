"""Learning the first noise floor from the frames held (:class:`Learner`), before the static
detector can start: when to end it (device time learned, a quiet or slow stream, the end of
input), what it learned, and how ``/health`` and the events say so."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from recal.detect.floor import NoiseFloor, NoiseFloorEstimator
from recal.errors import RecalInputError
from service.events import Events

#: While the first noise floor is learned, a step in device time between two frames longer than
#: this (s) is a gap or a clock reset: it is not counted as time learned.
LEARN_MAX_STEP_S = 1.0
#: Why learning the first noise floor ended, by code (``/health`` detector.learning.ended_by).
LEARN_ENDS = ("device_time", "quiet", "wall_time", "end_of_input", "stopping")


class Learner:
    """Holds frames and feeds the noise-floor estimator until ``learn_s`` of device time.

    Learning also ends, from what is held, when no more frames will come or may come soon: the
    stream has ended (``final``), has sent nothing for ``learn_quiet_s`` (a stream left open and
    quiet) or has taken ``learn_s`` of wall time without ``learn_s`` of device time (a slow or
    short stream): held forever, those frames would never become windows. Such an early end is
    said in a ``noise_floor`` event. ``clock`` is host time (s). Without an ``estimator``
    (:meth:`estimate_with` gives it) there is nothing to learn (thresholds given, a floor
    stored, an initial still period, the hull detector): the learner reports "not needed"."""

    def __init__(
        self,
        events: Events,
        estimator: NoiseFloorEstimator | None = None,
        learn_s: float = 120.0,
        learn_quiet_s: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._estimator = estimator
        self._events = events
        self._clock = clock
        self.learn_s = learn_s
        self.learn_quiet_s = learn_quiet_s
        self._held: list[Any] = []  # frames held while the first noise floor is learned
        self.learned_s = 0.0  # device time of the frames held (steps beyond a gap not counted)
        self._last_t: float | None = None  # device time of the last frame held
        self._started: float | None = None  # host time the first frame was held
        self.took_s: float | None = None  # host time learning took, once it has ended
        self._tried_s = -1.0  # learned_s at the last early attempt that failed
        self.ended_by: str | None = None  # a LEARN_ENDS code once learned from frames
        self.message: str | None = None  # why it ended (or failed), in plain words
        self._last_frame_at: float | None = None  # host time of the last frame fed

    def estimate_with(self, estimator: NoiseFloorEstimator) -> None:
        """Learn the floor with ``estimator`` (the detector has no thresholds)."""
        self._estimator = estimator

    def saw_frames(self, now: float, learning: bool) -> None:
        """Frames arrived at host time ``now``; ``learning``: they will be held (the first
        frame held starts the wall-time rule)."""
        self._last_frame_at = now
        if self._started is None and learning:
            self._started = now

    def learn(
        self, batch: Any, final: bool, why: str | None = None
    ) -> tuple[NoiseFloor | None, list[Any]]:
        """Hold ``batch`` (a drivers.FrameBatch, or None) and, when learning ends, the floor
        learned and the frames held for the detector; (None, []) while it goes on or when it
        failed for good (``final``: no frame will come; ``why`` a :data:`LEARN_ENDS` code)."""
        assert self._estimator is not None, "nothing to learn"
        if batch is not None and len(batch):
            self._held.append(batch)
            self._estimator.feed(batch.time_s, batch.gyro_dph, batch.accel_g, batch.valid)
            self.learned_s += self._device_span(batch.time_s)
        if self.learned_s >= self.learn_s:
            why = "device_time"
        elif not final:
            why = self.cut(pending=False)
            if why is None:
                return None, []
        try:
            floor = self._estimator.result()
        except RecalInputError as exc:
            if not final:  # not enough yet (e.g. all frames invalid so far): keep learning
                if why != "device_time" and self._tried_s < 0:
                    self._events.emit("noise_floor", f"cannot learn the noise floor yet "
                                      f"({self.why(why)}): {exc}; frames stay held",
                                      {"reason": why}, level=logging.WARNING)  # fmt: skip
                self._tried_s = self.learned_s
                return None, []
            self._events.emit("noise_floor", f"cannot learn the noise floor: {exc}",
                              level=logging.WARNING)  # fmt: skip
            self.ended_by, self.message = why, f"cannot learn it: {exc}"
            self.took_s = self.wall_s()
            self._held = []
            return None, []
        self.took_s = self.wall_s()
        self.ended_by = why
        held = sum(len(b) for b in self._held)
        if why == "device_time":
            self.message = f"learned from the first {self.learned_s:.1f} s of device time"
        else:
            self.message = (
                f"learned from the {self.learned_s:.1f} s of device time held "
                f"(learn_s {self.learn_s:g}): {self.why(why)}"
            )
            floor = replace(floor, source=f"{floor.source}; {self.message}")
            self._events.emit("noise_floor", f"learning ended early: {self.why(why)}; "
                              f"the noise floor is learned from the {self.learned_s:.1f} s of "
                              f"device time held (learn_s {self.learn_s:g}) and its {held} "
                              "frames go to the detector",
                              {"reason": why, "learned_s": round(self.learned_s, 1),
                               "frames": held})  # fmt: skip
        held_batches, self._held = self._held, []
        return floor, held_batches

    def cut(self, pending: bool) -> str | None:
        """Why learning should end now from the frames held though ``learn_s`` of device time
        has not been reached: ``quiet`` (no frame for ``learn_quiet_s``) or ``wall_time``
        (``learn_s`` of host time since the first frame held); None: keep learning.
        ``pending``: frames arrived that the learner has not been given yet. An attempt that
        failed (too few frames) is not repeated before more frames are held."""
        if self.ended_by is not None or self._started is None:
            return None  # it failed for good (the input ended), or no frame yet
        if not (self._held or pending):
            return None
        if self._tried_s >= 0 and self.learned_s <= self._tried_s:
            return None  # tried with these frames already: wait for more
        now = self._clock()
        if self._last_frame_at is not None and now - self._last_frame_at >= self.learn_quiet_s:
            return "quiet"
        if now - self._started >= self.learn_s:
            return "wall_time"
        return None

    def why(self, why: str | None) -> str:
        """A :data:`LEARN_ENDS` code in plain words."""
        quiet = (
            "" if self._last_frame_at is None else f"{self._clock() - self._last_frame_at:.0f} s"
        )
        return {
            "device_time": f"{self.learn_s:g} s of device time learned",
            "quiet": f"the stream has sent no frame for {quiet} (learn_quiet_s "
            f"{self.learn_quiet_s:g})",
            "wall_time": f"{self.learn_s:g} s of wall time have passed with only "
            f"{self.learned_s:.1f} s of device time",
            "end_of_input": "the input has ended",
            "stopping": "the service is stopping",
        }.get(why or "", why or "")

    def wall_s(self) -> float | None:
        """Host time since the first frame was held (None before it)."""
        return None if self._started is None else self._clock() - self._started

    def _device_span(self, t: Any) -> float:
        """Device time frames at times ``t`` add to what is learned: from the last frame held
        (each batch's first step counts too), except across a step longer than
        :data:`LEARN_MAX_STEP_S` or backwards (a gap, a reset clock)."""
        if len(t) == 0:
            return 0.0
        first, last = float(t[0]), float(t[-1])
        previous, self._last_t = self._last_t, last
        if previous is not None and 0.0 <= first - previous <= LEARN_MAX_STEP_S:
            first = previous
        return max(0.0, last - first)

    def health(self, learning: bool, detector_started: bool, threshold_source: Any) -> dict:
        """The first noise floor's learning as ``/health`` shows it (``detector.learning``):
        ``state`` (``learning``: frames held; ``learned``: from the frames held, ``ended_by``
        a :data:`LEARN_ENDS` code; ``failed``: too few frames; ``not needed``: thresholds
        given, a floor stored for the device or an initial still period), device seconds
        ``learned_s`` of ``learn_s``, host seconds ``waited_s`` since the first frame held (or
        that learning took), and ``message`` in plain words."""
        if self.ended_by is not None:
            state = "failed" if not detector_started else "learned"
            waited, message = self.took_s, self.message
        elif learning:
            state = "learning"
            waited = self.wall_s()
            message = (
                f"holding frames to learn the noise floor: {self.learned_s:.1f} of "
                f"{self.learn_s:g} s of device time; it ends sooner if the stream sends "
                f"nothing for {self.learn_quiet_s:g} s, after {self.learn_s:g} s of wall "
                "time, or when the input ends"
            )
        else:
            state, waited = "not needed", None
            message = threshold_source
        return {
            "state": state,
            "ended_by": self.ended_by,
            "learned_s": round(self.learned_s, 1),
            "learn_s": self.learn_s,
            "learn_quiet_s": self.learn_quiet_s,
            "waited_s": None if waited is None else round(waited, 1),
            "message": message,
        }
