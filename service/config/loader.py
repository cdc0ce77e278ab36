"""Reading settings: a TOML file, the environment and keyword arguments, in that order of
rising precedence; bad input is one line naming the field (:class:`RecalInputError`)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, TypeVar

from pydantic import ValidationError
from pydantic_settings import BaseSettings, SettingsConfigDict

from recal.errors import RecalInputError
from service.config.settings import Settings

S = TypeVar("S", bound=BaseSettings)


def _one_line(err: Any) -> str:
    """``config: where: message`` for one pydantic error."""
    where = ".".join(str(x) for x in err["loc"])
    ctx = err.get("ctx") or {}
    msg = str(ctx["error"]) if err["type"] == "value_error" and "error" in ctx else err["msg"]
    msg = " ".join(msg.split())
    return f"config: {where}: {msg}" if where else f"config: {msg}"


def load_settings(path: str | os.PathLike[str] | None = None, **overrides: Any) -> Settings:
    """Settings from ``path`` (TOML), the environment and ``overrides``; bad input is a
    one-line :class:`RecalInputError` naming the field."""
    return load_toml_settings(Settings, path, **overrides)


def load_toml_settings(
    settings_cls: type[S], path: str | os.PathLike[str] | None = None, **overrides: Any
) -> S:
    """``settings_cls`` (a :class:`BaseSettings` reading ``toml_file``, as :class:`Settings`
    and the shore's ``service.fleet.config.ShoreSettings``) from ``path``, the environment and
    ``overrides``; bad input is a one-line :class:`RecalInputError` naming the field."""
    cls: type[S] = settings_cls
    if path is not None:
        p = Path(path)
        if not p.is_file():
            raise RecalInputError(f"config file {p} does not exist")

        class FileSettings(settings_cls):  # type: ignore[valid-type,misc]
            model_config = SettingsConfigDict(toml_file=p)

        cls = FileSettings
    try:
        return cls(**overrides)
    except ValidationError as exc:
        raise RecalInputError(_one_line(exc.errors()[0])) from None
    except ValueError as exc:  # TOML syntax errors
        raise RecalInputError(f"config {path}: {exc}") from None
