"""``[detector]``: the still detector's thresholds and durations, and the hull detector's keys."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, model_validator

from service.config.section import Section, config_from


class DetectorSettings(Section):
    """The static detector. Durations left unset follow the device rate (recal.detect.static_detector); the
    thresholds come, in this order, from explicit values, the noise floor stored for the device
    (reused after a restart: the unit may be moving then), an initial still period
    (init_still_s), or the quietest stretches of the first ``learn_s`` seconds."""

    window_s: float | None = Field(
        None, gt=0, description="moving-variance window (s; unset: about 100 frames)"
    )
    min_duration_s: float | None = Field(
        None, gt=0, description="shortest static window kept (s; unset: max(window_s, 0.5 s))"
    )
    edge_trim_s: float | None = Field(
        None, ge=0, description="dropped at both ends of a window (s; unset: window_s / 2)"
    )
    init_still_s: float | None = Field(
        None,
        gt=0,
        description="the unit starts still for this long: learn the noise floor there (s)",
    )
    learn_s: float = Field(
        120.0,
        gt=0,
        description="else learn it from the quietest stretches of the first learn_s (s)",
    )
    learn_quiet_s: float = Field(
        10.0,
        gt=0,
        description="learning ends sooner, from the frames held, when the stream sends nothing "
        "for this long (s of wall time), after learn_s of wall time, or when the input ends",
    )
    threshold_k: float = Field(5.0, gt=0, description="threshold = threshold_k x noise floor")
    accel_threshold: float | None = Field(
        None, ge=0, description="explicit accel threshold on the moving variance ((m/s^2)^2)"
    )
    gyro_threshold: float | None = Field(
        None, ge=0, description="explicit gyro threshold on the moving variance (gyro units^2)"
    )
    max_gap_frames: int = Field(
        5, ge=0, description="longest run of lost or invalid frames a window may contain"
    )
    # the hull detector (recal.detect.hull); the defaults are recal.detect.hull_config.HullConfig's
    motion: Literal["still", "hull"] = Field(
        "still",
        description="still: windows where the moving variance is low (a unit at rest); hull: "
        "quasi-static windows of a hull that rolls, pitches and swings at berth "
        "(recal.detect.hull: no noise floor is learned; the hull_* keys tune it)",
    )
    hull_min_window_s: float = Field(
        120.0, gt=0, description="hull: shortest quasi-static window (s; many wave periods)"
    )
    hull_max_window_s: float = Field(
        900.0, gt=0, description="hull: a longer quiet stretch is cut into windows this long (s)"
    )
    hull_turn_window_s: float = Field(
        60.0,
        ge=40,
        description="hull: span the rate is averaged over to find heading turns (s; at least "
        "two of the longest wave periods, 40 s)",
    )
    hull_max_swing_deg: float = Field(
        1.0, ge=0, description="hull: largest heading swing at berth that is not a turn (deg)"
    )
    hull_trim_s: float = Field(
        30.0, ge=0, description="hull: dropped at both ends of a quiet stretch (s)"
    )
    hull_lever_arm_max_m: float = Field(
        10.0,
        ge=0,
        description="hull: largest distance of the IMU from the hull's centre of rotation (m): "
        "its centripetal acceleration is carried in the accel uncertainty",
    )

    @model_validator(mode="after")
    def _hull_windows(self) -> DetectorSettings:
        if self.hull_min_window_s > self.hull_max_window_s:
            raise ValueError(
                f"hull_min_window_s {self.hull_min_window_s:g} exceeds hull_max_window_s "
                f"{self.hull_max_window_s:g}"
            )
        return self

    def hull_config(self) -> Any:
        """The hull detector's :class:`recal.detect.hull_config.HullConfig` from the hull_* keys."""
        from recal.detect.hull_config import HullConfig

        return config_from(HullConfig, self, "hull_", max_gap_frames=self.max_gap_frames)
