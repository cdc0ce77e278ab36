"""``[nav]``: the ship's GNSS and heading over NMEA 0183."""

from __future__ import annotations

from pydantic import Field, field_validator, model_validator

from service.config.section import Section


class NavSettings(Section):
    """The ship's GNSS and heading over NMEA 0183 (docs/service.md, `[nav]`);
    without ``url`` (no ``[nav]`` section) none are read."""

    url: str | None = Field(
        None,
        description="where the sentences come from: udp://:10110 (the marine default: UDP "
        "broadcasts on port 10110), tcp://HOST:PORT, or a serial port as [device] url takes; "
        "unset: no ship's sensors",
    )
    log: str | None = Field(
        None,
        description="instead of url, for a replayed capture ([device] url = replay://...): a "
        "file of the sentences logged beside it, its first sentence at the capture's first "
        "frame (as recal positions --nmea aligns it); the windows are joined to it on the "
        "capture's own clock, whatever the replay's speed",
    )
    baudrate: int = Field(
        4800, gt=0, description="serial line speed (bit/s; NMEA 0183: 4800, high-speed 38400)"
    )
    max_sog_kn: float = Field(
        1.0,
        ge=0,
        description="a window whose mean speed over ground exceeds this is rejected as "
        "underway (kn); below it the transport rate of its net displacement is added to its "
        "gyro sigma (docs/service.md, 'The ship's sensors')",
    )

    @field_validator("url")
    @classmethod
    def _openable(cls, url: str | None) -> str | None:
        if url is None or url.strip() == "":
            return None
        from drivers.transport import check_url

        check_url(url.strip(), must_exist=False)  # DriverInputError naming the known schemes
        return url.strip()

    @field_validator("log")
    @classmethod
    def _readable(cls, log: str | None) -> str | None:
        if log is None or log.strip() == "":
            return None
        from pathlib import Path

        if not Path(log.strip()).is_file():
            raise ValueError(f"{log.strip()} is not a file")
        return log.strip()

    @model_validator(mode="after")
    def _one_source(self) -> NavSettings:
        if self.url is not None and self.log is not None:
            raise ValueError("give url (a live talker) or log (a replayed one), not both")
        return self

    @property
    def enabled(self) -> bool:
        return self.url is not None or self.log is not None
