"""Start-up checks: each setting the daemon cannot use is one line naming the setting to fix.

:func:`check_startup` runs before anything is opened (``recal serve`` calls it after loading
the configuration); each failure is a :class:`RecalInputError`, so the command exits with code 2
and one line on stderr instead of a traceback or a misleading message later on.
"""

from __future__ import annotations

import errno
import os
import socket
from pathlib import Path
from typing import Any

from recal.errors import RecalInputError
from service.config import Settings


def check_startup(settings: Settings) -> None:
    """Raise :class:`RecalInputError` for the first setting that cannot work on this machine."""
    check_prior(settings.prior_path)
    if settings.gate.fleet_prior is not None:
        read_fleet_prior_file(settings.gate.fleet_prior)
    prepare_state_dir(settings)
    check_database(settings.database_url)
    check_api_port(settings.api.host, settings.api.port)


def spool_folder(settings: Settings) -> Path | None:
    """The spool's folder: ``spool_dir``, else its default (None: no spool)."""
    from service.spool import default_spool_dir

    if settings.spool_dir:
        return Path(settings.spool_dir)
    return default_spool_dir(settings.database_url, settings.state_dir)


def prepare_state_dir(settings: Settings) -> Path | None:
    """Create ``state_dir`` (and its parents) when a file the daemon writes goes in it: the
    SQLite database, the published file or the spool, by default or given there. A fresh
    user-level default (``~/.local/state/recal``) then works at the first start, while a
    database folder given explicitly must still exist (:func:`check_database` says so).
    Returns the folder when it is used, else None; RecalInputError when it cannot be made."""
    state = Path(settings.state_dir)
    spool = spool_folder(settings)
    written = [sqlite_folder(settings.database_url), Path(settings.publish_path).absolute(),
               None if spool is None else spool.absolute()]  # fmt: skip
    if not any(p is not None and p.is_relative_to(state) for p in written):
        return None
    try:
        state.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RecalInputError(
            f"state_dir {state} cannot be created ({exc.strerror or exc}): set state_dir (or "
            "STATE_DIRECTORY) to a writable folder, or give database_url, publish_path and "
            "spool_dir"
        ) from None
    return state


def check_prior(path: str | None) -> None:
    """The prior file exists and reads as coefficients: a newer or foreign ``schema`` stops the
    daemon at start (exit 2 naming it), not at its first recalibration."""
    if path is not None:
        read_prior(path)


def read_prior(path: str) -> Any:
    """``prior_path`` as a :class:`recal.model.coefficients.CoefficientSet` (RecalInputError naming
    the setting when it cannot be read)."""
    if not Path(path).is_file():
        raise RecalInputError(f"prior_path: {path} is not a file")
    from recal.model.coefficients import read_coefficients

    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise RecalInputError(f"prior_path: cannot read {path} as UTF-8 text: {exc}") from None
    try:
        return read_coefficients(text, source=path)
    except RecalInputError as exc:
        raise RecalInputError(f"prior_path: {exc}") from None


def read_fleet_prior_file(path: str, setting: str = "[gate] fleet_prior") -> Any:
    """A fleet prior file (:class:`recal.fleet.prior.FleetPrior`, issue 28; RecalInputError
    naming the setting when it cannot be read, or its format is newer or foreign)."""
    from recal.fleet.prior import read_fleet_prior

    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise RecalInputError(f"{setting}: cannot read {path}: {exc}") from None
    try:
        return read_fleet_prior(text, source=path)
    except RecalInputError as exc:
        raise RecalInputError(f"{setting}: {exc}") from None


def write_fleet_prior_file(path: str, prior: Any) -> None:
    """Save a fleet prior as its versioned JSON file (docs/fleet.md), atomically."""
    import json

    target = Path(path)
    tmp = target.with_name(target.name + ".tmp")
    tmp.write_text(json.dumps(prior.to_json_dict(), indent=1) + "\n", encoding="utf-8")
    os.replace(tmp, target)


def check_database(url: str, timeout_s: float = 5.0) -> None:
    """The database opens (a SQLite file's folder exists and is writable; a server answers)."""
    from service.store.errors import StoreError
    from service.store.repository import Store

    folder = sqlite_folder(url)
    if folder is not None:
        check_sqlite_folder(folder)
    try:
        store = Store(url, connect_timeout_s=timeout_s)
    except StoreError as exc:
        raise RecalInputError(f"database_url: {exc}") from None
    store.close()


def sqlite_folder(url: str) -> Path | None:
    """The folder a file SQLite URL puts its database in (None for other URLs and :memory:)."""
    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import ArgumentError

    try:
        parsed = make_url(url)
    except ArgumentError:
        return None  # the Store names a bad URL
    if parsed.get_backend_name() != "sqlite" or parsed.database in (None, "", ":memory:"):
        return None
    return Path(parsed.database).absolute().parent


def check_sqlite_folder(folder: Path) -> None:
    if not folder.is_dir():
        what = "is not a directory" if folder.exists() else "does not exist"
        raise RecalInputError(
            f"database_url: the database folder {folder} {what}: create it "
            f"(mkdir -p {folder}, owned by the service's user) or change database_url"
        )
    if not os.access(folder, os.W_OK | os.X_OK):
        raise RecalInputError(
            f"database_url: the database folder {folder} is not writable by this user"
        )


def check_api_port(host: str, port: int) -> None:
    """The API's address can be bound now (port 0, any free port, always can)."""
    if port == 0:
        return
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    try:
        with socket.socket(family, socket.SOCK_STREAM) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn does
            sock.bind((host.strip("[]"), port))
    except socket.gaierror:
        raise RecalInputError(f"[api] host {host} is not a known address") from None
    except OSError as exc:
        raise RecalInputError(_bind_error(host, port, exc)) from None


def _bind_error(host: str, port: int, exc: OSError) -> str:
    if exc.errno == errno.EADDRINUSE:
        return f"[api] port {port} is already in use on {host}: stop the other program or change [api] port"
    if exc.errno == errno.EACCES:
        return f"[api] port {port} needs privileges: use a port above 1023"
    if exc.errno == errno.EADDRNOTAVAIL:
        return f"[api] host {host} is not an address of this machine"
    return f"[api] cannot listen on {host}:{port}: {exc.strerror or exc}"
