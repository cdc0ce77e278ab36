"""Service settings: a TOML file plus ``RECAL_*`` environment variables (pydantic-settings).

Precedence, highest first: keyword arguments, environment (``RECAL_SITE__LATITUDE_DEG=57.7``,
nested with ``__``), the TOML file, the defaults below. Example file::

    database_url = "sqlite:///var/lib/recal/recal.db"
    publish_path = "/run/recal/coefficients.json"

    [device]
    url = "/dev/ttyUSB0"       # or socket://host:port, replay:///path/capture.bin?speed=1
    format = "kvh-a"
    rate_hz = 1000

    [site]
    latitude_deg = 57.7

    [detector]
    init_still_s = 30

    [scheduler]
    min_positions = 12
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, Field, ValidationError
from pydantic_settings import (
    BaseSettings,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
    TomlConfigSettingsSource,
)

from recal.errors import RecalInputError


class DeviceSettings(BaseModel):
    url: str = "loop://"
    format: Literal["kvh-a", "kvh-b", "kvh-c"] = "kvh-a"
    baudrate: int = Field(921600, gt=0)
    rate_hz: float = Field(1000.0, gt=0, le=5000)
    gyro_output: Literal["delta", "rate"] = "delta"
    gyro_units: Literal["rad", "deg"] = "rad"
    temperature_units: Literal["degC", "centi"] = "degC"


class SiteSettings(BaseModel):
    latitude_deg: float = Field(45.0, ge=-90, le=90)
    height_m: float = 0.0


class DetectorSettings(BaseModel):
    window_s: float = Field(1.0, gt=0)
    min_duration_s: float = Field(10.0, gt=0)
    edge_trim_s: float = Field(1.0, ge=0)
    init_still_s: float | None = Field(30.0, gt=0)
    threshold_k: float = Field(5.0, gt=0)
    accel_threshold: float | None = None
    gyro_threshold: float | None = None
    max_gap_frames: int = Field(0, ge=0)


class SchedulerSettings(BaseModel):
    min_positions: int = Field(12, ge=1)
    min_new_positions: int = Field(4, ge=1)
    sensor: Literal["gyro", "accel", "both"] = "both"
    method: Literal["lm", "nafsa", "safsa", "oafsa"] = "lm"
    mc_runs: int = Field(100, ge=1)
    use_last_positions: int = Field(200, ge=1)


class GateSettings(BaseModel):
    max_chi2_red: float = Field(4.0, gt=0)
    max_change_sigma: float = Field(6.0, gt=0)
    max_relative_scale_sigma: float = Field(2e-3, gt=0)
    allow_jump: bool = False


class ApiSettings(BaseModel):
    host: str = "127.0.0.1"
    port: int = Field(8750, ge=0, le=65535)


class Settings(BaseSettings):
    """Everything the daemon needs; see the module docstring for the file layout."""

    model_config = SettingsConfigDict(env_prefix="RECAL_", env_nested_delimiter="__")

    database_url: str = "sqlite:///recal.db"
    publish_path: str = "coefficients.json"
    prior_path: str | None = None
    device: DeviceSettings = DeviceSettings()
    site: SiteSettings = SiteSettings()
    detector: DetectorSettings = DetectorSettings()
    scheduler: SchedulerSettings = SchedulerSettings()
    gate: GateSettings = GateSettings()
    api: ApiSettings = ApiSettings()

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        # keyword arguments > environment > TOML file (``toml_file`` of the model config)
        return init_settings, env_settings, TomlConfigSettingsSource(settings_cls)


def load_settings(path: str | os.PathLike[str] | None = None, **overrides: Any) -> Settings:
    """Settings from ``path`` (TOML), the environment and ``overrides``; bad input is a
    one-line :class:`RecalInputError` naming the field."""
    cls: type[Settings] = Settings
    if path is not None:
        p = Path(path)
        if not p.is_file():
            raise RecalInputError(f"config file {p} does not exist")

        class FileSettings(Settings):
            model_config = SettingsConfigDict(toml_file=p)

        cls = FileSettings
    try:
        return cls(**overrides)
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(x) for x in err["loc"])
        raise RecalInputError(f"config: {where}: {err['msg']}") from None
    except ValueError as exc:  # TOML syntax errors
        raise RecalInputError(f"config {path}: {exc}") from None
