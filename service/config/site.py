"""``[site]``: where the unit is (latitude, height, attitude) and the navigation horizon."""

from __future__ import annotations

from pydantic import Field

from service.config.section import Section

#: The latitude a still (laboratory) unit is taken at when ``[site] latitude_deg`` is unset, as
#: before the setting could be unset; a hull-fixed unit never assumes one (Settings._latitude).
STILL_DEFAULT_LATITUDE_DEG = 45.0


class SiteSettings(Section):
    latitude_deg: float | None = Field(
        None,
        ge=-90,
        le=90,
        description="where the unit is: gravity and Earth rate follow it; unset: from [nav] "
        "(the windows' latitude); a still unit without [nav] is taken at 45; with motion = "
        '"hull", [nav] url or this is required',
    )
    height_m: float = Field(0.0, description="height above the WGS-84 ellipsoid (m)")
    imu_attitude_rpy_deg: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0),
        description="the IMU's roll, pitch, yaw in north-east-down at berth (deg): where its axes "
        "point decides which coefficient errors reach the predicted navigation error",
    )
    navigation_hours: float = Field(
        24.0, gt=0, le=720, description="horizon of the predicted static navigation error (h)"
    )
