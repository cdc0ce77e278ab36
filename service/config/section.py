"""A settings section: unknown keys are errors (named, with the environment variable they
came from), and a section converts to the lower layer's config dataclass by shared field names."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from typing import Any, TypeVar

from pydantic import BaseModel, ConfigDict
from pydantic_settings import (
    BaseSettings,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
    TomlConfigSettingsSource,
)

T = TypeVar("T")


class Section(BaseModel):
    """A configuration section: a key it does not define is an error, not silently ignored."""

    model_config = ConfigDict(extra="forbid")


class TomlFileSettings(BaseSettings):
    """A settings file's model (the vessel's ``Settings``, the shore's ``ShoreSettings``): keyword
    arguments over the environment (``RECAL_SECTION__KEY``) over the TOML file (``toml_file`` of
    the model config)."""

    model_config = SettingsConfigDict(env_prefix="RECAL_", env_nested_delimiter="__")

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


def config_from(cls: type[T], section: BaseModel, prefix: str = "", **extra: Any) -> T:
    """``cls`` (a dataclass of a lower layer, e.g. ``recal.detect.static_config.DetectorConfig`` or
    ``drivers.DecoderConfig``) from the fields of a settings ``section`` it shares by name (the
    section's name with ``prefix`` before it: ``hull_trim_s`` for ``trim_s``), plus ``extra``: no
    field-by-field copy to fall out of step when either side gains a field."""
    names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    given = {
        k[len(prefix) :]: v
        for k, v in section.model_dump().items()
        if k.startswith(prefix) and k[len(prefix) :] in names
    }
    return cls(**{**given, **extra})


def check_keys(model: type[BaseModel], data: Mapping[str, Any], section: str | None) -> None:
    """Raise ValueError naming the first key of ``data`` that ``model`` (or one of its section
    models, recursively) does not define."""
    fields = model.model_fields
    for key, value in data.items():
        if key not in fields:
            where = f"{section}: " if section else ""
            raise ValueError(
                f"{where}unknown key {key} (known: {', '.join(fields)}){_env_hint(section, key)}"
            )
        sub = fields[key].annotation
        if isinstance(value, Mapping) and isinstance(sub, type) and issubclass(sub, BaseModel):
            check_keys(sub, value, f"{section}.{key}" if section else key)


def _env_hint(section: str | None, key: str) -> str:
    """Where an unknown key came from, when it is an environment variable."""
    parts = [*(section.split(".") if section else []), key]
    name = "RECAL_" + "__".join(parts)
    found = [k for k in os.environ if k.upper() == name.upper()]
    return f" from environment variable {found[0]}" if found else ""
