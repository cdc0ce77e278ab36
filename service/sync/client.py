"""The HTTP link to the shore: one ``POST /fleet/ingest`` at a time over ``http.client``, with a
connect timeout, a read timeout on every socket operation, and :meth:`Link.abort` for a stop
that must not wait for either (the standard library only: no new dependency on a vessel)."""

from __future__ import annotations

import contextlib
import http.client
import json
import socket
import ssl
import threading
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlsplit

#: The ingest endpoint under the shore service's base URL (docs/fleet.md).
INGEST_PATH = "/fleet/ingest"
#: Longest answer read from the shore, bytes (an answer is a few dozen).
MAX_REPLY_BYTES = 64 * 1024


class LinkError(Exception):
    """The request did not get an answer (no route, refused, timed out, cut, TLS failure);
    the message is one line."""


@dataclass(frozen=True)
class Reply:
    """The shore's answer: HTTP status and its JSON body (None when it is not JSON)."""

    status: int
    body: Any
    text: str

    def detail(self) -> str:
        """The shore's reason in one line: ``detail`` of a JSON answer, else the text."""
        found = self.body.get("detail") if isinstance(self.body, dict) else None
        if found is None:
            found = self.text
        text = found if isinstance(found, str) else json.dumps(found)
        return " ".join(text.split())[:500] or http.client.responses.get(self.status, "")


class Link:
    """Posts gzip JSON bodies to ``{url}/fleet/ingest`` with ``Authorization: Bearer token``.

    One request at a time (the sync thread's). ``connect_timeout_s`` bounds the TCP connect
    and the TLS handshake; ``read_timeout_s`` every later send or receive, so a shore that
    accepts and never answers costs at most that long; :meth:`abort`, from another thread,
    ends a request in flight at once.
    """

    def __init__(
        self,
        url: str,
        token: str,
        *,
        connect_timeout_s: float = 10.0,
        read_timeout_s: float = 30.0,
        context: ssl.SSLContext | None = None,
    ) -> None:
        parts = urlsplit(url)
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise ValueError(f"not an http(s) URL: {url!r}")
        self.url = url
        self._https = parts.scheme == "https"
        self._host = parts.hostname
        self._port = parts.port
        self._path = parts.path.rstrip("/") + INGEST_PATH
        self._token = token
        self.connect_timeout_s = connect_timeout_s
        self.read_timeout_s = read_timeout_s
        self._context = context
        self._lock = threading.Lock()
        self._conn: http.client.HTTPConnection | None = None
        self._aborted = False

    @property
    def endpoint(self) -> str:
        scheme = "https" if self._https else "http"
        port = "" if self._port is None else f":{self._port}"
        return f"{scheme}://{self._host}{port}{self._path}"

    def post(self, body: bytes) -> Reply:
        """Send one gzip JSON batch; the shore's answer, whatever its status. LinkError when
        there is none."""
        conn = self._connect()
        try:
            conn.putrequest("POST", self._path, skip_accept_encoding=True)
            for name, value in (
                ("Authorization", f"Bearer {self._token}"),
                ("Content-Type", "application/json"),
                ("Content-Encoding", "gzip"),
                ("Accept", "application/json"),
                ("Content-Length", str(len(body))),
                ("Connection", "close"),
            ):
                conn.putheader(name, value)
            conn.endheaders(body)
            response = conn.getresponse()
            raw = response.read(MAX_REPLY_BYTES)
            status = response.status
        except (OSError, http.client.HTTPException) as exc:
            raise LinkError(self._why(exc)) from None
        finally:
            self._release(conn)
        text = raw.decode("utf-8", "replace")
        try:
            parsed = json.loads(text) if text else None
        except ValueError:
            parsed = None
        return Reply(status, parsed, text)

    def abort(self) -> None:
        """End the request in flight, if any, and refuse new ones (the thread is stopping)."""
        with self._lock:
            self._aborted = True
            conn = self._conn
        sock = None if conn is None else conn.sock
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)

    def _connect(self) -> http.client.HTTPConnection:
        conn: http.client.HTTPConnection
        if self._https:
            context = self._context or ssl.create_default_context()
            conn = http.client.HTTPSConnection(
                self._host, self._port, timeout=self.connect_timeout_s, context=context
            )
        else:
            conn = http.client.HTTPConnection(
                self._host, self._port, timeout=self.connect_timeout_s
            )
        with self._lock:
            if self._aborted:
                raise LinkError("stopping")
            self._conn = conn
        try:
            conn.connect()
        except (OSError, http.client.HTTPException) as exc:
            self._release(conn)
            raise LinkError(self._why(exc, connecting=True)) from None
        assert conn.sock is not None
        conn.sock.settimeout(self.read_timeout_s)
        with self._lock:
            aborted = self._aborted
        if aborted:  # abort() ran before the socket existed
            self._release(conn)
            raise LinkError("stopping")
        return conn

    def _release(self, conn: http.client.HTTPConnection) -> None:
        with self._lock:
            if self._conn is conn:
                self._conn = None
        conn.close()

    def _why(self, exc: BaseException, connecting: bool = False) -> str:
        """One line: what failed, where."""
        where = f"{self._host}:{self._port or (443 if self._https else 80)}"
        if self._aborted:
            return "stopping"
        if isinstance(exc, TimeoutError | socket.timeout):
            if connecting:
                return f"no connection to {where} within {self.connect_timeout_s:g} s"
            return f"{where} did not answer within {self.read_timeout_s:g} s"
        if isinstance(exc, ssl.SSLError):
            return f"TLS with {where} failed: {exc.reason or exc}"
        if isinstance(exc, http.client.RemoteDisconnected | ConnectionResetError | BrokenPipeError):
            return f"{where} closed the connection before answering"
        if isinstance(exc, socket.gaierror):
            return f"cannot resolve {self._host}: {exc.strerror or exc}"
        text = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
        return f"{'cannot connect to' if connecting else 'request to'} {where}: {text}"
