"""When to recalibrate: the scheduler of the daemon.

:class:`Scheduler` decides when the stored positions are worth a recalibration (the first one
after ``min_positions`` windows; then by drift, information gain or count,
:mod:`service.triggers`), runs :func:`service.recalibration.calibration_job` in a supervised
worker process (so the numerics never stall the reader or the API), stores the version with why
it ran, and publishes it when the gate accepts it. The triggers are evaluated in the scheduler's
own policy thread, never in the reader's.
"""

from __future__ import annotations

import logging
import threading
import time
from datetime import UTC, datetime
from typing import Any

import numpy as np

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.positions import Positions
from recal.solve.calibrate import check_design
from recal.solve.options import CalibrationOptions
from service.config import Settings
from service.events import Events
from service.jobs import JobEnd, JobRunner
from service.nav import NO_LATITUDE, working_latitude
from service.recalibration import JobOutcome, calibration_job, months_since
from service.store.errors import StoreError
from service.triggers import (
    Evaluation,
    accepted_coefficients,
    describe_reason,
    epoch_start,
    evaluate,
    stored_slews,
    with_sessions,
)

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
        # the policy thread: evaluates the triggers after new windows (never in the reader)
        self._wake = threading.Event()
        self._idle = threading.Event()
        self._idle.set()
        self._stopping = False
        self._policy: threading.Thread | None = None
        self._job_on_version: int | None = None  # accepted version when the last job started
        self._said: dict[str, str] = {}  # trigger problems already reported (once each)
        self.last_evaluation: Evaluation | None = None
        self._ending_in: int | None = None  # thread handling a job's end (it may chain one)
        self.last_reason: dict[str, Any] | None = None  # why the last job started
        # CPU of the trigger evaluations, s (per window, not per frame: health and benchmarks
        # keep it apart from the stream's per-frame cost)
        self.evaluation_cpu_s = 0.0
        self.evaluations = 0

    # -- triggers -------------------------------------------------------------------------
    def notify(self, ids: list[int]) -> None:
        """New positions were stored: the policy thread looks at them (returns at once)."""
        with self._lock:
            self._new_positions += len(ids)
            if self._stopping:
                return
            self._idle.clear()
            self._wake.set()
            if self._policy is None or not self._policy.is_alive():
                self._policy = threading.Thread(target=self._policy_loop, name="scheduler-policy",
                                                daemon=True)  # fmt: skip
                self._policy.start()

    def _policy_loop(self) -> None:
        while not self._stopping:
            if not self._wake.wait(1.0):
                continue
            self._wake.clear()
            try:
                self.evaluate()
            except Exception:  # noqa: BLE001 - one bad evaluation must not end the policy
                log.exception("evaluating the triggers failed")
            finally:
                if not self._wake.is_set():
                    self._idle.set()

    def evaluate(self, chained: bool = False) -> int | None:
        """Look at the stored windows and start a job when a configured trigger says so;
        returns the job number (the policy thread calls this after new windows; the end of a
        job, ``chained``, calls it while that job still counts as running)."""
        c0 = time.thread_time()
        try:
            return self._evaluate(chained)
        finally:
            self.evaluation_cpu_s += time.thread_time() - c0
            self.evaluations += 1

    def _evaluate(self, chained: bool) -> int | None:
        s = self._settings.scheduler
        if (self.busy and not chained) or self._stopping:
            return None  # the job's end looks again
        try:
            if self._store.count_positions() < s.min_positions:
                return None
            current = self._store.current()
            if current is None:  # the first calibration: by count
                if self._new_positions < s.min_new_positions:
                    return None
                return self._try("count", {"first": True, "new_windows": self._new_positions})
            rerun_wait = self._job_on_version == current.version
            ev = evaluate(self._store, self._settings, current, self._new_positions, rerun_wait)
        except StoreError:
            return None
        self._report(ev)
        if ev.decision is None:
            return None
        d = ev.decision
        job = self._try(d.trigger, d.detail, d.since_id)
        if job is None and d.trigger == "drift":
            self._say("drift-wait", f"drift declared at window {d.detail.get('alarm_id')} "
                      f"({d.detail.get('suspect')}); waiting for windows since the change that "
                      "the engine can use", level=logging.WARNING)  # fmt: skip
        return job

    def _report(self, ev: Evaluation) -> None:
        """The drift statistic as an event per evaluation (the dashboard plots them); trigger
        problems once each."""
        self.last_evaluation = ev
        if ev.drift is not None:
            d = ev.drift
            alarm = "DRIFT" if d["alarm_window"] is not None else "steady"
            self._events.emit(
                "drift",
                f"{alarm}: statistic {d['statistic']:.2f} (threshold {d['threshold']:.2f}) "
                f"over {d['windows']} windows since version {ev.version}"
                + (f"; looks like {d['suspect']}" if d["alarm_window"] is not None else ""),
                {"version": ev.version, **{k: v for k, v in d.items() if k != "notes"}},
                level=logging.WARNING if d["alarm_window"] is not None else logging.INFO,
            )
        for p in ev.problems:
            self._say(p.split(":")[0], f"trigger not evaluated: {p}", level=logging.WARNING)

    def _say(self, key: str, message: str, level: int = logging.INFO) -> None:
        if self._said.get(key) != message:
            self._said[key] = message
            self._events.emit("scheduler", message, level=level)

    def _try(self, trigger: str, detail: dict[str, Any] | None = None,
             since_id: int | None = None) -> int | None:  # fmt: skip
        try:
            return self.trigger(trigger, detail, since_id)
        except (SchedulerBusy, SchedulerRefused, StoreError):
            return None

    @property
    def busy(self) -> bool:
        return self._runner.busy

    def trigger(self, trigger: str = "manual", detail: dict[str, Any] | None = None,
                since_id: int | None = None) -> int:  # fmt: skip
        """Start a recalibration now; returns the job number. ``trigger``: why (manual,
        resume, retry, count, drift, information), ``detail`` what the trigger saw (kept with
        the record), ``since_id``: use only the windows stored after it.

        Raises SchedulerBusy (a job runs), SchedulerRefused (too few positions) or StoreError.
        """
        s = self._settings
        with self._lock:
            # the end of a job may start the next one while that job still counts as running
            if self.busy and self._ending_in != threading.get_ident():
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
            previous = self._store.current()
            if since_id is None:  # windows from before a declared drift describe another unit
                since_id = epoch_start(previous)
            positions, ids = self._store.positions(since_id=since_id)
            if not ids:
                raise SchedulerRefused(f"no positions stored after window {since_id} (the last "
                                       "declared drift): nothing to calibrate from")  # fmt: skip
            keep = s.scheduler.use_last_positions
            if len(ids) > keep:  # the most recent windows describe the unit as it is now
                positions, ids = positions.subset(np.arange(len(ids) - keep, len(ids))), ids[-keep:]
            units = self._unit_problems(positions)
            if units:  # calibrating would publish a scale factor of 0.1, "accepted"
                raise SchedulerRefused("; ".join(units))
            latitude = working_latitude(s, positions)  # the ship's, else the site's
            if latitude is None:
                raise SchedulerRefused(NO_LATITUDE)
            slews = stored_slews(self._store, positions, ids) if s.scheduler.use_slews else None
            # each session restarts the device clock: the wander correlates windows within one
            positions = with_sessions(self._store, positions, ids)
            options = CalibrationOptions(
                sensor=None if s.scheduler.sensor == "both" else s.scheduler.sensor,
                method=s.scheduler.method,
                mc_runs=s.scheduler.mc_runs,
                latitude_deg=latitude,
                height_m=s.site.height_m,
                prior=self._prior(previous),
                fleet_prior=self._fleet_prior(),
                prior_age_months=months_since(previous),
                slews=slews,
                turn_closure_sigma_deg=s.scheduler.turn_closure_deg,
                wander=None if s.scheduler.wander == "none" else s.scheduler.wander,
            )
            try:  # a design the engine would refuse is refused now, with its reason
                # a hull-fixed unit may publish what it shows ([gate] publish_observable_part)
                observable_part = (
                    s.gate.publish_observable_part and s.gate.require_verdict == "partial"
                )
                check_design(positions, options, partial_ok=observable_part)
            except RecalInputError as exc:
                raise SchedulerRefused(
                    f"the {len(ids)} stored positions cannot be used: {exc}"
                ) from None
            why = {"trigger": trigger, **(detail or {})}
            if since_id is not None:
                why["since_id"] = since_id
            expected = f"drift declared, {describe_reason(why)}" if trigger == "drift" else None
            args = (positions.columns, options, previous, s.gate.model_dump(),
                    s.site.model_dump(), expected)  # fmt: skip
            method = options.method
            self._finished.clear()
            try:
                job = self._runner.submit(
                    calibration_job,
                    args,
                    lambda end: self._finish(end, trigger, ids, previous, method, why),
                )
            except RuntimeError as exc:
                self._finished.set()
                raise SchedulerBusy(str(exc)) from None
            self._new_positions = 0
            self._retry = False
            self._job_on_version = None if previous is None else previous.version
            self.last_reason = why
        self._events.emit("job", f"recalibration {job} started ({describe_reason(why)})",
                          {"job": job, "state": "started", "trigger": trigger,
                           "positions": len(ids), "reason": why})  # fmt: skip
        return job

    def _unit_problems(self, positions: Positions) -> list[str]:
        """A KVH outputs physical units: windows far from Earth's rate or 1 g mean a wrong
        ``[device]`` setting, named in the reason (emitted once as a device event)."""
        from recal.detect.plausibility import check_units

        d = self._settings.device
        units = "[device] gyro_output / gyro_units"
        problems = check_units(positions).problems("[device] rate_hz", d.rate_hz, units)
        if problems and problems != self._unit_warned:
            self._events.emit("device", "; ".join(problems), level=logging.WARNING)
        self._unit_warned = problems
        return problems

    def resume(self) -> int | None:
        """At start: rerun the job a restart interrupted, or look at the windows stored since
        the last job as the triggers would (:meth:`evaluate`)."""
        last_start = self._store.last_event("job", state="started")
        last_end = self._store.last_event("job", state="ended")
        interrupted = last_start is not None and (
            last_end is None or last_end["id"] < last_start["id"]
        )
        if interrupted:
            was = (last_start.get("data") or {}).get("reason") or {}
            job = self._try("resume", {"why": "a job was interrupted by the restart",
                                       "interrupted": was})  # fmt: skip
            if job is not None:
                log.info("resumed: a job was interrupted by the restart")
            return job
        latest = self._store.history(limit=1)
        seen = max(latest[0].positions_used, default=0) if latest else 0
        with self._lock:
            self._new_positions = self._store.count_positions(since_id=seen)
        return self.evaluate()

    def tick(self) -> None:
        """Periodic duties (the daemon calls this every second or so): retry a job whose result
        could not be stored."""
        if self._retry and not self.busy:
            self._try("retry")

    def wait(self, timeout: float | None = None) -> JobOutcome | None:
        """Block until the triggers have looked at the windows notified so far and the job they
        started (if any) is finished, stored and published."""
        start = time.monotonic()
        self._idle.wait(timeout)
        left = None if timeout is None else max(0.0, timeout - (time.monotonic() - start))
        self._finished.wait(left)
        return self.last_outcome

    def settled(self) -> bool:
        """The triggers have looked at every window notified, and no job runs or is due."""
        return self._idle.is_set() and not self.busy and self._finished.is_set()

    def stop_starting(self) -> None:
        """No new job from now on (windows stored while stopping must not start one)."""
        self._stopping = True
        self._wake.set()
        self._idle.set()
        self._runner.stop_starting()

    def shutdown(self, wait_s: float = 0.0) -> None:
        """Let a running job finish for up to ``wait_s`` s, then abandon it (recorded)."""
        self._runner.shutdown(wait_s)

    def health(self) -> dict[str, Any]:
        end, ev = self.last_end, self.last_evaluation
        return {
            "busy": self.busy,
            "running_for_s": self._runner.running_for_s(),
            # the running job: elapsed time, time limit and Monte Carlo runs done (swarms)
            "job": self._runner.progress(),
            "supervisor_alive": self._runner.alive,
            "policy_alive": self._policy_alive(),
            "triggers": list(self._settings.scheduler.trigger),
            "last_reason": self.last_reason,
            "evaluations": self.evaluations,
            "evaluation_cpu_s": round(self.evaluation_cpu_s, 3),
            "last_evaluation": None
            if ev is None
            else {
                "version": ev.version,
                "windows": ev.windows,
                "drift": ev.drift,
                "information": ev.information,
                "problems": ev.problems,
            },
            "last_job": None
            if end is None
            else {
                "job": end.job,
                "status": end.status,
                "message": end.message,
                "duration_s": round(end.duration_s, 3),
            },  # fmt: skip
        }

    def _policy_alive(self) -> bool:
        p = self._policy
        return p is None or p.is_alive() or self._stopping

    @property
    def alive(self) -> bool:
        """The job supervisor and the policy thread live (the watchdog's check)."""
        return self._runner.alive and self._policy_alive()

    # -- internals ------------------------------------------------------------------------
    def _fleet_prior(self) -> Any:
        """``[gate] fleet_prior``, read at every job (a new file from shore is used at the next
        recalibration); a file that no longer reads refuses the job, naming it."""
        path = self._settings.gate_fleet_prior()
        if path is None:
            return None
        from service.startup import read_fleet_prior_file

        try:
            setting = ("[gate] fleet_prior" if path == self._settings.gate.fleet_prior
                       else "the fleet prior fetched from shore")  # fmt: skip
            return read_fleet_prior_file(path, setting)
        except RecalInputError as exc:
            raise SchedulerRefused(str(exc)) from None

    def _prior(self, previous: Any) -> CoefficientSet | None:
        if previous is not None:
            # its uncertainty is what the coefficients held at it add to the new fit's
            return accepted_coefficients(previous)[0]
        if self._settings.prior_path:
            from service.startup import read_prior

            return read_prior(self._settings.prior_path)
        return None

    def _finish(self, end: JobEnd, trigger: str, ids: list[int], previous: Any,
                method: str, why: dict[str, Any]) -> None:  # fmt: skip
        """Called once per job by the runner's supervisor thread."""
        self.last_end = end
        if end.ok:
            outcome: JobOutcome = end.result
        else:
            outcome = JobOutcome(None, False, [end.message], error=end.message)
        self.last_outcome = outcome
        chained = False
        try:
            self._store_outcome(outcome, end, trigger, ids, previous, method, why)
            # positions that arrived while this job ran may already justify the next one;
            # started before "finished" is signalled, so a waiter never sees a false idle
            if self._new_positions > 0:
                self._ending_in = threading.get_ident()
                try:
                    chained = self.evaluate(chained=True) is not None
                finally:
                    self._ending_in = None
        except StoreError as exc:
            self._retry = True
            self._events.emit("job", f"recalibration {end.job} finished but could not be "
                              f"stored ({exc}); it will run again", level=logging.ERROR)  # fmt: skip
        finally:
            if not chained:
                self._finished.set()

    def _store_outcome(self, outcome: JobOutcome, end: JobEnd, trigger: str, ids: list[int],
                       previous: Any, method: str, why: dict[str, Any]) -> None:  # fmt: skip
        from service.store.records import CalibrationRecord

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
            document={**outcome.document, "trigger_detail": why},
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
