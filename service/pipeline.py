"""The live pipeline: frames -> static windows -> positions -> calibration jobs -> versions.

:class:`Ingest` runs the static detector on decoded frames (batched, since a detector call has a
fixed cost) and stores every closed window as a position. :class:`Scheduler` decides when the
stored positions are worth a recalibration, runs :func:`calibration_job` in a worker process
(so the numerics never stall the reader or the API), passes the result through the gate, stores
the version and publishes it when accepted.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from recal.detect.floor import NoiseFloor, NoiseFloorEstimator
from recal.detect.rest import REST_REASONS, RestReference, rest_filter
from recal.detect.slew_collect import SlewTracker
from recal.detect.static_config import DetectorConfig
from recal.detect.static_detector import StaticDetector
from recal.detect.windows import Window, windows_to_columns
from recal.errors import RecalInputError
from service.config import Settings
from service.db import StoreError, UnknownSessionError
from service.events import Events
from service.spool import Spool, SpoolEntry, SpoolWriteError, read_entry

log = logging.getLogger("recal.pipeline")

#: Frames buffered before a detector call (4 s at 1 kHz): a call costs ~0.4 ms whatever its size.
DETECTOR_BLOCK = 4096
#: ... but never hold frames longer than this (host time, s), so slow streams are not delayed.
DETECTOR_MAX_WAIT_S = 1.0
#: Windows kept in memory while both the database and the spool folder refuse them (a week of
#: windows at one a minute); windows on disk are not limited.
SPOOL_MAX = 10_000
#: Back-off between attempts to store spooled windows, s.
SPOOL_RETRY_MIN_S, SPOOL_RETRY_MAX_S = 0.5, 30.0


#: Windows between two refinements of the stored noise floor, and how many recent windows the
#: refined value is the median of.
REFINE_EVERY, REFINE_OVER = 10, 50
#: One refinement moves the floor by at most this factor (a few odd windows cannot run away).
REFINE_MAX_STEP = 2.0
#: While the first noise floor is learned, a step in device time between two frames longer than
#: this (s) is a gap or a clock reset: it is not counted as time learned.
LEARN_MAX_STEP_S = 1.0
#: The rest reference is rebuilt at the ship's latitude when it has moved by more than this, deg.
REST_LATITUDE_STEP_DEG = 0.05
#: Why learning the first noise floor ended, by code (``/health`` detector.learning.ended_by).
LEARN_ENDS = ("device_time", "quiet", "wall_time", "end_of_input", "stopping")


def detector_config(settings: Settings) -> DetectorConfig:
    """The detector as configured (thresholds, if any, not yet from the store)."""
    d = settings.detector
    return DetectorConfig(
        window_s=d.window_s,
        min_duration_s=d.min_duration_s,
        edge_trim_s=d.edge_trim_s,
        accel_threshold=d.accel_threshold,
        gyro_threshold=d.gyro_threshold,
        init_still_s=None if d.accel_threshold is not None else d.init_still_s,
        threshold_k=d.threshold_k,
        sample_rate_hz=settings.device.rate_hz,
        max_gap_frames=d.max_gap_frames,
    )


def rest_reference(
    settings: Settings, prior: Any = None, latitude_deg: float | None = None
) -> RestReference | None:
    """The rest check's reference (recal.detect.rest) for this unit: from ``prior`` (the accepted
    version, else ``prior_path``), else nominal for a format whose outputs are deg/h and g
    (a KVH); None when the outputs cannot be turned into physics (no rest check then).

    The prior gives the conversion (scale factors, biases); the plausible range is never
    narrower than the navigation class's: an accepted version's own 1-sigma would censor the
    very windows that show the unit has drifted from it. The latitude is ``latitude_deg`` (the
    ship's sensors), else the site's (:attr:`Settings.site_latitude_deg`); with neither, gravity
    anywhere between the equator's and the pole's is at rest until the ship's sensors give it.
    """
    from drivers.registry import get_input_format

    lat = settings.site_latitude_deg if latitude_deg is None else latitude_deg
    known, height = lat is not None, settings.site.height_m
    lat = 45.0 if lat is None else lat
    nominal = RestReference.nominal(lat, height)
    if prior is None:
        physical = tuple(get_input_format(settings.device.format).units) == ("deg/h", "g")
        ref = nominal if physical else None
    else:
        ref = RestReference.from_coefficients(prior, lat, height)
        ref = replace(
            ref,
            scale_sigma=max(ref.scale_sigma, nominal.scale_sigma),
            gyro_bias_sigma_dph=max(ref.gyro_bias_sigma_dph, nominal.gyro_bias_sigma_dph),
            accel_bias_sigma_g=max(ref.accel_bias_sigma_g, nominal.accel_bias_sigma_g),
            misalignment_sigma=max(ref.misalignment_sigma, nominal.misalignment_sigma),
        )
    return ref if ref is None or known else ref.at_unknown_latitude()


def window_frames(config: DetectorConfig, rate_hz: float) -> int:
    """The moving-window length W (frames) the detector uses at ``rate_hz``."""
    window_s = config.durations(rate_hz)[0]
    return 2 * max(1, round(window_s * rate_hz / 2)) + 1


class FloorKeeper:
    """The static detector's noise floor for one device, kept in the store.

    A unit restarted at sea may be moving: thresholds learned then would let motion through as
    "static". So the floor learned once (from the quietest stretches of the first minutes, or an
    initial still period) is stored with the device and reused at every start, and refined only
    from windows that passed the detector: the median of their moving-variance traces.
    """

    def __init__(self, store: Any, device: str, events: Events, window_samples: int) -> None:
        self._store = store
        self.device = device
        self._events = events
        self._w = window_samples
        self._recent: deque[tuple[float, float]] = deque(maxlen=REFINE_OVER)
        self._since = 0
        self._windows = 0
        self.floor: NoiseFloor | None = None

    def load(self) -> NoiseFloor | None:
        """The stored floor for this device and moving-window length, or None."""
        row = self._store.noise_floor(self.device)
        if row is None or int(row["window_samples"]) != self._w:
            return None
        self._windows = int(row["windows"])
        self.floor = NoiseFloor(
            accel=row["accel"],
            gyro=row["gyro"],
            window_samples=self._w,
            source=f"stored for this device on {row['created_at'][:19]} ({row['source']})",
        )
        return self.floor

    def save(self, floor: NoiseFloor, source: str) -> None:
        self.floor = floor
        try:
            self._store.save_noise_floor(self.device, {
                "accel": floor.accel, "gyro": floor.gyro, "window_samples": floor.window_samples,
                "source": source, "windows": self._windows})  # fmt: skip
        except StoreError as exc:  # kept in memory; the next refinement stores it again
            log.warning("event=noise_floor cannot store it: %s", exc)
            return
        self._events.emit("noise_floor", f"detector noise floor {source}: accel "
                          f"{floor.accel:.4g}, gyro {floor.gyro:.4g}",
                          {"device": self.device, "windows": self._windows})  # fmt: skip

    def refine(self, windows: list[Window]) -> None:
        """Take the moving-variance traces of windows that passed; store a new floor now and
        then."""
        for w in windows:
            # an accelerometer-only window's gyro trace is tremor, not the gyro's noise floor
            if np.isfinite(w.accel_mvar) and np.isfinite(w.gyro_mvar) and w.gyro_still:
                self._recent.append((w.accel_mvar, w.gyro_mvar))
                self._since += 1
                self._windows += 1
        if self.floor is None or self._since < REFINE_EVERY:
            return
        self._since = 0
        med = np.median(np.array(self._recent), axis=0)
        old = np.array([self.floor.accel, self.floor.gyro])
        new = np.clip(med, old / REFINE_MAX_STEP, old * REFINE_MAX_STEP)
        floor = NoiseFloor(float(new[0]), float(new[1]), self._w, self.floor.source)
        self.save(floor, f"refined from {self._windows} windows that passed")


@dataclass(eq=False)
class _Spooled:
    """A batch of windows (one detector call) waiting for the database, in order: on disk
    (``entry`` None: read back from ``path`` when stored) or, when the spool could not take
    it, held in memory (``entry``)."""

    key: str
    windows: int
    path: Path | None = None
    entry: SpoolEntry | None = None
    replayed: bool = False  # spooled by an earlier run: it may already be stored

    def load(self) -> SpoolEntry:
        return self.entry if self.entry is not None else read_entry(self.path)


class Ingest:
    """Feeds decoded frames to the static detector and stores each closed window.

    With a ``rest`` reference (:func:`rest_reference`) the static detector's windows pass the
    rest check in physics too (:func:`recal.detect.rest.rest_filter`: a steady turn has a quiet
    moving variance but not Earth's rate); those it refuses are counted by reason in
    ``/health`` (``detector.rejected``). With a ``hull`` configuration the hull detector
    (:class:`recal.detect.hull.HullDetector`, which needs ``rest``) finds quasi-static windows
    instead: no noise floor is learned and no slews are kept (a rocking hull's window ends are
    off its mean attitude by the wave's angle).

    Without thresholds or a stored floor, frames are held while the first noise floor is
    learned from the first ``learn_s`` of device time; learning ends sooner, from what is held,
    when the stream sends nothing for ``learn_quiet_s``, after ``learn_s`` of host time (a slow
    or short stream) or at the end of input (:meth:`end_of_input`, :meth:`flush`), so held
    frames always become windows. ``/health`` shows it (:meth:`learning_health`).

    The motion between consecutive windows is kept too (:class:`recal.detect.slews.SlewTracker`,
    bounded memory) and stored with them, so the gyro can be calibrated from the slews.

    With a ``spool`` (:class:`service.spool.Spool`) each detector call's windows are written to
    it durably *before* they count as detected (``detected``) and go to the database; a batch's
    file is deleted once the database committed it. Batches a previous run left in the spool
    are queued first, in order (:meth:`replay`). During a database outage batches wait on disk,
    retried with exponential back-off from :meth:`poll`. When the spool folder refuses a write
    (disk full, permissions) the error is kept in ``spool_error`` and the batch goes straight to
    the database; only when both refuse is it held in memory, bounded (:data:`SPOOL_MAX`
    windows, overflow counted in ``windows_dropped``).
    """

    def __init__(
        self,
        store: Any,
        session_id: int,
        config: DetectorConfig,
        on_positions: Callable[[list[int]], None] | None = None,
        events: Events | None = None,
        keeper: FloorKeeper | None = None,
        learn_s: float = 120.0,
        spool: Spool | None = None,
        rest: RestReference | None = None,
        hull: Any = None,
        learn_quiet_s: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
        nav: Any = None,
        rest_at: Callable[[float], RestReference | None] | None = None,
    ) -> None:
        self._clock = clock  # host time, s (a test's own clock drives the wall-time rules)
        # the ship's sensors (service.nav.ShipSensors): each window's ship state, the underway
        # rule; rest_at(latitude) rebuilds the rest reference when they give the latitude
        self._nav = nav
        self._rest_at = rest_at
        self._nav_latitude: float | None = None  # the newest latitude given, not yet applied
        self._rest_latitude: float | None = None  # the latitude the rest reference is built at
        self._store = store
        self._session = session_id
        self._on_positions = on_positions
        self._events = events or Events(store)
        self._keeper = keeper
        self._config = config
        self._learn_s = learn_s
        self._estimator: NoiseFloorEstimator | None = None
        self._learning: list[Any] = []  # frames held while the first noise floor is learned
        self._learned_s = 0.0  # device time of the frames held (steps beyond a gap not counted)
        self._learn_quiet_s = learn_quiet_s
        self._learn_last_t: float | None = None  # device time of the last frame held
        self._learn_started: float | None = None  # host time the first frame was held
        self._learn_took_s: float | None = None  # host time learning took, once it has ended
        self._learn_tried_s = -1.0  # learned_s at the last early attempt that failed
        self.learn_ended_by: str | None = None  # a LEARN_ENDS code once learned from frames
        self.learn_message: str | None = None  # why it ended (or failed), in plain words
        self._last_frame_at: float | None = None  # host time of the last frame fed
        self.input_ended = False  # end_of_input() was called: no frame will come
        self._detector: StaticDetector | None = None
        self._rest = rest
        self._rest_seen = self._rest_refused = 0  # static windows judged / refused by it
        self._refused_norms: deque[tuple[float, float]] = deque(maxlen=50)  # deg/h, g
        self._rest_warned: list[str] = []
        self._hull: Any = None
        if hull is not None:  # quasi-static windows of a moving hull: nothing to learn
            from recal.detect.hull import HullDetector

            if rest is None:
                raise RecalInputError(
                    '[detector] motion = "hull" judges windows by Earth\'s rate and gravity: the '
                    "unit must output deg/h and g (a KVH format), or set prior_path to convert "
                    "its outputs"
                )
            self._hull = HullDetector(rest, hull, rate_hz=config.sample_rate_hz or 1000.0)
            self._keeper = None
        else:
            explicit = config.accel_threshold is not None and config.gyro_threshold is not None
            stored = keeper.load() if keeper is not None and not explicit else None
            if stored is not None:  # the stored floor wins over learning again (maybe in motion)
                self._config = replace(config, noise_floor=stored, init_still_s=None)
            if self._config.has_thresholds:
                self._start_detector()
            else:
                self._estimator = NoiseFloorEstimator(config.window_s, config.sample_rate_hz)
        self._pending: list[Any] = []
        self._count = 0
        self._first_pending = 0.0
        self._lock = threading.Lock()
        self._spool: deque[_Spooled] = deque()
        self._disk = spool
        self.spool_error: str | None = None  # why the spool folder refused the last batch
        self.windows_in_memory = 0  # windows neither on disk nor stored (both refused them)
        self.detected = 0  # windows made durable (spool or database): they survive a kill
        self.replayed = 0  # windows of earlier runs stored from the spool by this one
        self._tracker: SlewTracker | None = None
        self._fed = 0  # frames given to the detector
        self._last_key: str | None = None  # this session's last batch (row -1 of the next)
        self._stored_last: tuple[str, int] | None = None  # the last batch stored: key, last id
        self.slews = 0
        self.slews_dropped: dict[str, int] = {}
        self._retry_at = 0.0
        self._backoff_s = SPOOL_RETRY_MIN_S
        self.store_error: str | None = None
        self.frames = 0
        self.windows = 0
        self.windows_dropped = 0
        self.last_detector_run = self._clock()

    def feed(self, batch: Any) -> list[int]:
        """Take a drivers.FrameBatch; returns the ids of positions stored by this call."""
        with self._lock:
            if len(batch) == 0:
                return []
            if self._nav is not None:  # the frames' device and host times: windows to host time
                self._nav.observe(batch)
            now = self._clock()
            self._last_frame_at = now
            if self._learn_started is None and self.learning:
                self._learn_started = now
            if not self._pending:
                self._first_pending = now
            self._pending.append(batch)
            self._count += len(batch)
            self.frames += len(batch)
            if self._count < DETECTOR_BLOCK and not self._stale():
                return []
            return self._run(flush=False)

    def poll(self) -> list[int]:
        """Run the detector on frames held longer than DETECTOR_MAX_WAIT_S, and retry spooled
        windows when their back-off has passed (call periodically)."""
        with self._lock:
            if self._pending and self._stale():
                return self._run(flush=False)
            if self._learn_cut() is not None:  # the stream went quiet, or is too slow
                return self._run(flush=False)
            if self._spool and self._clock() >= self._retry_at:
                return self._drain()
            return []

    def _stale(self) -> bool:
        return self._clock() - self._first_pending >= DETECTOR_MAX_WAIT_S

    def flush(self, why: str = "end_of_input") -> list[int]:
        """End of stream: learn the noise floor from the frames held, if it is still being
        learned, then close the open window, if any. ``why`` (a :data:`LEARN_ENDS` code) is
        what ``/health`` and the events give as the end of learning."""
        with self._lock:
            return self._run(flush=True, why=why)

    def end_of_input(self) -> list[int]:
        """No frame will come (a replayed capture read to its end): say so in an ``input``
        event, then :meth:`flush`. Called once per stream; later calls do nothing, so the
        reader's signal and a caller that also knows the stream has ended cannot double it."""
        with self._lock:
            if self.input_ended:
                return []
            self.input_ended = True
            self._events.emit("input", "end of input: the stream has ended; the frames held are "
                              "processed and the open window is closed",
                              {"frames": self.frames})  # fmt: skip
            return self._run(flush=True, why="end_of_input")

    @property
    def report(self) -> Any:
        if self._hull is not None:
            return self._hull.report
        return None if self._detector is None else self._detector.report

    @property
    def learning(self) -> bool:
        """Frames are being held to learn the first noise floor (no windows yet)."""
        return self._detector is None and self._hull is None

    def _start_detector(self) -> None:
        self._detector = StaticDetector(self._config)
        cfg = self._config
        self._learned_from_still = (
            self._keeper is not None and cfg.init_still_s is not None and cfg.noise_floor is None
        )

    def _learn(self, batch: Any, final: bool, why: str | None = None) -> list[Any]:
        """Hold frames and feed the estimator until ``learn_s`` of device time; then start the
        detector with the floor and give it the held frames.

        Learning also ends, from what is held, when no more frames will come or may come soon:
        the stream has ended (``final``, ``why`` naming the cause), has sent nothing for
        ``learn_quiet_s`` (a stream left open and quiet) or has taken ``learn_s`` of wall time
        without ``learn_s`` of device time (a slow or short stream): held forever, those frames
        would never become windows. Such an early end is said in a ``noise_floor`` event."""
        if batch is not None and len(batch):
            self._learning.append(batch)
            self._estimator.feed(batch.time_s, batch.gyro_dph, batch.accel_g, batch.valid)
            self._learned_s += self._device_span(batch.time_s)
        if self._learned_s >= self._learn_s:
            why = "device_time"
        elif not final:
            why = self._learn_cut()
            if why is None:
                return []
        try:
            floor = self._estimator.result()
        except RecalInputError as exc:
            if not final:  # not enough yet (e.g. all frames invalid so far): keep learning
                if why != "device_time" and self._learn_tried_s < 0:
                    self._events.emit("noise_floor", f"cannot learn the noise floor yet "
                                      f"({self._learn_why(why)}): {exc}; frames stay held",
                                      {"reason": why}, level=logging.WARNING)  # fmt: skip
                self._learn_tried_s = self._learned_s
                return []
            self._events.emit("noise_floor", f"cannot learn the noise floor: {exc}",
                              level=logging.WARNING)  # fmt: skip
            self.learn_ended_by, self.learn_message = why, f"cannot learn it: {exc}"
            self._learn_took_s = self._learning_wall_s()
            self._learning = []
            return []
        self._learn_took_s = self._learning_wall_s()
        self.learn_ended_by = why
        held = sum(len(b) for b in self._learning)
        if why == "device_time":
            self.learn_message = f"learned from the first {self._learned_s:.1f} s of device time"
        else:
            self.learn_message = (
                f"learned from the {self._learned_s:.1f} s of device time held "
                f"(learn_s {self._learn_s:g}): {self._learn_why(why)}"
            )
            floor = replace(floor, source=f"{floor.source}; {self.learn_message}")
            self._events.emit("noise_floor", f"learning ended early: {self._learn_why(why)}; "
                              f"the noise floor is learned from the {self._learned_s:.1f} s of "
                              f"device time held (learn_s {self._learn_s:g}) and its {held} "
                              "frames go to the detector",
                              {"reason": why, "learned_s": round(self._learned_s, 1),
                               "frames": held})  # fmt: skip
        self._config = replace(self._config, noise_floor=floor)
        self._start_detector()
        if self._keeper is not None:
            self._keeper.save(floor, floor.source)
        held_batches, self._learning = self._learning, []
        return held_batches

    def _learn_cut(self) -> str | None:
        """Why learning should end now from the frames held though ``learn_s`` of device time
        has not been reached: ``quiet`` (no frame for ``learn_quiet_s``) or ``wall_time``
        (``learn_s`` of host time since the first frame held); None: keep learning. An attempt
        that failed (too few frames) is not repeated before more frames are held."""
        if not self.learning or self.learn_ended_by is not None or self._learn_started is None:
            return None  # not learning, or it failed for good (the input ended)
        if not (self._learning or self._pending):
            return None
        if self._learn_tried_s >= 0 and self._learned_s <= self._learn_tried_s:
            return None  # tried with these frames already: wait for more
        now = self._clock()
        if self._last_frame_at is not None and now - self._last_frame_at >= self._learn_quiet_s:
            return "quiet"
        if now - self._learn_started >= self._learn_s:
            return "wall_time"
        return None

    def _learn_why(self, why: str | None) -> str:
        """A :data:`LEARN_ENDS` code in plain words."""
        quiet = (
            "" if self._last_frame_at is None else f"{self._clock() - self._last_frame_at:.0f} s"
        )
        return {
            "device_time": f"{self._learn_s:g} s of device time learned",
            "quiet": f"the stream has sent no frame for {quiet} (learn_quiet_s "
            f"{self._learn_quiet_s:g})",
            "wall_time": f"{self._learn_s:g} s of wall time have passed with only "
            f"{self._learned_s:.1f} s of device time",
            "end_of_input": "the input has ended",
            "stopping": "the service is stopping",
        }.get(why or "", why or "")

    def _learning_wall_s(self) -> float | None:
        """Host time since the first frame was held (None before it)."""
        return None if self._learn_started is None else self._clock() - self._learn_started

    def _device_span(self, t: Any) -> float:
        """Device time frames at times ``t`` add to what is learned: from the last frame held
        (each batch's first step counts too), except across a step longer than
        :data:`LEARN_MAX_STEP_S` or backwards (a gap, a reset clock)."""
        if len(t) == 0:
            return 0.0
        first, last = float(t[0]), float(t[-1])
        previous, self._learn_last_t = self._learn_last_t, last
        if previous is not None and 0.0 <= first - previous <= LEARN_MAX_STEP_S:
            first = previous
        return max(0.0, last - first)

    def frames_waiting_s(self) -> float | None:
        """How long the oldest frame not yet given to the detector has waited (host s)."""
        with self._lock:
            return self._clock() - self._first_pending if self._pending else None

    def detector_health(self) -> dict[str, Any]:
        """The detector as ``/health`` shows it: ``motion``, the rest check's reference
        (``rest_check``, None without one), windows kept and ``rejected`` by reason (the rest
        check's reasons included); the hull detector's ``blocks`` by state too."""
        rest = None if self._rest is None else self._rest.source
        if self._hull is not None:
            rep = self._hull.report
            return {
                "motion": "hull",
                "rest_check": rest,
                "windows_kept": rep.kept,
                # every reason, counted or not (an operator sees what is looked for)
                "rejected": {r: 0 for r in ("too_short", *REST_REASONS, *self._nav_reasons)}
                | dict(rep.rejected),
                "blocks": {
                    "total": rep.blocks,
                    "turning": rep.blocks_turning,
                    "accelerating": rep.blocks_accelerating,
                    "fault": rep.blocks_fault,
                },
                "block_s": self._hull.cfg.block_s,
            }
        if self._detector is None:
            return {"motion": "still", "rest_check": rest, "learning_noise_floor": True,
                    "learned_s": round(self._learned_s, 1), "learn_s": self._learn_s,
                    "learning": self.learning_health()}  # fmt: skip
        rep = self._detector.report
        return {
            "motion": "still",
            "rest_check": rest,
            "accel_threshold": rep.accel_threshold,
            "gyro_threshold": rep.gyro_threshold,
            "threshold_source": getattr(rep, "threshold_source", None),
            "windows_kept": rep.windows_kept,
            # the rest check's reasons included, and the underway rule's with [nav]
            "rejected": dict.fromkeys(self._nav_reasons, 0) | dict(rep.rejected),
            "learning": self.learning_health(),
        }

    @property
    def _nav_reasons(self) -> tuple[str, ...]:
        """The underway rule's reason with ``[nav]``, else none."""
        return () if self._nav is None else ("underway",)

    def learning_health(self) -> dict[str, Any]:
        """The first noise floor's learning as ``/health`` shows it (``detector.learning``):
        ``state`` (``learning``: frames held; ``learned``: from the frames held, ``ended_by``
        a :data:`LEARN_ENDS` code; ``failed``: too few frames; ``not needed``: thresholds
        given, a floor stored for the device or an initial still period), device seconds
        ``learned_s`` of ``learn_s``, host seconds ``waited_s`` since the first frame held (or
        that learning took), and ``message`` in plain words."""
        if self.learn_ended_by is not None:
            state = "failed" if self._detector is None else "learned"
            waited, message = self._learn_took_s, self.learn_message
        elif self.learning:
            state = "learning"
            waited = self._learning_wall_s()
            message = (
                f"holding frames to learn the noise floor: {self._learned_s:.1f} of "
                f"{self._learn_s:g} s of device time; it ends sooner if the stream sends "
                f"nothing for {self._learn_quiet_s:g} s, after {self._learn_s:g} s of wall "
                "time, or when the input ends"
            )
        else:
            state, waited = "not needed", None
            message = getattr(self.report, "threshold_source", None)
        return {
            "state": state,
            "ended_by": self.learn_ended_by,
            "learned_s": round(self._learned_s, 1),
            "learn_s": self._learn_s,
            "learn_quiet_s": self._learn_quiet_s,
            "waited_s": None if waited is None else round(waited, 1),
            "message": message,
        }

    @property
    def spooled(self) -> int:
        """Windows waiting for the database (on disk or in memory)."""
        return sum(item.windows for item in self._spool)

    def spool_health(self) -> dict[str, Any]:
        """The spool as ``/health`` shows it."""
        on_disk = [item for item in self._spool if item.path is not None]
        return {
            "dir": None if self._disk is None else str(self._disk.directory),
            "batches_on_disk": len(on_disk),
            "windows_on_disk": sum(item.windows for item in on_disk),
            "windows_in_memory": self.windows_in_memory,
            "windows_replayed": self.replayed,
            "error": self.spool_error,
        }

    def replay(self) -> list[int]:
        """Queue the batches earlier runs left in the spool (oldest first, ahead of any new
        window) and store what the database takes now; returns the ids stored."""
        if self._disk is None:
            return []
        with self._lock:
            try:
                self._disk.probe()
            except SpoolWriteError as exc:
                self._spool_failed(exc)
            entries = self._disk.load()
            for bad in self._disk.unreadable:
                self._events.emit("spool", f"unreadable spool file kept as .bad: {bad}",
                                  level=logging.ERROR)  # fmt: skip
            if entries:
                n = sum(e.size for e in entries)
                self._events.emit("spool", f"replaying {n} window(s) in {len(entries)} batch(es) "
                                  f"from {self._disk.directory}", {"windows": n})  # fmt: skip
            old = [_Spooled(e.key, e.size, e.path, replayed=True) for e in entries]
            self._spool.extendleft(reversed(old))
            self._retry_at = 0.0
            return self._drain() if self._spool else []

    def nav_latitude(self, latitude_deg: float) -> None:
        """The ship's sensors give this latitude (any thread; returns at once): the rest
        reference is rebuilt at it before the detector next runs, when it has moved by more than
        :data:`REST_LATITUDE_STEP_DEG` (gravity moves by 0.1 mg a degree, Earth's vertical rate
        by 0.26 deg/h)."""
        self._nav_latitude = float(latitude_deg)

    def _apply_nav_latitude(self) -> None:
        lat = self._nav_latitude
        if lat is None or self._rest_at is None:
            return
        if (
            self._rest_latitude is not None
            and abs(lat - self._rest_latitude) <= REST_LATITUDE_STEP_DEG
        ):
            return
        ref = self._rest_at(lat)
        if ref is None:
            return
        first = self._rest_latitude is None
        self._rest_latitude = lat
        self._rest = ref
        if self._hull is not None:
            self._hull.ref = ref
        if first:
            self._events.emit("nav", f"the ship's sensors give latitude {lat:.4f} deg: the rest "
                              "check uses it from now on", {"latitude_deg": round(lat, 6)})  # fmt: skip

    def _ship_state(self, windows: list[Window]) -> tuple[list[Window], list[Any] | None]:
        """The windows the underway rule keeps, with the ship over each (None without
        ``[nav]``); those it rejects are counted in the detector's report."""
        if self._nav is None or not windows:
            return windows, None
        from recal.detect.underway import count_rejections, underway_rule

        ships = self._nav.over(windows)
        rule = underway_rule(ships, self._nav.max_sog_kn)
        if not rule.kept.all():
            count_rejections(self.report, windows, list(rule.reasons))
            keep = np.flatnonzero(rule.kept)
            windows, ships = [windows[i] for i in keep], [ships[i] for i in keep]
        return windows, ships

    def _run(self, flush: bool, why: str = "end_of_input") -> list[int]:
        self._apply_nav_latitude()
        if self._hull is not None:
            return self._run_hull(flush)
        windows = []
        self.last_detector_run = self._clock()
        batches, self._pending, self._count = self._pending, [], 0
        if self._detector is None:
            from drivers import FrameBatch

            batch = FrameBatch.concat(batches) if batches else None
            batches = self._learn(batch, final=flush, why=why)
        if batches and self._detector is not None:
            from drivers import FrameBatch

            b = FrameBatch.concat(batches)
            windows += self._detector.feed(
                b.time_s, b.gyro_dph, b.accel_g, b.temperature_c, b.valid, b.lost_before
            )
            self._track(b)
        if flush and self._detector is not None:
            windows += self._detector.flush()
        if self._detector is not None and self._learned_from_still:
            rep = self._detector.report
            if rep.accel_threshold is not None:  # the initial still period is over: store it
                self._learned_from_still = False
                k = self._config.threshold_k
                floor = NoiseFloor(rep.accel_threshold / k, rep.gyro_threshold / k,
                                   rep.window_samples, rep.threshold_source)  # fmt: skip
                self._keeper.save(floor, rep.threshold_source or "initial still period")
        if windows and self._rest is not None:
            windows = self._rest_check(windows)
        if windows and self._keeper is not None:
            self._keeper.refine(windows)
        windows, ships = self._ship_state(windows)
        return self._queue(windows, ships)

    def _run_hull(self, flush: bool) -> list[int]:
        """The hull detector's turn: frames in, the windows it has decided out (no slews)."""
        self.last_detector_run = self._clock()
        batches, self._pending, self._count = self._pending, [], 0
        found = []
        if batches:
            from drivers import FrameBatch

            b = FrameBatch.concat(batches)
            # the ship's heading per frame ([nav] HDT/THS): the hull's creep measured, not
            # guessed (recal.detect.creep)
            psi = None if self._nav is None else self._nav.heading_of(b.time_s)
            found += self._hull.feed(b.time_s, b.gyro_dph, b.accel_g, b.temperature_c, b.valid,
                                     heading_deg=psi)  # fmt: skip
        if flush:
            found += self._hull.flush()
        windows, ships = self._ship_state([hw.window for hw in found])
        return self._queue(windows, ships)

    def _rest_check(self, windows: list[Window]) -> list[Window]:
        """The static detector's windows that are at rest in physics; the others counted by
        reason. When every window so far failed it, the windows' norms may say a ``[device]``
        setting is wrong (as the scheduler would say of stored ones): a ``device`` event."""
        kept, reasons = rest_filter(windows, self._rest)
        self._detector.report.add_rest_rejections(windows, reasons)
        refused = [w for w, r in zip(windows, reasons, strict=True) if r]
        self._rest_seen += len(windows)
        self._rest_refused += len(refused)
        if refused:
            ref = self._rest
            rate = np.linalg.norm(ref.rate_dph(np.array([w.gyro for w in refused])), axis=1)
            force = np.linalg.norm(ref.force_g(np.array([w.accel for w in refused])), axis=1)
            self._refused_norms.extend(zip(rate.tolist(), force.tolist(), strict=True))
            if self._rest_refused == self._rest_seen >= 4:
                self._warn_units()
        return kept

    def _warn_units(self) -> None:
        """A ``device`` event when the refused windows agree on norms far from Earth's rate or
        gravity (a wrong rate or unit setting scales them all alike; motion scatters them)."""
        from recal.detect.plausibility import MAX_FACTOR, UnitCheck
        from recal.model.reference import OMEGA_IE_DEG_H

        ref = self._rest
        rate, force = np.array(self._refused_norms).T
        for norms in (rate, force):
            if not (np.all(norms > 0) and norms.max() <= MAX_FACTOR * norms.min()):
                return
        check = UnitCheck(float(np.median(rate)) / OMEGA_IE_DEG_H,
                          float(np.median(force)) / ref.gravity_g)  # fmt: skip
        rate_hz = self._config.sample_rate_hz or 0.0
        problems = check.problems("[device] rate_hz", rate_hz, "[device] gyro_output / gyro_units")
        if problems and problems != self._rest_warned:
            self._events.emit("device", "every window so far fails the rest check: "
                              + "; ".join(problems), level=logging.WARNING)  # fmt: skip
        self._rest_warned = problems

    def _queue(self, windows: list[Window], ships: list[Any] | None = None) -> list[int]:
        """Spool a detector call's windows (with the slews between them and, with ``[nav]``, the
        ship over each: its columns, and the transport rate in the gyro sigma) and store what
        the database takes now."""
        if windows:
            slews = []
            if self._tracker is not None:
                for k, w in enumerate(windows):
                    r = self._tracker.window(w)
                    if r is not None:
                        slews.append((k - 1, k, r))
            period = None if self._tracker is None else self._tracker.period_s
            columns = windows_to_columns(windows)
            if ships is not None:
                columns = self._ship_columns(columns, ships)
            entry = SpoolEntry(self._session, columns, slews, self._last_key, period)
            self._last_key = entry.key
            self._hold(entry)
            self._retry_at = 0.0  # new data: try the database now
        return self._drain() if self._spool and self._clock() >= self._retry_at else []

    def _ship_columns(self, columns: dict[str, Any], ships: list[Any]) -> dict[str, Any]:
        """The ship's columns, and the transport rate of each window's net displacement added to
        its gyro sigma in the gyro's output units (the rest reference's scale; none without
        one: the outputs' units are not known)."""
        from recal.detect.underway import ship_columns, underway_rule

        scale = 0.0 if self._rest is None else self._rest.gyro_scale
        return ship_columns(columns, ships, underway_rule(ships, self._nav.max_sog_kn, scale))

    def _spool_failed(self, exc: SpoolWriteError) -> None:
        if self.spool_error != str(exc):
            self._events.emit("spool", f"{exc}: storing windows straight to the database, in "
                              "memory while it is down", {"dir": str(self._disk.directory)},
                              level=logging.ERROR)  # fmt: skip
        self.spool_error = str(exc)

    def _hold(self, entry: SpoolEntry) -> None:
        """Queue a new batch: on disk first (durable before it counts as detected); when the
        spool refuses it, in memory, where the drain that follows stores it if it can."""
        if self._disk is not None:
            try:
                self._disk.append(entry)
            except SpoolWriteError as exc:
                self._spool_failed(exc)
            else:
                if self.spool_error is not None:
                    self._events.emit("spool", f"spool {self._disk.directory} writable again")
                self.spool_error = None
                self._spool.append(_Spooled(entry.key, entry.size, entry.path))
                self.detected += entry.size
                return
        self._spool.append(_Spooled(entry.key, entry.size, entry=entry))
        self.windows_in_memory += entry.size
        while self.windows_in_memory > SPOOL_MAX:  # drop the oldest batch held in memory
            old = next(item for item in self._spool if item.entry is not None)
            self._spool.remove(old)
            self.windows_in_memory -= old.windows
            self.windows_dropped += old.windows

    def _track(self, b: Any) -> None:
        """Give the frames the detector just took to the slew tracker (created once the frame
        rate is known; frames before it cannot be part of a slew)."""
        if self._tracker is None:
            rate = self._detector.report.sample_rate_hz or self._config.sample_rate_hz
            if rate:
                self._tracker = SlewTracker(1.0 / rate, start_index=self._fed)
        if self._tracker is not None:
            self._tracker.feed(b.gyro_dph, b.valid, b.lost_before)
        self._fed += len(b)

    def _drain(self) -> list[int]:
        """Store queued batches in order until none is left or the database fails."""
        stored: list[int] = []
        while self._spool:
            item = self._spool[0]
            try:
                entry = item.load()
            except (OSError, ValueError, KeyError) as exc:  # the file went bad under us
                self._events.emit("spool", f"cannot read spooled batch {item.path}: {exc}",
                                  level=logging.ERROR)  # fmt: skip
                self._spool.popleft()
                self.windows_dropped += item.windows
                continue
            try:
                ids = self._store_entry(entry, item.replayed)
            except (UnknownSessionError, RecalInputError) as exc:  # retrying cannot help
                self._set_aside(item, str(exc))
                continue
            except StoreError as exc:
                if self.store_error is None:
                    where = "spooling them" if self._disk is None else "they wait in the spool"
                    self._events.emit("database", f"cannot store windows, {where}: {exc}",
                                      level=logging.WARNING)  # fmt: skip
                self.store_error = str(exc)
                self._retry_at = self._clock() + self._backoff_s
                self._backoff_s = min(2 * self._backoff_s, SPOOL_RETRY_MAX_S)
                break
            self._spool.popleft()
            if item.entry is not None:  # durable only now
                self.windows_in_memory -= item.windows
                self.detected += item.windows
            if self._disk is not None and entry.path is not None:
                try:
                    self._disk.remove(entry)
                except OSError as exc:  # committed with its key: a replay of it adds nothing
                    log.warning("event=spool cannot delete %s: %s", entry.path, exc)
            if ids is None:  # an earlier run stored it and was killed before the delete
                continue
            stored += ids
            if item.replayed:
                self.replayed += len(ids)
        if stored:
            if self.store_error is not None:
                self._events.emit("database", "database back: spooled windows stored",
                                  {"windows": len(stored)})  # fmt: skip
            self.store_error = None
            self._backoff_s = SPOOL_RETRY_MIN_S
            self.windows += len(stored)
            log.info("event=window stored %d window(s), ids %s", len(stored), stored)
            if self._on_positions:
                self._on_positions(stored)
        return stored

    def _set_aside(self, item: _Spooled, why: str) -> None:
        """A batch the database can never take (e.g. a spool from another database): out of
        the queue, its file kept as ``*.bad`` for a person to look at."""
        self._spool.popleft()
        self.windows_dropped += item.windows
        if item.entry is not None:
            self.windows_in_memory -= item.windows
        if item.path is not None:
            with contextlib.suppress(OSError):
                item.path.rename(item.path.with_suffix(".bad"))
        self._events.emit("spool", f"batch {item.key} ({item.windows} window(s)) cannot be "
                          f"stored, set aside: {why}", level=logging.ERROR)  # fmt: skip

    def _store_entry(self, entry: SpoolEntry, replayed: bool) -> list[int] | None:
        """Store one batch with its slews (StoreError if the database refuses); None when a
        replayed batch is stored already."""
        if replayed and self._store.keyed_positions(entry.key):
            return None
        previous = None  # the last window of the batch before, if it was stored
        if entry.previous_key is not None:
            if self._stored_last is not None and self._stored_last[0] == entry.previous_key:
                previous = self._stored_last[1]
            elif replayed:
                before = self._store.keyed_positions(entry.previous_key)
                previous = before[-1] if before else None
        ids = self._store.add_positions(entry.session_id, entry.columns, entry.slews,
                                        entry.period_s, previous, spool_key=entry.key)  # fmt: skip
        if ids:
            self._stored_last = (entry.key, ids[-1])
        for a, _, r in entry.slews:
            if a < 0 and previous is None:
                continue  # its first window was never stored: not stored
            if r.dropped is None:
                self.slews += 1
            else:
                self.slews_dropped[r.dropped] = self.slews_dropped.get(r.dropped, 0) + 1
        return ids


#: Queued to the ingest thread by :meth:`IngestThread.end`: the input has ended.
_END = object()


class IngestThread:
    """Hands the reader's batches to :class:`Ingest` in a thread of its own ("ingest").

    The reader thread must never wait: the detector, the spool's fsync and the database take
    milliseconds to seconds, and a reader that stalls lets the serial buffer overflow and makes
    a format without timestamps date its frames from their late arrival. :meth:`put` only
    queues; the thread feeds Ingest in order. :meth:`stop` drains the queue first. :meth:`end`
    (the reader's end of input) is queued too, so Ingest hears of it after the last frame.
    """

    def __init__(self, ingest: Ingest) -> None:
        import queue

        self._ingest = ingest
        self._queue: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._oldest: float | None = None  # host time of the oldest batch not yet fed
        self._lock = threading.Lock()
        self._idle = threading.Condition(self._lock)
        self._queued = 0  # batches put and not yet fed
        self._thread = threading.Thread(target=self._loop, name="ingest", daemon=True)
        self._thread.start()

    def put(self, batch: Any) -> None:
        """Queue a drivers.FrameBatch (the reader's callback; returns at once)."""
        with self._lock:
            if self._oldest is None:
                self._oldest = time.monotonic()
            self._queued += 1
        self._queue.put(batch)

    def end(self) -> None:
        """The input has ended: :meth:`Ingest.end_of_input` once every batch queued before
        has been fed (returns at once, as :meth:`put`)."""
        self.put(_END)

    def _loop(self) -> None:
        while True:
            batch = self._queue.get()
            if batch is None:
                return
            try:
                if batch is _END:
                    self._ingest.end_of_input()
                else:
                    self._ingest.feed(batch)
            except Exception:  # noqa: BLE001 - one bad batch must not end the ingest
                log.exception("ingest: a batch failed")
            with self._lock:
                self._queued -= 1
                self._oldest = None if self._queued == 0 else time.monotonic()
                if self._queued == 0:
                    self._idle.notify_all()

    def wait_idle(self, timeout_s: float | None = None) -> bool:
        """Block until every batch put so far has been fed; False on timeout."""
        with self._idle:
            return self._idle.wait_for(lambda: self._queued == 0, timeout_s)

    def waiting_s(self) -> float | None:
        """How long the oldest queued batch has waited (host s), None when none waits."""
        with self._lock:
            return None if self._oldest is None else time.monotonic() - self._oldest

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def stop(self, timeout_s: float = 60.0) -> None:
        """Feed what is queued, then end the thread."""
        self._queue.put(None)
        self._thread.join(timeout_s)
