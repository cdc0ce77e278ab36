"""The live pipeline: frames -> static windows -> positions -> calibration jobs -> versions.

:class:`Ingest` runs the static detector on decoded frames (batched, since a detector call has a
fixed cost) and stores every closed window as a position. :class:`Scheduler` decides when the
stored positions are worth a recalibration, runs :func:`calibration_job` in a worker process
(so the numerics never stall the reader or the API), passes the result through the gate, stores
the version and publishes it when accepted.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from typing import Any

import numpy as np

from recal.calibrate import CalibrationOptions, calibrate, check_design
from recal.coefficients import CoefficientSet
from recal.errors import RecalInputError
from recal.positions import Positions
from recal.slews import ReducedSlew, SlewTracker, slews_from_reduced
from recal.static import (
    DetectorConfig,
    NoiseFloor,
    NoiseFloorEstimator,
    StaticDetector,
    Window,
    windows_to_columns,
)
from service.config import Settings
from service.db import StoreError
from service.events import Events
from service.jobs import JobEnd, JobRunner, report_progress

log = logging.getLogger("recal.pipeline")

#: Frames buffered before a detector call (4 s at 1 kHz): a call costs ~0.4 ms whatever its size.
DETECTOR_BLOCK = 4096
#: ... but never hold frames longer than this (host time, s), so slow streams are not delayed.
DETECTOR_MAX_WAIT_S = 1.0
#: Windows kept in memory while the database is unavailable (a week of windows at one a minute).
SPOOL_MAX = 10_000
#: Back-off between attempts to store spooled windows, s.
SPOOL_RETRY_MIN_S, SPOOL_RETRY_MAX_S = 0.5, 30.0


#: Windows between two refinements of the stored noise floor, and how many recent windows the
#: refined value is the median of.
REFINE_EVERY, REFINE_OVER = 10, 50
#: One refinement moves the floor by at most this factor (a few odd windows cannot run away).
REFINE_MAX_STEP = 2.0


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


@dataclass
class _Spooled:
    """Windows closed by one detector call, with the slews between them, waiting to be stored.

    slews: (first row, second row, recal.slews.ReducedSlew); row -1 is the window stored just
    before this batch (``after_gap``: that window was dropped from the spool, so those slews
    are skipped).
    """

    columns: dict[str, np.ndarray]
    slews: list[tuple[int, int, Any]]
    after_gap: bool = False


class Ingest:
    """Feeds decoded frames to the static detector and stores each closed window.

    The motion between consecutive windows is kept too (:class:`recal.slews.SlewTracker`,
    bounded memory) and stored with them, so the gyro can be calibrated from the slews.

    A window that cannot be stored (database outage) waits in a bounded spool, in order, and is
    retried with exponential back-off from :meth:`poll`; nothing is dropped unless the spool
    overflows (:data:`SPOOL_MAX` windows, counted in ``windows_dropped``).
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
    ) -> None:
        self._store = store
        self._session = session_id
        self._on_positions = on_positions
        self._events = events or Events(store)
        self._keeper = keeper
        self._config = config
        self._learn_s = learn_s
        self._estimator: NoiseFloorEstimator | None = None
        self._learning: list[Any] = []  # frames held while the first noise floor is learned
        self._learned_s = 0.0
        self._detector: StaticDetector | None = None
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
        self._tracker: SlewTracker | None = None
        self._fed = 0  # frames given to the detector
        self._last_id: int | None = None  # the last window stored (first end of the next slew)
        self.slews = 0
        self.slews_dropped: dict[str, int] = {}
        self._retry_at = 0.0
        self._backoff_s = SPOOL_RETRY_MIN_S
        self.store_error: str | None = None
        self.frames = 0
        self.windows = 0
        self.windows_dropped = 0
        self.last_detector_run = time.monotonic()

    def feed(self, batch: Any) -> list[int]:
        """Take a drivers.FrameBatch; returns the ids of positions stored by this call."""
        with self._lock:
            if len(batch) == 0:
                return []
            if not self._pending:
                self._first_pending = time.monotonic()
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
            if self._spool and time.monotonic() >= self._retry_at:
                return self._drain()
            return []

    def _stale(self) -> bool:
        return time.monotonic() - self._first_pending >= DETECTOR_MAX_WAIT_S

    def flush(self) -> list[int]:
        """End of stream: close the open window, if any."""
        with self._lock:
            return self._run(flush=True)

    @property
    def report(self) -> Any:
        return None if self._detector is None else self._detector.report

    @property
    def learning(self) -> bool:
        """Frames are being held to learn the first noise floor (no windows yet)."""
        return self._detector is None

    def _start_detector(self) -> None:
        self._detector = StaticDetector(self._config)
        cfg = self._config
        self._learned_from_still = (
            self._keeper is not None and cfg.init_still_s is not None and cfg.noise_floor is None
        )

    def _learn(self, batch: Any, final: bool) -> list[Any]:
        """Hold frames and feed the estimator until ``learn_s`` of device time (or the end of
        the stream); then start the detector with the floor and give it the held frames."""
        if batch is not None and len(batch):
            self._learning.append(batch)
            self._estimator.feed(batch.time_s, batch.gyro_dph, batch.accel_g, batch.valid)
            t = batch.time_s
            self._learned_s += float(t[-1] - t[0]) if len(t) > 1 else 0.0
        if self._learned_s < self._learn_s and not final:
            return []
        try:
            floor = self._estimator.result()
        except RecalInputError as exc:
            if not final:
                return []  # not enough yet (e.g. all frames invalid so far): keep learning
            self._events.emit("noise_floor", f"cannot learn the noise floor: {exc}",
                              level=logging.WARNING)  # fmt: skip
            self._learning = []
            return []
        self._config = replace(self._config, noise_floor=floor)
        self._start_detector()
        if self._keeper is not None:
            self._keeper.save(floor, floor.source)
        held, self._learning = self._learning, []
        return held

    def frames_waiting_s(self) -> float | None:
        """How long the oldest frame not yet given to the detector has waited (host s)."""
        with self._lock:
            return time.monotonic() - self._first_pending if self._pending else None

    def detector_health(self) -> dict[str, Any]:
        if self._detector is None:
            return {"learning_noise_floor": True, "learned_s": round(self._learned_s, 1),
                    "learn_s": self._learn_s}  # fmt: skip
        rep = self._detector.report
        return {
            "accel_threshold": rep.accel_threshold,
            "gyro_threshold": rep.gyro_threshold,
            "threshold_source": getattr(rep, "threshold_source", None),
            "windows_kept": rep.windows_kept,
            "rejected": dict(rep.rejected),
        }

    @property
    def spooled(self) -> int:
        """Windows waiting for the database."""
        return len(self._spool)

    def _run(self, flush: bool) -> list[int]:
        windows = []
        self.last_detector_run = time.monotonic()
        batches, self._pending, self._count = self._pending, [], 0
        if self._detector is None:
            from drivers import FrameBatch

            batches = self._learn(FrameBatch.concat(batches) if batches else None, final=flush)
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
        if windows and self._keeper is not None:
            self._keeper.refine(windows)
        if windows:
            if len(self._spool) >= SPOOL_MAX:
                self._spool.popleft()
                self.windows_dropped += 1
                if self._spool:
                    self._spool[0].after_gap = True
            slews = []
            if self._tracker is not None:
                for k, w in enumerate(windows):
                    r = self._tracker.window(w)
                    if r is not None:
                        slews.append((k - 1, k, r))
            self._spool.append(_Spooled(windows_to_columns(windows), slews))
            self._retry_at = 0.0  # new data: try the database now
        return self._drain() if self._spool and time.monotonic() >= self._retry_at else []

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
        """Store spooled windows in order until the spool is empty or the database fails."""
        stored: list[int] = []
        while self._spool:
            entry = self._spool[0]
            slews = [x for x in entry.slews if x[0] >= 0 or not entry.after_gap]
            period = None if self._tracker is None else self._tracker.period_s
            try:
                ids = self._store.add_positions(
                    self._session, entry.columns, slews, period, self._last_id
                )
            except StoreError as exc:
                if self.store_error is None:
                    self._events.emit("database", f"cannot store windows, spooling them: {exc}",
                                      level=logging.WARNING)  # fmt: skip
                self.store_error = str(exc)
                self._retry_at = time.monotonic() + self._backoff_s
                self._backoff_s = min(2 * self._backoff_s, SPOOL_RETRY_MAX_S)
                break
            self._spool.popleft()
            stored += ids
            self._last_id = ids[-1] if ids else self._last_id
            for *_, r in slews:
                if r.dropped is None:
                    self.slews += 1
                else:
                    self.slews_dropped[r.dropped] = self.slews_dropped.get(r.dropped, 0) + 1
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


@dataclass(frozen=True)
class JobOutcome:
    """What a calibration job returns to the scheduler (picklable)."""

    document: dict[str, Any] | None  # the `recal calibrate --json` object
    accepted: bool
    reasons: list[str]
    error: str | None = None  # unusable design or bad input: wait for more positions


def _mc_progress(options: CalibrationOptions) -> Callable[[float], None] | None:
    """For a swarm method: a progress callback that forwards the Monte Carlo runs done to the
    supervisor (service.jobs.report_progress; the API's /health shows them); None for LM."""
    if options.method == "lm":
        return None
    done = [0.0]

    def progress(runs: float) -> None:
        done[0] += runs
        report_progress(min(done[0], options.mc_runs), options.mc_runs)

    return progress


def calibration_job(
    columns: dict[str, np.ndarray],
    options: CalibrationOptions,
    previous: Any,
    gate_settings: dict[str, Any],
    site: dict[str, Any] | None = None,
) -> JobOutcome:
    """Calibrate, predict the navigation impact, then gate against the previous accepted
    version. Runs in a worker process. ``site``: ``[site]`` settings (IMU attitude, horizon)."""
    from service.gate import GateConfig, gate

    try:
        result = calibrate(
            Positions.from_columns(columns, source="store"), options, progress=_mc_progress(options)
        )
    except RecalInputError as exc:
        return JobOutcome(None, False, [str(exc)], error=str(exc))
    document = result.to_json_dict()
    try:
        impact = navigation_impact_of(result, previous, site or {})
    except (RecalInputError, ValueError, np.linalg.LinAlgError) as exc:
        impact = None  # the coefficients stand without it; the document says why it is missing
        document["navigation_impact_error"] = str(exc)
    document["navigation_impact"] = None if impact is None else impact.to_json_dict()
    check = None
    if options.effects:  # not better than the seed model while its core shift is unconfirmed
        from recal.diagnose import effects_check

        check = effects_check(result, options)
        document["effects_check"] = check
    decision = gate(result, previous, GateConfig(**gate_settings), impact, check)
    return JobOutcome(document, decision.accepted, list(decision.reasons))


def navigation_impact_of(result: Any, previous: Any, site: dict[str, Any]) -> Any:
    """The predicted 24 h static navigation error of a fit, and of replacing ``previous`` (the
    accepted :class:`CalibrationRecord`, or None) by it (:class:`recal.ins_error.NavigationImpact`).

    Coefficients the fit held keep the accepted version's 1-sigma (they were held at its
    values); a triad the fit did not calibrate is taken from the accepted version.
    """
    from recal.coefficients import CoefficientSet
    from recal.ins_error import (
        complete_seed_set,
        navigation_impact,
        predict_from_uncertainty,
        seed_covariance,
        sigma_from_doc,
    )

    lat, height = result.problem.latitude_deg, result.problem.height_m
    attitude = tuple(site.get("imu_attitude_rpy_deg", (0.0, 0.0, 0.0)))
    hours = float(site.get("navigation_hours", 24.0))
    old = old_sigma = None
    if previous is not None:
        doc = previous.document
        old = CoefficientSet.from_json_dict(doc.get("coefficients") or {}, source="accepted")
        old_sigma = sigma_from_doc(doc) if doc.get("uncertainty") else {}
    new, _ = complete_seed_set(result.coefficients, old)
    cov, exact = seed_covariance(result.layout.term_slices(), result.covariance, old_sigma)
    accepted_m = None
    if previous is not None:
        old_full, _ = complete_seed_set(old, new)
        stored = previous.document.get("navigation_impact") or {}
        same = [stored.get(k) for k in ("latitude_deg", "hours")] == [lat, hours] and tuple(
            stored.get("attitude_rpy_deg") or ()
        ) == attitude
        if same and stored.get("static_24h_error_m_1sigma") is not None:
            accepted_m = float(stored["static_24h_error_m_1sigma"])
        elif old_sigma:  # an older record, or the site changed: recompute (independent 1-sigmas)
            u = predict_from_uncertainty(previous.document, old_full, lat, height, attitude, hours)
            accepted_m = float(u.sigma_horizontal_m[-1])
        old = old_full
    return navigation_impact(
        new, cov, lat, height, attitude, hours, exact, old,
        None if previous is None else previous.version, accepted_m,
    )  # fmt: skip


class SchedulerBusy(RuntimeError):
    """A recalibration is already running."""


class SchedulerRefused(RuntimeError):
    """A recalibration cannot start now (the message says why and which setting decides)."""


class Scheduler:
    """Starts a recalibration when enough new positions have arrived (or when asked).

    Jobs run in a supervised worker process (:class:`service.jobs.JobRunner`): a job that dies,
    hangs past ``scheduler.job_timeout_s`` or is cancelled at shutdown is recorded as failed with
    the reason, and the next trigger works. Every step is an event (log line and store row).
    """

    def __init__(
        self,
        store: Any,
        settings: Settings,
        publisher: Any,
        events: Events | None = None,
        runner: JobRunner | None = None,
    ) -> None:
        self._store = store
        self._settings = settings
        self._publisher = publisher
        self._events = events or Events(store)
        self._runner = runner or JobRunner(timeout_s=settings.scheduler.job_timeout_s)
        self._lock = threading.Lock()
        self._new_positions = 0
        self._retry = False  # a finished job could not be stored: run again when possible
        self.last_outcome: JobOutcome | None = None
        self.last_end: JobEnd | None = None
        self._unit_warned: list[str] = []
        self._finished = threading.Event()
        self._finished.set()

    # -- triggers -------------------------------------------------------------------------
    def notify(self, ids: list[int]) -> None:
        """New positions were stored; start a job when the policy says so."""
        s = self._settings.scheduler
        with self._lock:
            self._new_positions += len(ids)
            if self._new_positions < s.min_new_positions or self.busy:
                return
        self._try("auto")

    def _try(self, trigger: str) -> int | None:
        try:
            return self.trigger(trigger)
        except (SchedulerBusy, SchedulerRefused, StoreError):
            return None

    @property
    def busy(self) -> bool:
        return self._runner.busy

    def trigger(self, trigger: str = "manual") -> int:
        """Start a recalibration now; returns the job number.

        Raises SchedulerBusy (a job runs), SchedulerRefused (too few positions) or StoreError.
        """
        s = self._settings
        with self._lock:
            if self.busy:
                raise SchedulerBusy("a recalibration is already running")
            stored = self._store.count_positions()
            # the policy's minimum decides automatic jobs; an operator's trigger, or the rerun of
            # a job a restart interrupted, only needs positions the engine can use
            if trigger not in ("manual", "resume") and stored < s.scheduler.min_positions:
                raise SchedulerRefused(
                    f"only {stored} positions are stored; an automatic recalibration waits for "
                    f"{s.scheduler.min_positions} (scheduler.min_positions)"
                )
            if stored == 0:
                raise SchedulerRefused("no positions are stored yet: nothing to calibrate from")
            positions, ids = self._store.positions()
            keep = s.scheduler.use_last_positions
            if len(ids) > keep:  # the most recent windows describe the unit as it is now
                positions, ids = positions.subset(np.arange(len(ids) - keep, len(ids))), ids[-keep:]
            units = self._unit_problems(positions)
            if units:  # calibrating would publish a scale factor of 0.1, "accepted"
                raise SchedulerRefused("; ".join(units))
            previous = self._store.current()
            slews = self._slews(positions, ids) if s.scheduler.use_slews else None
            options = CalibrationOptions(
                sensor=None if s.scheduler.sensor == "both" else s.scheduler.sensor,
                method=s.scheduler.method,
                mc_runs=s.scheduler.mc_runs,
                latitude_deg=s.site.latitude_deg,
                height_m=s.site.height_m,
                prior=self._prior(previous),
                slews=slews,
            )
            try:  # a design the engine would refuse is refused now, with its reason
                check_design(positions, options, partial_ok=False)
            except RecalInputError as exc:
                raise SchedulerRefused(
                    f"the {len(ids)} stored positions cannot be used: {exc}"
                ) from None
            args = (positions.columns, options, previous, s.gate.model_dump(), s.site.model_dump())
            method = options.method
            self._finished.clear()
            try:
                job = self._runner.submit(
                    calibration_job,
                    args,
                    lambda end: self._finish(end, trigger, ids, previous, method),
                )
            except RuntimeError as exc:
                self._finished.set()
                raise SchedulerBusy(str(exc)) from None
            self._new_positions = 0
            self._retry = False
        self._events.emit("job", f"recalibration {job} started ({trigger})",
                          {"job": job, "state": "started", "trigger": trigger,
                           "positions": len(ids)})  # fmt: skip
        return job

    def _unit_problems(self, positions: Positions) -> list[str]:
        """A KVH outputs physical units: windows far from Earth's rate or 1 g mean a wrong
        ``[device]`` setting, named in the reason (emitted once as a device event)."""
        from recal.plausibility import check_units

        d = self._settings.device
        units = "[device] gyro_output / gyro_units"
        problems = check_units(positions).problems("[device] rate_hz", d.rate_hz, units)
        if problems and problems != self._unit_warned:
            self._events.emit("device", "; ".join(problems), level=logging.WARNING)
        self._unit_warned = problems
        return problems

    def _slews(self, positions: Positions, ids: list[int]) -> Any:
        """The stored slews between these positions, with their rows (None when there are none)."""
        records = self._store.slews(ids)
        if not records:
            return None
        row = {pid: k for k, pid in enumerate(ids)}
        period = records[0].period_s
        reduced = [
            (
                row[r.first_id],
                row[r.second_id],
                ReducedSlew(None, None, r.reference, r.samples, r.groups, r.dropped),
            )  # fmt: skip
            for r in records
            if abs(r.period_s - period) <= 1e-9 * period  # one frame rate per calibration
        ]
        cols = positions.columns
        return slews_from_reduced(reduced, period, cols["start_s"], cols["end_s"])

    def resume(self) -> int | None:
        """At start: run the job a restart interrupted, or the one new positions justify."""
        last_start = self._store.last_event("job", state="started")
        last_end = self._store.last_event("job", state="ended")
        interrupted = last_start is not None and (
            last_end is None or last_end["id"] < last_start["id"]
        )
        latest = self._store.history(limit=1)
        seen = max(latest[0].positions_used, default=0) if latest else 0
        s = self._settings.scheduler
        due = self._store.count_positions(since_id=seen) >= s.min_new_positions and (
            self._store.count_positions() >= s.min_positions
        )
        if not (interrupted or due):
            return None
        why = "a job was interrupted by the restart" if interrupted else "new positions"
        job = self._try("resume")
        if job is not None:
            log.info("resumed: %s", why)
        return job

    def tick(self) -> None:
        """Periodic duties (the daemon calls this every second or so): retry a job whose result
        could not be stored."""
        if self._retry and not self.busy:
            self._try("retry")

    def wait(self, timeout: float | None = None) -> JobOutcome | None:
        """Block until the running job (if any) is finished, stored and published."""
        self._finished.wait(timeout)
        return self.last_outcome

    def stop_starting(self) -> None:
        """No new job from now on (windows stored while stopping must not start one)."""
        self._runner.stop_starting()

    def shutdown(self, wait_s: float = 0.0) -> None:
        """Let a running job finish for up to ``wait_s`` s, then abandon it (recorded)."""
        self._runner.shutdown(wait_s)

    def health(self) -> dict[str, Any]:
        end = self.last_end
        return {
            "busy": self.busy,
            "running_for_s": self._runner.running_for_s(),
            # the running job: elapsed time, time limit and Monte Carlo runs done (swarms)
            "job": self._runner.progress(),
            "supervisor_alive": self._runner.alive,
            "last_job": None
            if end is None
            else {
                "job": end.job,
                "status": end.status,
                "message": end.message,
                "duration_s": round(end.duration_s, 3),
            },  # fmt: skip
        }

    @property
    def alive(self) -> bool:
        return self._runner.alive

    # -- internals ------------------------------------------------------------------------
    def _prior(self, previous: Any) -> CoefficientSet | None:
        if previous is not None:
            doc = previous.document
            # its uncertainty (inside "coefficients" since schema 1 files carry it; beside it
            # in older records) is what the coefficients held at it add to the new fit's
            block = {"uncertainty": doc.get("uncertainty"), **doc["coefficients"]}
            cs = CoefficientSet.from_json_dict(block)
            cs.metadata["source"] = f"version {previous.version}"
            return cs
        if self._settings.prior_path:
            from service.cli.common import load_coefficients

            return load_coefficients(self._settings.prior_path)
        return None

    def _finish(self, end: JobEnd, trigger: str, ids: list[int], previous: Any,
                method: str) -> None:  # fmt: skip
        """Called once per job by the runner's supervisor thread."""
        self.last_end = end
        if end.ok:
            outcome: JobOutcome = end.result
        else:
            outcome = JobOutcome(None, False, [end.message], error=end.message)
        self.last_outcome = outcome
        chained = False
        try:
            self._store_outcome(outcome, end, trigger, ids, previous, method)
            # positions that arrived while this job ran may already justify the next one;
            # started before "finished" is signalled, so a waiter never sees a false idle
            if self._new_positions >= self._settings.scheduler.min_new_positions:
                chained = self._try("auto") is not None
        except StoreError as exc:
            self._retry = True
            self._events.emit("job", f"recalibration {end.job} finished but could not be "
                              f"stored ({exc}); it will run again", level=logging.ERROR)  # fmt: skip
        finally:
            if not chained:
                self._finished.set()

    def _store_outcome(self, outcome: JobOutcome, end: JobEnd, trigger: str, ids: list[int],
                       previous: Any, method: str) -> None:  # fmt: skip
        from service.db import CalibrationRecord

        job = end.job
        ended = {"job": job, "state": "ended", "status": end.status,
                 "duration_s": round(end.duration_s, 3)}  # fmt: skip
        if outcome.document is None:
            what = "not possible" if end.ok else f"failed ({end.status})"
            self._events.emit("job", f"recalibration {job} {what}: {outcome.error}", ended,
                              level=logging.WARNING)  # fmt: skip
            return
        record = CalibrationRecord(
            version=None,
            created_at=datetime.now(UTC),
            trigger=trigger,
            method=method,
            accepted=outcome.accepted,
            reasons=outcome.reasons,
            document=outcome.document,
            positions_used=list(ids),
            prior_version=None if previous is None else previous.version,
        )
        version = self._store.add_calibration(record)
        verdict = "accepted" if outcome.accepted else "rejected: " + "; ".join(outcome.reasons)
        self._events.emit("calibration", f"version {version} {verdict}",
                          {"version": version, "accepted": outcome.accepted,
                           "chi2_red": outcome.document.get("chi2_red")},
                          level=logging.INFO if outcome.accepted else logging.WARNING)  # fmt: skip
        self._events.emit("job", f"recalibration {job} ended: version {version}",
                          ended | {"version": version})  # fmt: skip
        if outcome.accepted:
            self._publisher.sync(self._store.current())
