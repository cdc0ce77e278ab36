"""Why a recalibration should run: the drift and information triggers of the scheduler.

Once a version is accepted, the windows stored after the last one it used are looked at each
time new ones arrive:

* **drift** (:mod:`recal.diagnose.drift`): the sequential GLR test of those windows against the accepted
  coefficients and their covariance, at the false-alarm rate the configuration sets
  (``drift_false_alarm_days`` at ``windows_per_day``). An alarm starts a job on the windows
  since the estimated change, once they form a design the engine can use (before that, the
  windows from before the change would pull the answer back towards the old unit);
* **information** (:mod:`recal.diagnose.information`): the expected cut of the accepted coefficients'
  1-sigma if the new windows (and the slews between them) were added; a job runs when some
  coefficient would sharpen by ``min_information_gain``;
* **count**: ``min_new_positions`` new windows since the last job (the old rule).

Each decision carries a JSON-ready ``detail`` that the job's record keeps (``trigger_detail``)
and the dashboard shows.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from recal.detect.slew_collect import ReducedSlew, slews_from_reduced
from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.positions import Positions
from service.config import Settings
from service.nav import NO_LATITUDE, working_latitude


@dataclass(frozen=True)
class Decision:
    """Start a job: ``trigger`` (drift, information, count), ``detail`` (JSON-ready, kept with
    the job's record), ``since_id``: the job uses only the windows stored after this id (None:
    the usual most recent ``use_last_positions``)."""

    trigger: str
    detail: dict[str, Any]
    since_id: int | None = None


@dataclass
class Evaluation:
    """One look at the windows since the accepted version: what each trigger found."""

    version: int
    windows: int
    drift: dict[str, Any] | None = None
    information: dict[str, Any] | None = None
    decision: Decision | None = None
    problems: list[str] = field(default_factory=list)  # a trigger that could not be evaluated


def accepted_coefficients(record: Any) -> tuple[CoefficientSet, dict[str, Any] | None]:
    """The accepted version's coefficients (with their 1-sigma) and its ``covariance`` block
    (None in records stored before versions carried it: the 1-sigma then act as a diagonal)."""
    from recal.model.coefficients import read_coefficients

    cs = read_coefficients(record.document, source=f"version {record.version}")
    return cs, record.document.get("covariance")


def epoch_start(record: Any) -> int | None:
    """The window after which the unit is the one ``record`` (the accepted version) describes:
    set by a job that a declared drift started (it used only the windows since the change) and
    carried by every later job; None when no drift was ever declared."""
    if record is None:
        return None
    since = (record.document.get("trigger_detail") or {}).get("since_id")
    return None if since is None else int(since)


def describe_reason(why: dict[str, Any] | None) -> str:
    """'drift: statistic 31.2 > 17.4, looks like gyro x scale, about +600 ppm' and the like."""
    if not why:
        return "unknown"
    t = why.get("trigger", "unknown")
    if t == "drift" and "statistic" in why:
        return (f"drift: statistic {why['statistic']:.1f} > {why['threshold']:.1f}"
                + (f", looks like {why['suspect']}" if why.get("suspect") else ""))  # fmt: skip
    if t == "information" and "gain" in why:
        return (
            f"information: {why.get('coefficient')} 1-sigma would fall "
            f"{100 * why['gain']:.0f} % (threshold {100 * why['threshold']:.0f} %)"
        )
    if t == "count" and "new_windows" in why:
        return f"count: {why['new_windows']} new windows"
    if t == "resume":
        return "resume: " + str(why.get("why", "restart"))
    return t


def stored_slews(store: Any, positions: Positions, ids: list[int]) -> Any:
    """The stored slews between these positions as a :class:`recal.detect.slew_data.Slews` in their rows
    (None when there are none)."""
    records = store.slews(ids)
    if not records:
        return None
    row = {pid: k for k, pid in enumerate(ids)}
    period = records[0].period_s
    reduced = [
        (row[r.first_id], row[r.second_id],
         ReducedSlew(None, None, r.reference, r.samples, r.groups, r.dropped))
        for r in records
        if abs(r.period_s - period) <= 1e-9 * period  # one frame rate per calibration
    ]  # fmt: skip
    cols = positions.columns
    return slews_from_reduced(reduced, period, cols["start_s"], cols["end_s"])


def evaluate(
    store: Any,
    settings: Settings,
    current: Any,
    new_since_job: int,
    rerun_wait: bool,
) -> Evaluation:
    """Look at the windows stored after the ones ``current`` (the accepted version) used.

    ``new_since_job``: windows since the last job started; ``rerun_wait``: a job already ran
    since ``current`` was accepted and was not accepted, so another one by drift or information
    also waits for ``min_new_positions`` new windows (a persistent alarm must not start a job
    per window).
    """
    s = settings.scheduler
    seen = max(current.positions_used, default=0)
    positions, ids = store.positions(since_id=seen)
    out = Evaluation(current.version, len(ids))
    if not ids:
        return out
    coefficients, covariance = accepted_coefficients(current)
    lat, height = working_latitude(settings, positions), settings.site.height_m
    if lat is None:
        out.problems.append(NO_LATITUDE)
        return out
    may_rerun = not rerun_wait or new_since_job >= s.min_new_positions
    if "drift" in s.trigger:
        try:
            out.drift = _drift(store, positions, ids, coefficients, covariance, settings, current)
        except (RecalInputError, ValueError, np.linalg.LinAlgError) as exc:
            out.problems.append(f"drift test: {exc}")
        else:
            if out.drift["alarm_window"] is not None and may_rerun:
                since = out.drift.pop("_since_id")
                out.decision = Decision("drift", out.drift, since)
                return out
            out.drift.pop("_since_id", None)
    if "information" in s.trigger:
        try:
            slews = stored_slews(store, positions, ids) if s.use_slews else None
            from recal.diagnose.information import information_gain

            gain = information_gain(positions, coefficients, covariance, lat, height, slews)
            out.information = gain.to_json_dict() | {"threshold": s.min_information_gain}
        except (RecalInputError, ValueError, np.linalg.LinAlgError) as exc:
            out.problems.append(f"information gain: {exc}")
        else:
            if gain.gain >= s.min_information_gain and may_rerun:
                out.decision = Decision("information", out.information)
                return out
    if "count" in s.trigger and new_since_job >= s.min_new_positions:
        out.decision = Decision("count", {"new_windows": new_since_job,
                                          "threshold": s.min_new_positions})  # fmt: skip
    return out


#: Device time of stored windows before their measured rate sets the drift threshold, s.
RATE_MIN_SPAN_S = 86400.0
#: The rate assumed until then: one window an hour.
DEFAULT_WINDOWS_PER_DAY = 24.0


def windows_per_day(store: Any, settings: Settings) -> tuple[float, bool]:
    """The rate of static windows the drift threshold is set at, and whether it was measured.

    The false-alarm rate is configured in days, the test runs per window: a hull detector stores
    several windows an hour, a still detector in port one a day. Unless ``windows_per_day`` is
    set, the rate is measured from the stored windows' device time (a day of it at least; before
    that one an hour is assumed)."""
    configured = settings.scheduler.windows_per_day
    if configured is not None:
        return float(configured), False
    count, span = store.window_rate()
    if span < RATE_MIN_SPAN_S or count < 2:
        return DEFAULT_WINDOWS_PER_DAY, False
    return count / span * 86400.0, True


def with_sessions(store: Any, positions: Positions, ids: list[int]) -> Positions:
    """The windows with their ``session`` column (each session restarts the device clock)."""
    cols = {**positions.columns, "session": store.sessions_of(ids)}
    return Positions(columns=cols, source=positions.source)


def _drift(
    store: Any,
    positions: Positions,
    ids: list[int],
    coefficients: CoefficientSet,
    covariance: dict[str, Any] | None,
    settings: Settings,
    current: Any = None,
) -> dict[str, Any]:
    """The drift test of these windows: last statistic, threshold, alarm, suspect (JSON)."""
    from recal.diagnose.drift import DriftConfig, drift_inputs, drift_test

    s = settings.scheduler
    from recal.solve.wander_model import possible_wander

    # the accepted version's bias wander (and the bound of what its windows could not show), so
    # that wander between windows is not read as a step
    wander = possible_wander((getattr(current, "document", None) or {}).get("noise_model"))
    positions = with_sessions(store, positions, ids) if wander else positions
    lat = working_latitude(settings, positions)  # the ship's, else the site's
    inputs = drift_inputs(positions, coefficients, covariance, lat, settings.site.height_m,
                          wander=wander)  # fmt: skip
    per_day, measured = windows_per_day(store, settings)
    result = drift_test(inputs, DriftConfig.per_days(s.drift_false_alarm_days, per_day))
    last = len(ids) - 1
    alarm = result.alarm_window
    change = int(result.change_window[last])
    end_s = positions.columns.get("end_s")
    out = {
        "statistic": round(float(result.statistic[last]), 4),
        "threshold": round(float(result.threshold), 4),
        "windows": len(ids),
        "first_id": ids[0],
        "last_id": ids[-1],
        "last_end_s": None if end_s is None else float(end_s[last]),
        "alarm_window": alarm,
        "alarm_id": None if alarm is None else ids[alarm],
        "change_id": ids[change],
        "suspect": result.suspects[0]["description"] if result.suspects else None,
        "windows_per_day": round(per_day, 2),
        "windows_per_day_measured": measured,
        "notes": list(inputs.notes),
        "_since_id": ids[change - 1] if change > 0 else ids[0] - 1,
    }
    return out
