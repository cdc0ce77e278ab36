"""``[device]``: the IMU and its link (port, format, rate, units)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, field_validator, model_validator

from service.config.section import Section


def servable_formats() -> list[str]:
    """The registered formats the daemon can read from one port (not a pair of files)."""
    from drivers.registry import input_formats

    return [f.name for f in input_formats() if f.inputs == 1]


class DeviceSettings(Section):
    url: str = Field(
        "loop://",
        description="serial port (/dev/ttyUSB0), socket://host:port, or "
        "replay:///path/capture.bin?speed=1 to replay a recording",
    )
    format: str = Field(
        "kvh-a",
        description="input format, one registered in drivers.registry (recal positions --help "
        "lists them: KVH binary frames, csv lines, ...)",
        json_schema_extra={"choices": lambda: servable_formats()},
    )
    baudrate: int = Field(921600, gt=0, description="serial line speed (bit/s)")
    rate_hz: float = Field(
        1000.0,
        gt=0,
        le=5000,
        description="samples per second the unit sends (csv without a time column: time = "
        "row / rate_hz)",
    )
    gyro_output: Literal["delta", "rate"] = Field(
        "delta",
        description="KVH: delta: angle per sample (the device default); rate: per second",
    )
    gyro_units: Literal["rad", "deg"] = Field("rad", description="KVH: unit of the gyro output")
    temperature_units: Literal["degC", "centi"] = Field(
        "degC", description="KVH: centi: hundredths of a degC (the device's C_100)"
    )
    columns: str | None = Field(
        None,
        description="csv: the stream's own column names for the standard ones, NEW=OLD,... as "
        "recal positions --columns (e.g. accel_x=ax,accel_y=ay,accel_z=az,time_s=t)",
    )
    header: str | None = Field(
        None,
        description="csv: the header row, for a stream joined after its header went by (then "
        "every line read is data)",
    )

    @field_validator("format")
    @classmethod
    def _registered(cls, value: str) -> str:
        from drivers.registry import get_input_format

        fmt = get_input_format(value)  # InputError naming the registered formats
        if fmt.inputs != 1:
            raise ValueError(f"{fmt.name} is read from {fmt.inputs} files; a port carries one")
        return fmt.name

    @model_validator(mode="after")
    def _options_of_the_format(self) -> DeviceSettings:
        from drivers.registry import check_options

        check_options(self.format, {k: getattr(self, k) for k in ("columns", "header")})
        return self

    def format_options(self) -> dict[str, Any]:
        """The settings the format's parser takes (drivers.registry), by name."""
        from drivers.registry import get_input_format

        return {
            name: getattr(self, name)
            for name in get_input_format(self.format).option_names
            if getattr(self, name, None) is not None
        }
