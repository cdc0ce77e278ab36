"""``recal serve --config FILE.toml``: the onboard daemon (reader, pipeline, HTTP API)."""

from __future__ import annotations

import argparse
from typing import Any

#: Stands for the settings listing in the epilog until the help is shown: building it imports
#: pydantic, which ``recal --help`` and the other commands should not pay for.
SETTINGS_MARK = "\0settings\0"
_HEADER = "configuration settings"


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "serve",
        help="run the onboard service: read the IMU, find static windows, recalibrate, publish",
        description="Run the daemon described by a TOML config: upgrade the database schema, "
        "read the IMU, store its static windows, recalibrate on schedule, gate and publish the "
        "coefficients, serve the HTTP API. Stops cleanly on SIGINT/SIGTERM.",
        epilog=SETTINGS_MARK,
        formatter_class=SettingsHelpFormatter,
    )
    p.add_argument("--config", required=True, metavar="FILE.toml",
                   help="the settings (listed below); RECAL_* environment variables override "
                   "them")  # fmt: skip
    p.add_argument("--log-level", default="INFO", choices=("DEBUG", "INFO", "WARNING", "ERROR"),
                   help="messages logged on stderr from this level up (default INFO)")  # fmt: skip
    p.set_defaults(func=run)
    return p


class SettingsHelpFormatter(argparse.HelpFormatter):
    """Fills in the settings listing and keeps its layout (argparse would rewrap it)."""

    settings_cls: Any = None  # None: the daemon's (service.config.Settings)

    def add_text(self, text: str | None) -> None:
        if text == SETTINGS_MARK:
            text = settings_help(self._width, self._settings_cls())
        super().add_text(text)

    def _settings_cls(self) -> Any:
        if isinstance(self.settings_cls, str):  # "module:Name", imported only for --help
            import importlib

            module, name = self.settings_cls.split(":")
            return getattr(importlib.import_module(module), name)
        return self.settings_cls

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if text.startswith(_HEADER):
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)


def settings_help(width: int = 79, settings_cls: Any = None) -> str:
    """Every setting of the TOML file, by section: key = default, allowed values, description;
    read from the pydantic models of :mod:`service.config` (or of ``settings_cls``, e.g. the
    shore's)."""
    import textwrap

    from pydantic import BaseModel

    from service.config import Settings

    settings_cls = settings_cls or Settings
    lines = textwrap.wrap(
        f"{_HEADER} (the TOML file; an environment variable RECAL_<SECTION>__<KEY> overrides "
        "a key, e.g. RECAL_SITE__LATITUDE_DEG=57.7 or RECAL_API__TOKEN; unset: no value):",
        width,
    ) + [""]
    sections = []
    for key, info in settings_cls.model_fields.items():
        if isinstance(info.annotation, type) and issubclass(info.annotation, BaseModel):
            sections.append((key, info))
        else:
            lines += _setting(key, info, width)
    for key, info in sections:
        lines += ["", f"[{key}]" + (f"  # {info.description}" if info.description else "")]
        for name, field in info.annotation.model_fields.items():
            lines += _setting(name, field, width)
    return "\n".join(lines) + "\n"


def _setting(key: str, info: Any, width: int) -> list[str]:
    import textwrap

    allowed = _allowed(info)
    value = "required" if info.is_required() else _toml(info.get_default(call_default_factory=True))
    head = f"  {key} = {value}"
    out = [head + (f"  ({allowed})" if allowed else "")]
    if info.description:
        # never break inside a hyphenated name or path (recal-spool/...)
        out += textwrap.wrap(info.description, width, initial_indent=" " * 6,
                             subsequent_indent=" " * 6, break_on_hyphens=False)  # fmt: skip
    return out


def _toml(value: Any) -> str:
    import json

    if value is None:
        return "unset"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str | list | tuple):
        return json.dumps(value)  # a TOML basic string or array
    return repr(value)


def _allowed(info: Any) -> str:
    """The choices of a Literal, or the bounds of a number."""
    import types
    import typing

    extra = info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}
    if callable(extra.get("choices")):  # choices known at run time (a registry)
        return "one of " + ", ".join(extra["choices"]())
    ann = info.annotation
    many = typing.get_origin(ann) is list
    if many:  # a list of choices
        ann = typing.get_args(ann)[0]
    union = typing.get_origin(ann) in (typing.Union, types.UnionType)
    parts = typing.get_args(ann) if union else (ann,)
    choices = [
        str(arg)
        for part in parts
        if typing.get_origin(part) is typing.Literal
        for arg in typing.get_args(part)
    ]
    if choices:
        return ("any of " if many else "one of ") + ", ".join(choices)
    symbols = {"gt": ">", "ge": ">=", "lt": "<", "le": "<="}
    return ", ".join(
        f"{symbols[name]} {getattr(m, name):g}"
        for m in info.metadata
        for name in symbols
        if getattr(m, name, None) is not None
    )


def run(args: argparse.Namespace) -> int:
    import logging
    import signal
    import sys

    # a stop asked for while loading and checking the settings is a clean exit (run_daemon
    # installs its own handlers before it opens anything)
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: sys.exit(0))

    from service.config import load_settings
    from service.daemon import run_daemon
    from service.startup import check_startup

    logging.basicConfig(level=args.log_level, format="%(asctime)s %(name)s %(message)s")
    settings = load_settings(args.config)
    check_startup(settings)  # a setting this machine cannot honour: one line, exit code 2
    return run_daemon(settings)
