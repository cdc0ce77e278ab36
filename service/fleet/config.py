"""Shore settings: ``shore.toml`` plus ``RECAL_*`` environment variables, as the vessel's.

Read with :func:`service.config.load_toml_settings`, so precedence, unknown keys and one-line
errors are the vessel's own (``RECAL_API__TOKEN``, ``RECAL_DATABASE_URL``). Example::

    database_url = "postgresql+psycopg://recal@db.example/fleet"

    [api]
    host = "0.0.0.0"
    port = 8760
    token = "..."      # the fleet administrator's; reads every unit
"""

from __future__ import annotations

from typing import Any

from pydantic import Field, SecretStr, field_validator, model_validator
from pydantic_settings import (
    BaseSettings,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
    TomlConfigSettingsSource,
)

from service.config import ApiSettings, Section, _check_keys, load_toml_settings

#: The shore's default port (the vessel's API listens on 8750).
DEFAULT_PORT = 8760
#: Largest request body ``POST /fleet/ingest`` takes, compressed and decompressed (bytes).
DEFAULT_MAX_BATCH_BYTES = 4 * 1024 * 1024


class ShoreApiSettings(Section):
    host: str = Field(
        "127.0.0.1",
        description="address the shore API listens on (not loopback: needs a token)",
    )
    port: int = Field(DEFAULT_PORT, ge=0, le=65535, description="its TCP port")
    token: SecretStr | None = Field(
        None,
        description="the fleet administrator's bearer token: reads every unit (units use "
        "their own, from recal fleet add-unit); without one only unit tokens are accepted, and "
        "the API may only listen on a loopback address",
    )
    max_batch_bytes: int = Field(
        DEFAULT_MAX_BATCH_BYTES,
        ge=1024,
        description="largest ingest body, compressed and decompressed (bytes); larger: 413",
    )

    # the vessel's rules for the same keys ([api] of service.config)
    _strong_token = field_validator("token")(ApiSettings._strong_token.__func__)  # type: ignore[attr-defined]

    @model_validator(mode="after")
    def _loopback_without_token(self) -> ShoreApiSettings:
        ApiSettings._loopback_without_token(self)  # type: ignore[arg-type]
        return self


class ShoreSettings(BaseSettings):
    """Everything ``recal fleet serve`` and ``recal fleet add-unit`` need."""

    model_config = SettingsConfigDict(env_prefix="RECAL_", env_nested_delimiter="__")

    database_url: str = Field(
        description="where the fleet is kept: postgresql+psycopg://user@host/db (sqlite:///FILE "
        "for a demo); shared with other tables it keeps to its own (fleet_*), and its schema "
        "is upgraded at start",
    )
    api: ShoreApiSettings = Field(ShoreApiSettings(), description="the shore's HTTP API")

    @model_validator(mode="before")
    @classmethod
    def _no_unknown_keys(cls, data: Any) -> Any:
        if isinstance(data, dict):
            _check_keys(cls, data, section=None)
        return data

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        return init_settings, env_settings, TomlConfigSettingsSource(settings_cls)


def load_shore_settings(path: str | None = None, **overrides: Any) -> ShoreSettings:
    """Shore settings from ``path`` (TOML), the environment and ``overrides``; bad input is a
    one-line :class:`recal.errors.RecalInputError` naming the field."""
    return load_toml_settings(ShoreSettings, path, **overrides)
