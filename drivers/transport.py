"""Opening ports: every port goes through ``serial.serial_for_url``.

Importing this module registers the project's ``replay://`` handler with pyserial (pyserial
looks for ``<package>.protocol_<scheme>`` in ``serial.protocol_handler_packages``).

Port forms: a device path (``/dev/ttyUSB0``, ``COM3``) at a baud rate, ``loop://``,
``socket://host:port``, ``rfc2217://host:port``, and
``replay:///path/capture.bin?speed=1.0&rate=1000&fmt=kvh-a`` (see drivers.protocol_replay).
"""

from __future__ import annotations

import errno
import importlib
import os
import pkgutil
import sys
import time
from collections.abc import Callable
from typing import Any
from urllib.parse import quote, unquote, urlencode, urlsplit

import serial
import serial.urlhandler
from serial.urlhandler.protocol_socket import Serial as _SocketPort

from .errors import DriverInputError

if "drivers" not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append("drivers")

DEFAULT_BAUD = 921600


def known_protocols() -> list[str]:
    """URL schemes pyserial can open here (its own handlers and the project's)."""
    names = {
        m.name[len("protocol_") :]
        for m in pkgutil.iter_modules(serial.urlhandler.__path__)
        if m.name.startswith("protocol_")
    }
    for package in serial.protocol_handler_packages:
        try:
            mod = importlib.import_module(package)
        except ImportError:
            continue
        for m in pkgutil.iter_modules(getattr(mod, "__path__", [])):
            if m.name.startswith("protocol_"):
                names.add(m.name[len("protocol_") :])
    return sorted(names)


def check_url(url: str, must_exist: bool = True) -> None:
    """Raise DriverInputError for a port string that can never open (bad scheme, missing path)."""
    if not isinstance(url, str) or not url.strip():
        raise DriverInputError(
            "no serial port given (e.g. /dev/ttyUSB0 or replay:///path/capture.bin)"
        )
    if "://" in url:
        scheme = url.split("://", 1)[0].lower()
        known = known_protocols()
        if scheme not in known:
            raise DriverInputError(
                f"bad port URL {url!r}: unknown scheme {scheme!r}:// (known: "
                + ", ".join(f"{k}://" for k in known)
                + ")"
            )
        return
    if must_exist and not sys.platform.startswith("win") and not os.path.exists(url):
        hint = "is the device plugged in?"
        if not url.startswith("/dev/"):
            hint += f" to play a capture file use replay://{os.path.abspath(url)}"
        raise DriverInputError(f"serial port {url} does not exist ({hint})")


def _describe_open_error(url: str, exc: BaseException) -> str:
    code = getattr(exc, "errno", None)
    if code is None and exc.args and isinstance(exc.args[0], int):
        code = exc.args[0]
    if code == errno.ENOENT:
        if url.lower().startswith("replay://"):
            path = unquote(urlsplit(url).netloc + urlsplit(url).path)
            return f"replay capture file {path} does not exist"
        return f"serial port {url} does not exist (is the device plugged in?)"
    if code in (errno.EACCES, errno.EPERM):
        return f"no permission to open serial port {url} (is the user in the dialout group?)"
    if code == errno.EBUSY:
        return f"serial port {url} is busy (is another program using it?)"
    return f"cannot open {url}: {exc}"


def open_serial(
    url: str, baudrate: int = DEFAULT_BAUD, timeout: float | None = 0.1, **kwargs: Any
) -> serial.SerialBase:
    """serial.serial_for_url with the project's defaults; raises pyserial's own errors."""
    return serial.serial_for_url(url, baudrate=baudrate, timeout=timeout, **kwargs)


def open_port(
    url: str, baudrate: int = DEFAULT_BAUD, timeout: float | None = 0.1, **kwargs: Any
) -> serial.SerialBase:
    """Open a port for the user: any failure becomes a one-line DriverInputError."""
    check_url(url)
    try:
        return open_serial(url, baudrate=baudrate, timeout=timeout, **kwargs)
    except ValueError as exc:
        raise DriverInputError(f"bad port URL or setting {url!r}: {exc}") from None
    except (serial.SerialException, OSError) as exc:
        raise DriverInputError(_describe_open_error(url, exc)) from None
    except Exception as exc:  # noqa: BLE001 - some pyserial handlers fail oddly on bad options
        raise DriverInputError(
            f"bad port URL or setting {url!r}: {type(exc).__name__}: {exc}"
        ) from None


def read_size_for(byte_rate: float, latency_s: float, limit: int) -> int:
    """Bytes a read should wait for: ``latency_s`` of data at ``byte_rate``, 1 to ``limit``."""
    return int(min(max(1.0, byte_rate * latency_s), limit))


def read_chunk(
    port: serial.SerialBase,
    min_bytes: int,
    max_bytes: int,
    byte_rate: float | None = None,
    pause: Callable[[float], object] = time.sleep,
) -> bytes:
    """One read of a useful size, never a busy loop.

    Less than ``min_bytes`` waiting and ``byte_rate`` known: ``pause`` until about
    ``min_bytes`` should be there (at most the port's timeout), then take what is waiting.
    Then, or without ``byte_rate``, read everything waiting (up to ``max_bytes``), or when less
    is waiting block until ``min_bytes`` have come or the port's timeout expires. pyserial's
    posix ``read(n)`` wakes at every arrival from the kernel (each USB packet, each write to a
    pty); the pause makes that about 1/latency wake-ups a second. Raises what the port raises.

    pyserial's ``socket://`` port says 1 in ``in_waiting`` however much has come: it would be
    read a byte per pause. It is read up to ``max_bytes`` at once, blocking until they have come
    or the timeout expires (it wakes per TCP segment, not per byte).
    """
    if isinstance(port, _SocketPort):
        return port.read(max_bytes)
    waiting = port.in_waiting
    if byte_rate and waiting < min_bytes:
        timeout = getattr(port, "timeout", None)
        timeout = 1.0 if timeout is None else timeout
        pause(min((min_bytes - waiting) / byte_rate, timeout))
        waiting = port.in_waiting
        if waiting:
            return port.read(min(waiting, max_bytes))
    return port.read(max(1, min(max(waiting, min_bytes), max_bytes)))


def replay_url(path: str | os.PathLike[str], **options: object) -> str:
    """replay:// URL for a capture file, e.g. replay_url("cap.bin", speed="max", chunk="random")."""
    absolute = os.path.abspath(os.fspath(path))
    query = urlencode({k: str(v) for k, v in options.items()})
    return "replay://" + quote(absolute) + (f"?{query}" if query else "")
