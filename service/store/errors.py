"""The Store's errors: one line each, whatever the driver said."""

from __future__ import annotations


class StoreError(RuntimeError):
    """The database cannot be opened or used; the message is one line."""


class UnknownSessionError(StoreError):
    """Positions for a session this database does not have (retrying cannot help)."""


def one_line(exc: BaseException) -> str:
    """First non-empty line of a driver error (psycopg messages span several lines)."""
    orig = getattr(exc, "orig", None) or exc
    lines = [ln.strip() for ln in str(orig).splitlines() if ln.strip()]
    return lines[0] if lines else type(orig).__name__
