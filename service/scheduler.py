"""When to recalibrate: the scheduler of the daemon.

:class:`Scheduler` decides when the stored positions are worth a recalibration, runs
:func:`service.recalibration.calibration_job` in a supervised worker process (so the numerics
never stall the reader or the API), stores the version and publishes it when the gate accepts it.
"""

from __future__ import annotations

import logging
import threading
from datetime import UTC, datetime
from typing import Any

import numpy as np

from recal.calibrate import CalibrationOptions, check_design
from recal.coefficients import CoefficientSet
from recal.errors import RecalInputError
from recal.positions import Positions
from recal.slews import ReducedSlew, slews_from_reduced
from service.config import Settings
from service.db import StoreError
from service.events import Events
from service.jobs import JobEnd, JobRunner
from service.recalibration import JobOutcome, calibration_job

log = logging.getLogger("recal.scheduler")


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
