"""``[api]``: the HTTP API's address, token, allowed origins and stream cap."""

from __future__ import annotations

import re

from pydantic import Field, SecretStr, field_validator, model_validator

from service.config.hosts import is_loopback
from service.config.section import Section

#: Shortest ``[api] token`` accepted.
MIN_TOKEN_LENGTH = 16
_ORIGIN = re.compile(
    r"https?://[A-Za-z0-9.\-]+(:[0-9]{1,5})?|https?://\[[0-9A-Fa-f:.]+\](:[0-9]{1,5})?"
)


class ApiSettings(Section):
    host: str = Field(
        "127.0.0.1", description="address the HTTP API listens on (not loopback: needs a token)"
    )
    port: int = Field(8750, ge=0, le=65535, description="its TCP port")
    token: SecretStr | None = Field(
        None,
        description="bearer token the write endpoints require (Authorization: Bearer ...); "
        "without one they are refused, and the API may only listen on a loopback address",
    )
    allowed_origins: list[str] = Field(
        [],
        description="browser origins (scheme://host[:port]) allowed to call the API from their "
        "pages",
    )
    max_event_streams: int = Field(
        32, ge=1, le=10_000, description="open /events streams at once; more are answered 429"
    )

    @field_validator("token")
    @classmethod
    def _strong_token(cls, token: SecretStr | None) -> SecretStr | None:
        if token is None or token.get_secret_value() == "":  # RECAL_API__TOKEN= means unset
            return None
        value = token.get_secret_value()
        if len(value) < MIN_TOKEN_LENGTH or value != value.strip():
            raise ValueError(
                f"must be at least {MIN_TOKEN_LENGTH} characters without surrounding spaces "
                "(recal demo --serve prints a fresh one)"
            )
        return token

    @field_validator("allowed_origins")
    @classmethod
    def _origins(cls, origins: list[str]) -> list[str]:
        for origin in origins:
            if not _ORIGIN.fullmatch(origin):
                raise ValueError(f"{origin!r} is not an origin like http://host:port")
        return [o.lower() for o in origins]

    @model_validator(mode="after")
    def _loopback_without_token(self) -> ApiSettings:
        if self.token is None and not is_loopback(self.host):
            raise ValueError(
                f"host {self.host} is reachable from other machines: set [api] token "
                "(or RECAL_API__TOKEN), or listen on 127.0.0.1"
            )
        return self
