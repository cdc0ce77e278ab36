"""``[sync]``: fleet sync to the shore service (URL, unit serial, token)."""

from __future__ import annotations

import re
from urllib.parse import urlsplit

from pydantic import Field, SecretStr, field_validator, model_validator

from service.config.hosts import is_loopback
from service.config.section import Section

#: A unit's serial, as the shore registers it (docs/fleet.md, "Commands").
_SERIAL = re.compile(r"[A-Za-z0-9._-]{1,64}")


class SyncSettings(Section):
    """Fleet sync to the shore service (docs/fleet.md); without ``url``, ``unit`` and
    ``token`` (no ``[sync]`` section) nothing is sent."""

    url: str | None = Field(
        None,
        description="the shore service's base URL (https://host:port; plain http only to a "
        "loopback address, e.g. a local tunnel); unset: no sync",
    )
    unit: str | None = Field(
        None, description="this unit's serial, unique in the fleet (as registered on shore)"
    )
    token: SecretStr | None = Field(
        None,
        description="this unit's credential, printed by recal fleet add-unit on shore (or "
        "RECAL_SYNC__TOKEN)",
    )
    interval_s: float = Field(
        60.0,
        gt=0,
        description="how often the outbox is offered when the link is up (s); a backlog is "
        "sent batch after batch without waiting",
    )
    fleet_prior: bool = Field(
        True,
        description="fetch the fleet prior of this unit's model from the shore (at start, then "
        "every 6 h the link is up) into state_dir/fleet_prior.json, which the gate uses unless "
        "[gate] fleet_prior names a file",
    )

    @field_validator("url")
    @classmethod
    def _shore_url(cls, url: str | None) -> str | None:
        if url is None or url.strip() == "":
            return None
        parts = urlsplit(url.strip())
        if parts.scheme not in ("https", "http") or not parts.hostname:
            raise ValueError(f"{url!r} is not a URL like https://shore.example:8443")
        if parts.query or parts.fragment or parts.username or parts.password:
            raise ValueError(f"{url!r}: give the base URL only (no user, query or fragment)")
        if parts.scheme == "http" and not is_loopback(parts.hostname):
            raise ValueError(
                f"{url!r} would send the token in clear: use https (plain http only to a "
                "loopback address, e.g. a local tunnel)"
            )
        return url.strip().rstrip("/")

    @field_validator("unit")
    @classmethod
    def _serial(cls, unit: str | None) -> str | None:
        if unit is None or unit == "":
            return None
        if not _SERIAL.fullmatch(unit):  # what recal fleet add-unit registers
            raise ValueError(f"{unit!r}: a serial is 1 to 64 letters, digits, '.', '-', '_'")
        return unit

    @field_validator("token")
    @classmethod
    def _credential(cls, token: SecretStr | None) -> SecretStr | None:
        if token is None or token.get_secret_value() == "":  # RECAL_SYNC__TOKEN= means unset
            return None
        value = token.get_secret_value()
        if value != value.strip() or not value.isprintable() or " " in value:
            raise ValueError("must be printable, without spaces")
        return token

    @model_validator(mode="after")
    def _together(self) -> SyncSettings:
        given = {k: getattr(self, k) is not None for k in ("url", "unit", "token")}
        if any(given.values()) and not all(given.values()):
            missing = ", ".join(k for k, v in given.items() if not v)
            raise ValueError(
                f"url, unit and token go together (missing: {missing}; the token may come "
                "from RECAL_SYNC__TOKEN)"
            )
        return self

    @property
    def enabled(self) -> bool:
        return self.url is not None
