"""The live pipeline: frames -> static windows -> positions -> calibration jobs -> versions.

:class:`Ingest` runs the static detector on decoded frames (batched, since a detector call has a
fixed cost) and stores every closed window as a position. :class:`Scheduler` decides when the
stored positions are worth a recalibration, runs :func:`calibration_job` in a worker process
(so the numerics never stall the reader or the API), passes the result through the gate, stores
the version and publishes it when accepted.
"""

from __future__ import annotations

import logging
import signal
import threading
import time
from collections.abc import Callable
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from dataclasses import dataclass
from datetime import UTC, datetime
from multiprocessing import get_context
from typing import Any

import numpy as np

from recal.calibrate import CalibrationOptions, calibrate
from recal.coefficients import CoefficientSet
from recal.errors import RecalInputError
from recal.positions import Positions
from recal.static import DetectorConfig, StaticDetector, windows_to_columns
from service.config import Settings

log = logging.getLogger("recal.pipeline")

#: Frames buffered before a detector call (4 s at 1 kHz): a call costs ~0.4 ms whatever its size.
DETECTOR_BLOCK = 4096
#: ... but never hold frames longer than this (host time, s), so slow streams are not delayed.
DETECTOR_MAX_WAIT_S = 1.0


def detector_config(settings: Settings) -> DetectorConfig:
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


class Ingest:
    """Feeds decoded frames to the static detector and stores each closed window."""

    def __init__(
        self,
        store: Any,
        session_id: int,
        config: DetectorConfig,
        on_positions: Callable[[list[int]], None] | None = None,
    ) -> None:
        self._store = store
        self._session = session_id
        self._detector = StaticDetector(config)
        self._on_positions = on_positions
        self._pending: list[Any] = []
        self._count = 0
        self._first_pending = 0.0
        self._lock = threading.Lock()
        self.frames = 0
        self.windows = 0

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
        """Run the detector on frames held longer than DETECTOR_MAX_WAIT_S (call periodically:
        when the stream pauses, no new batch arrives to push them through)."""
        with self._lock:
            return self._run(flush=False) if self._pending and self._stale() else []

    def _stale(self) -> bool:
        return time.monotonic() - self._first_pending >= DETECTOR_MAX_WAIT_S

    def flush(self) -> list[int]:
        """End of stream: close the open window, if any."""
        with self._lock:
            return self._run(flush=True)

    @property
    def report(self) -> Any:
        return self._detector.report

    def _run(self, flush: bool) -> list[int]:
        windows = []
        if self._pending:
            from drivers import FrameBatch

            b = FrameBatch.concat(self._pending)
            self._pending, self._count = [], 0
            windows += self._detector.feed(
                b.time_s, b.gyro_dph, b.accel_g, b.temperature_c, b.valid, b.lost_before
            )
        if flush:
            windows += self._detector.flush()
        if not windows:
            return []
        ids = self._store.add_positions(self._session, windows_to_columns(windows))
        self.windows += len(ids)
        if self._on_positions:
            self._on_positions(ids)
        return ids


@dataclass(frozen=True)
class JobOutcome:
    """What a calibration job returns to the scheduler (picklable)."""

    document: dict[str, Any] | None  # the `recal calibrate --json` object
    accepted: bool
    reasons: list[str]
    error: str | None = None  # unusable design or bad input: wait for more positions


def calibration_job(
    columns: dict[str, np.ndarray],
    options: CalibrationOptions,
    previous: Any,
    gate_settings: dict[str, Any],
) -> JobOutcome:
    """Calibrate, then gate against the previous accepted version. Runs in a worker process."""
    from service.gate import GateConfig, gate

    try:
        result = calibrate(Positions.from_columns(columns, source="store"), options)
    except RecalInputError as exc:
        return JobOutcome(None, False, [str(exc)], error=str(exc))
    decision = gate(result, previous, GateConfig(**gate_settings))
    return JobOutcome(result.to_json_dict(), decision.accepted, list(decision.reasons))


def _worker_init() -> None:
    # Ctrl-C reaches the whole process group: the daemon decides how jobs end, not the worker
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class SchedulerBusy(RuntimeError):
    """A recalibration is already running."""


class Scheduler:
    """Starts a recalibration when enough new positions have arrived (or when asked)."""

    def __init__(
        self,
        store: Any,
        settings: Settings,
        publisher: Any,
        executor: Executor | None = None,
    ) -> None:
        self._store = store
        self._settings = settings
        self._publisher = publisher
        self._executor = executor or ProcessPoolExecutor(
            max_workers=1, mp_context=get_context("spawn"), initializer=_worker_init
        )
        self._owns_executor = executor is None
        self._lock = threading.Lock()
        self._running: Future | None = None
        self._new_positions = 0
        self._jobs = 0
        self.last_outcome: JobOutcome | None = None
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
        if self._store.count_positions() >= s.min_positions:
            try:
                self.trigger("auto")
            except SchedulerBusy:
                pass

    @property
    def busy(self) -> bool:
        return self._running is not None and not self._running.done()

    def trigger(self, trigger: str = "manual") -> int:
        """Queue a recalibration now; returns the job number. Raises SchedulerBusy."""
        s = self._settings
        with self._lock:
            if self.busy:
                raise SchedulerBusy("a recalibration is already running")
            positions, ids = self._store.positions()
            keep = s.scheduler.use_last_positions
            if len(ids) > keep:  # the most recent windows describe the unit as it is now
                positions, ids = positions.subset(np.arange(len(ids) - keep, len(ids))), ids[-keep:]
            previous = self._store.current()
            options = CalibrationOptions(
                sensor=None if s.scheduler.sensor == "both" else s.scheduler.sensor,
                method=s.scheduler.method,
                mc_runs=s.scheduler.mc_runs,
                latitude_deg=s.site.latitude_deg,
                height_m=s.site.height_m,
                prior=self._prior(previous),
            )
            self._jobs += 1
            self._new_positions = 0
            self._finished.clear()
            job = self._jobs
            fut = self._executor.submit(
                calibration_job, positions.columns, options, previous, s.gate.model_dump()
            )
            self._running = fut
            fut.add_done_callback(
                lambda f: self._finish(f, job, trigger, ids, previous, options.method)
            )
            self._store.add_event("job", f"recalibration {job} started ({trigger})",
                                  {"positions": len(ids)})  # fmt: skip
            return job

    def wait(self, timeout: float | None = None) -> JobOutcome | None:
        """Block until the running job (if any) is finished, stored and published."""
        self._finished.wait(timeout)
        return self.last_outcome

    def shutdown(self) -> None:
        if self._owns_executor:
            self._executor.shutdown(wait=True, cancel_futures=True)

    # -- internals ------------------------------------------------------------------------
    def _prior(self, previous: Any) -> CoefficientSet | None:
        if previous is not None:
            cs = CoefficientSet.from_json_dict(previous.document["coefficients"])
            cs.metadata["source"] = f"version {previous.version}"
            return cs
        if self._settings.prior_path:
            from service.cli.common import load_coefficients

            return load_coefficients(self._settings.prior_path)
        return None

    def _finish(self, fut: Future, job: int, trigger: str, ids: list[int], previous: Any,
                method: str) -> None:  # fmt: skip
        try:
            outcome: JobOutcome = fut.result()
        except Exception as exc:  # noqa: BLE001 - a crashed job must not take the daemon down
            log.exception("recalibration %d crashed", job)
            outcome = JobOutcome(None, False, [f"internal error: {exc}"], error=str(exc))
        self.last_outcome = outcome
        chained = False
        try:
            self._store_outcome(outcome, job, trigger, ids, previous, method)
            # positions that arrived while this job ran may already justify the next one;
            # started before "finished" is signalled, so a waiter never sees a false idle
            if self._new_positions >= self._settings.scheduler.min_new_positions:
                try:
                    self.trigger("auto")
                    chained = True
                except RuntimeError:  # busy, or the executor is shutting down
                    pass
        finally:
            if not chained:
                self._finished.set()

    def _store_outcome(self, outcome: JobOutcome, job: int, trigger: str, ids: list[int],
                       previous: Any, method: str) -> None:  # fmt: skip
        from service.db import CalibrationRecord

        if outcome.document is None:
            self._store.add_event("job", f"recalibration {job} not possible: {outcome.error}")
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
        self._store.add_event("calibration", f"version {version} {verdict}")
        if outcome.accepted:
            self._publisher.publish(self._store.calibration(version))
