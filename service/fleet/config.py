"""Shore settings: ``shore.toml`` plus ``RECAL_*`` environment variables, as the vessel's.

Read with :func:`service.config.load_toml_settings`, so precedence, unknown keys and one-line
errors are the vessel's own (``RECAL_API__TOKEN``, ``RECAL_DATABASE_URL``). Example::

    database_url = "postgresql+psycopg://recal@db.example/fleet"

    [api]
    host = "0.0.0.0"
    port = 8760
    # the fleet administrator's token (reads every unit), never written in this file: a file
    # systemd passes (LoadCredential=), RECAL_API__TOKEN, or only its sha256
    token_file = "/run/credentials/recal-shore.service/admin-token"

A plain ``[api] token`` in the file still works, with a warning, until :data:`TOKEN_IN_FILE_REMOVED_IN`.
"""

from __future__ import annotations

import hashlib
import hmac
import logging
import re
import tomllib
from pathlib import Path
from typing import Any

from pydantic import Field, PrivateAttr, SecretStr, field_validator, model_validator

from service.config import ApiSettings, Section, check_keys, is_loopback, load_toml_settings
from service.config.section import TomlFileSettings

log = logging.getLogger("recal.fleet")

#: The shore's default port (the vessel's API listens on 8750).
DEFAULT_PORT = 8760
#: Largest request body ``POST /fleet/ingest`` takes, compressed and decompressed (bytes).
DEFAULT_MAX_BATCH_BYTES = 4 * 1024 * 1024
#: The release that stops reading a plain ``[api] token`` from shore.toml (deprecated in 0.3.0).
TOKEN_IN_FILE_REMOVED_IN = "0.4.0"

_SHA256 = re.compile(r"[0-9a-f]{64}")


def token_digest(token: str) -> bytes:
    """The sha256 of a token; ``[api] token_sha256`` holds it in hex (``printf %s TOKEN |
    sha256sum``)."""
    return hashlib.sha256(token.encode()).digest()


class ShoreApiSettings(Section):
    host: str = Field(
        "127.0.0.1",
        description="address the shore API listens on (not loopback: needs a token)",
    )
    port: int = Field(DEFAULT_PORT, ge=0, le=65535, description="its TCP port")
    token: SecretStr | None = Field(
        None,
        description="the fleet administrator's bearer token: reads every unit (units use "
        "their own, from recal fleet add-unit); give it as RECAL_API__TOKEN, token_file or "
        f"token_sha256 (in shore.toml it is deprecated: it warns, and is no longer read from "
        f"{TOKEN_IN_FILE_REMOVED_IN}); without any of them only unit tokens are accepted, and "
        "the API may only listen on a loopback address",
    )
    token_file: str | None = Field(
        None,
        description="a file holding the administrator's token (its one line; e.g. systemd's "
        "LoadCredential=, /run/credentials/recal-shore.service/admin-token), read at start",
    )
    token_sha256: str | None = Field(
        None,
        description="the administrator's token as its hex sha256 (printf %s TOKEN | sha256sum): "
        "the shore keeps no copy of the token itself",
    )
    max_batch_bytes: int = Field(
        DEFAULT_MAX_BATCH_BYTES,
        ge=1024,
        description="largest ingest body, compressed and decompressed (bytes); larger: 413",
    )

    #: sha256 of the administrator's token, whichever key gave it (None: no administrator)
    _admin_digest: bytes | None = PrivateAttr(None)

    # the vessel's rules for the same keys ([api] of service.config)
    _strong_token = field_validator("token")(ApiSettings._strong_token.__func__)  # type: ignore[attr-defined]

    @field_validator("token_file", "token_sha256")
    @classmethod
    def _unset_if_empty(cls, value: str | None) -> str | None:
        return None if value is None or value.strip() == "" else value.strip()

    @field_validator("token_sha256")
    @classmethod
    def _hex_digest(cls, value: str | None) -> str | None:
        if value is not None and not _SHA256.fullmatch(value.lower()):
            raise ValueError("must be 64 hex digits, the sha256 of the token (printf %s TOKEN "
                             "| sha256sum)")  # fmt: skip
        return None if value is None else value.lower()

    @model_validator(mode="after")
    def _one_admin_token(self) -> ShoreApiSettings:
        given = [k for k in ("token", "token_file", "token_sha256") if getattr(self, k) is not None]
        if len(given) > 1:
            raise ValueError(f"{' and '.join(given)} are set: give the administrator's token "
                             "one way")  # fmt: skip
        if self.token_file is not None:
            self._admin_digest = token_digest(_read_token_file(self.token_file))
        elif self.token is not None:
            self._admin_digest = token_digest(self.token.get_secret_value())
        elif self.token_sha256 is not None:
            self._admin_digest = bytes.fromhex(self.token_sha256)
        return self

    @model_validator(mode="after")
    def _loopback_without_token(self) -> ShoreApiSettings:
        if self._admin_digest is None and not is_loopback(self.host):
            raise ValueError(
                f"host {self.host} is reachable from other machines: set the administrator's "
                "token ([api] token_file, token_sha256 or RECAL_API__TOKEN), or listen on "
                "127.0.0.1"
            )
        return self

    @property
    def has_admin(self) -> bool:
        """Whether an administrator's token is set (any of the three ways)."""
        return self._admin_digest is not None

    def is_admin(self, token: str) -> bool:
        """Whether ``token`` is the administrator's (compared as sha256 digests, in constant
        time)."""
        if self._admin_digest is None:
            return False
        return hmac.compare_digest(token_digest(token), self._admin_digest)


def _read_token_file(path: str) -> str:
    """The token a ``token_file`` holds: its text without the line's end, checked as ``token``."""
    p = Path(path).expanduser()
    try:
        token = p.read_text(encoding="utf-8").rstrip("\r\n")
        if ApiSettings._strong_token(SecretStr(token)) is None:  # type: ignore[call-arg]
            raise ValueError("it is empty")
    except OSError as exc:
        raise ValueError(f"token_file {p} cannot be read: {exc.strerror}") from None
    except ValueError as exc:
        raise ValueError(f"token_file {p}: the token {exc}") from None
    return token


class ShoreSettings(TomlFileSettings):
    """Everything ``recal fleet serve`` and ``recal fleet add-unit`` need."""

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
            check_keys(cls, data, section=None)
        return data


def load_shore_settings(path: str | None = None, **overrides: Any) -> ShoreSettings:
    """Shore settings from ``path`` (TOML), the environment and ``overrides``; bad input is a
    one-line :class:`recal.errors.RecalInputError` naming the field. A plain ``[api] token``
    in the file is logged as deprecated (it still works until 0.4.0)."""
    settings = load_toml_settings(ShoreSettings, path, **overrides)
    if path is not None and _token_in_file(Path(path)):
        log.warning(
            "%s: [api] token in the file is deprecated (it is no longer read from recal %s): "
            "give the administrator's token as [api] token_file (e.g. systemd LoadCredential=), "
            "RECAL_API__TOKEN, or [api] token_sha256 (docs/fleet.md, shore.toml)",
            path,
            TOKEN_IN_FILE_REMOVED_IN,
        )
    return settings


def _token_in_file(path: Path) -> bool:
    """Whether the (already parsed, valid) TOML file holds ``[api] token``."""
    with path.open("rb") as f:
        api = tomllib.load(f).get("api")
    return isinstance(api, dict) and api.get("token") not in (None, "")
