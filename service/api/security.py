"""The API's two guards (docs/reference.md#api): the bearer token that write endpoints need,
and :class:`OriginGuard`, which refuses foreign origins and form-type write bodies so that a
web page open on a bridge computer cannot trigger anything."""

from __future__ import annotations

import hmac

from fastapi import Depends, FastAPI, HTTPException
from fastapi.responses import JSONResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.middleware.cors import CORSMiddleware
from starlette.types import ASGIApp, Receive, Scope, Send

from service.api.state import ApiDep

#: Methods that change something; they need the token and a non-form body.
WRITE_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})
#: Body types a browser sends cross-origin without asking first ("simple requests").
FORM_CONTENT_TYPES = frozenset(
    {"text/plain", "application/x-www-form-urlencoded", "multipart/form-data"}
)

_bearer = HTTPBearer(
    auto_error=False,
    description="The `[api] token` setting (or the RECAL_API__TOKEN environment variable).",
)


def require_token(
    api: ApiDep,
    credentials: HTTPAuthorizationCredentials | None = Depends(_bearer),  # noqa: B008
) -> None:
    """A dependency that refuses requests without ``Authorization: Bearer <[api] token>``
    (403 while no token is configured, 401 for a missing or wrong one)."""
    if api.token is None:
        raise HTTPException(
            403, "write endpoints are disabled: no [api] token is configured on the service"
        )
    expected = api.token.get_secret_value().encode()
    given = b"" if credentials is None else credentials.credentials.encode()
    if not hmac.compare_digest(given, expected):  # constant time
        raise HTTPException(
            401,
            "a valid Authorization: Bearer token is required",
            {"WWW-Authenticate": "Bearer"},
        )


def add_origin_guard(app: FastAPI, allowed: list[str]) -> None:
    """Install :class:`OriginGuard` (and CORS answers for the ``allowed`` origins)."""
    if allowed:  # answers the browsers' preflight for the configured origins
        app.add_middleware(
            CORSMiddleware,
            allow_origins=allowed,
            allow_methods=["GET", "POST"],
            allow_headers=["Authorization", "Content-Type", "Last-Event-ID"],
        )
    app.add_middleware(OriginGuard, allowed=frozenset(allowed))  # added last: runs first


class OriginGuard:
    """ASGI middleware: refuse cross-origin requests from origins not allowed (403) and write
    requests whose body type a plain HTML form can send (415)."""

    def __init__(self, app: ASGIApp, allowed: frozenset[str]) -> None:
        self.app = app
        self.allowed = allowed

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http":
            refusal = request_refusal(scope, self.allowed)
            if refusal is not None:
                status, detail = refusal
                await JSONResponse({"detail": detail}, status)(scope, receive, send)
                return
        await self.app(scope, receive, send)


def request_refusal(scope: Scope, allowed: frozenset[str]) -> tuple[int, str] | None:
    """Why an HTTP request is refused by :class:`OriginGuard`, or None."""
    headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
    origin = headers.get("origin")
    if origin is not None and not _same_origin(origin, scope, headers):
        if origin.lower() not in allowed:
            return 403, f"cross-origin request from {origin} refused ([api] allowed_origins)"
    if scope["method"] in WRITE_METHODS:
        media = headers.get("content-type", "").split(";")[0].strip().lower()
        if media in FORM_CONTENT_TYPES:
            return 415, f"a {media} body is not accepted here: send no body or application/json"
    return None


def _same_origin(origin: str, scope: Scope, headers: dict[str, str]) -> bool:
    """The page comes from this very server (e.g. the ``/docs`` page)."""
    host = headers.get("host")
    return host is not None and origin.lower() == f"{scope.get('scheme', 'http')}://{host}".lower()
