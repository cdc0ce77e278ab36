"""``[scheduler]``: when recalibrations run (triggers) and how (estimator, windows, limits)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, field_validator

from service.config.section import Section

Trigger = Literal["drift", "information", "count"]


class SchedulerSettings(Section):
    min_positions: int = Field(
        12, ge=1, description="stored windows before any automatic recalibration"
    )
    min_new_positions: int = Field(
        4,
        ge=1,
        description="new windows since the last job before the next automatic one by count, "
        "and before another drift or information job when the last one was not accepted",
    )
    trigger: list[Trigger] = Field(
        ["drift", "information"],
        description="what starts an automatic recalibration once one is accepted: 'drift' (the "
        "new windows show the coefficients changed, recal.diagnose.drift), 'information' (they would "
        "sharpen them by min_information_gain, recal.diagnose.information), 'count' (min_new_positions "
        "new windows); a list or one name (the first calibration always waits for "
        "min_positions windows)",
    )
    min_information_gain: float = Field(
        0.25,
        gt=0,
        lt=1,
        description="'information' trigger: run when the new windows would cut some "
        "coefficient's 1-sigma by this fraction",
    )
    drift_false_alarm_days: float = Field(
        30.0, gt=0, description="'drift' trigger: one false alarm per this many days..."
    )
    windows_per_day: float | None = Field(
        None,
        gt=0,
        description="... at this rate of static windows; unset: measured from the stored "
        "windows' device time (24 a day until a day of them is stored)",
    )

    sensor: Literal["gyro", "accel", "both"] = Field("both", description="triads to calibrate")
    method: Literal["lm", "nafsa", "safsa", "oafsa"] = Field(
        "nafsa",
        description="estimator (as recal calibrate --method): MCS-NAFSA, the seeds' method, "
        "by default (seconds with slews, docs/engine.md); lm is the fast fallback",
    )
    mc_runs: int = Field(100, ge=1, description="Monte Carlo runs for the uncertainties")
    use_last_positions: int = Field(
        200, ge=1, description="a job uses at most this many of the most recent windows"
    )
    use_slews: bool = Field(
        True,
        description="calibrate the gyro from the stored motion between windows too (recal.detect.slew_groups)",
    )
    turn_closure_deg: float = Field(
        0.0,
        ge=0,
        lt=180,
        description="declare that slews turning whole revolutions about the vertical close "
        "exactly, with this 1-sigma (deg), as recal calibrate --turn-closure; 0: none declared, "
        "a turn is closed only where the Earth-rate headings check it (a FOG)",
    )
    wander: Literal["auto", "none"] = Field(
        "auto",
        description="bias wander between windows (recal.solve.wander, as recal calibrate "
        "--wander): auto estimates it from each job's residuals where the windows of a session "
        "span an hour or more and keeps it when significant; none takes windows as independent",
    )
    job_timeout_s: float = Field(
        1800.0, gt=0, description="a job running longer is killed and recorded as failed (s)"
    )
    stop_wait_s: float = Field(
        60.0,
        ge=0,
        description="at shutdown a running job may finish for this long, then it is abandoned "
        "(s); keep it below the unit's TimeoutStopSec",
    )

    @field_validator("trigger", mode="before")
    @classmethod
    def _one_or_many(cls, value: Any) -> Any:
        if isinstance(value, str):  # trigger = "drift", or "drift+information"
            value = [v.strip() for v in value.replace(",", "+").split("+") if v.strip()]
        if isinstance(value, list | tuple):
            if not value:
                raise ValueError("name at least one of drift, information, count")
            return list(dict.fromkeys(value))
        return value
