"""The durable spool: detected windows on disk until the database has committed them.

A batch of windows (one detector call) is one file, ``<seq>.<key>.npz``: the positions columns
and the slews' arrays, plus a small JSON header (format version, key, session, slew fields),
no pickled objects. It is written to a temporary name, fsync'd, renamed into place and the
directory fsync'd, so after a crash a file is either whole or absent (a leftover temporary file
is a batch that never counted as detected). Files are read back in sequence order; one is
deleted only after the database committed its windows, and the key stored with them makes a
replay of a file whose delete was lost (a kill between commit and delete) a no-op.
"""

from __future__ import annotations

import errno
import io
import json
import os
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from recal.detect.slew_collect import ReducedSlew
from recal.errors import RecalInputError

#: Version of the file layout; a file of another version is left alone (and reported).
FORMAT = 1
SUFFIX = ".npz"
TMP_PREFIX = ".tmp-"


class SpoolWriteError(OSError):
    """A batch could not be made durable; ``str()`` names the directory and the cause."""


@dataclass
class SpoolEntry:
    """One detector call's windows (see ``service.pipeline``), as spooled.

    ``slews``: (first row, second row, ReducedSlew), row -1 being the last window of the batch
    ``previous_key`` (the session's batch before; its slew is skipped when that batch was
    never stored); ``period_s``: the gyro sample period of the slews (None before the frame
    rate was known); ``key``: unique, stored with the positions (``spool_batches``).
    """

    session_id: int
    columns: dict[str, np.ndarray]
    slews: list[tuple[int, int, Any]] = field(default_factory=list)
    previous_key: str | None = None  # the session's batch before this one (row -1's)
    period_s: float | None = None
    key: str = field(default_factory=lambda: uuid.uuid4().hex)
    path: Path | None = None  # its file once durable

    @property
    def size(self) -> int:
        """Windows in the batch."""
        return len(next(iter(self.columns.values()))) if self.columns else 0


def describe_os_error(exc: OSError) -> str:
    """``ENOSPC: No space left on device``-style one-line cause."""
    name = errno.errorcode.get(exc.errno or 0, "error")
    return f"{name}: {exc.strerror or exc}"


class Spool:
    """The spool directory. :meth:`append` makes an entry durable; :meth:`load` reads them all
    in order; :meth:`remove` deletes one. Not thread-safe (the Ingest lock covers it)."""

    def __init__(self, directory: str | os.PathLike[str]) -> None:
        self.directory = Path(directory)
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise RecalInputError(
                f"spool_dir {self.directory} cannot be created ({describe_os_error(exc)}): "
                "set spool_dir to a writable folder"
            ) from None
        if not self.directory.is_dir():
            raise RecalInputError(f"spool_dir {self.directory} is not a folder")
        self._seq = max((_seq_of(p) for p in self._files()), default=0)
        self.unreadable: list[str] = []  # files load() could not read (kept, renamed .bad)

    def _files(self) -> list[Path]:
        return sorted((p for p in self.directory.glob(f"*{SUFFIX}") if _seq_of(p) > 0), key=_seq_of)

    def __len__(self) -> int:
        return len(self._files())

    def append(self, entry: SpoolEntry) -> Path:
        """Write ``entry`` durably (temporary file, fsync, rename, directory fsync); sets and
        returns ``entry.path``. Raises :class:`SpoolWriteError` (nothing left behind)."""
        self._seq += 1
        name = f"{self._seq:012d}.{entry.key}{SUFFIX}"
        tmp = self.directory / f"{TMP_PREFIX}{name}"
        data = _encode(entry)
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            try:
                view = memoryview(data)
                while view:
                    view = view[os.write(fd, view) :]
                os.fsync(fd)
            finally:
                os.close(fd)
            os.replace(tmp, self.directory / name)
            _fsync_dir(self.directory)
        except OSError as exc:
            self._seq -= 1
            tmp.unlink(missing_ok=True)
            err = SpoolWriteError(f"spool {self.directory}: cannot write a window batch "
                                  f"({describe_os_error(exc)})")  # fmt: skip
            err.errno = exc.errno
            raise err from exc
        entry.path = self.directory / name
        return entry.path

    def probe(self) -> None:
        """Write, fsync and delete one byte (at start: a full or read-only folder is reported
        before the first window needs it). Raises :class:`SpoolWriteError`."""
        path = self.directory / f"{TMP_PREFIX}probe"
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
            try:
                os.write(fd, b"\0")
                os.fsync(fd)
            finally:
                os.close(fd)
        except OSError as exc:
            err = SpoolWriteError(f"spool {self.directory}: cannot write a window batch "
                                  f"({describe_os_error(exc)})")  # fmt: skip
            err.errno = exc.errno
            raise err from exc
        finally:
            path.unlink(missing_ok=True)

    def load(self) -> list[SpoolEntry]:
        """Every durable entry, oldest first. Leftover temporary files (a crash while writing:
        never counted as detected) are removed; an unreadable file is renamed ``*.bad`` and
        listed in :attr:`unreadable`."""
        for tmp in self.directory.glob(f"{TMP_PREFIX}*"):
            tmp.unlink(missing_ok=True)
        out = []
        for path in self._files():
            try:
                out.append(read_entry(path))
            except (OSError, ValueError, KeyError) as exc:
                self.unreadable.append(f"{path.name}: {exc}")
                path.rename(path.with_suffix(".bad"))
        return out

    def remove(self, entry: SpoolEntry) -> None:
        """Delete a committed entry's file (a failure leaves it for a no-op replay)."""
        if entry.path is not None:
            entry.path.unlink(missing_ok=True)
            entry.path = None


def _seq_of(path: Path) -> int:
    head = path.name.split(".", 1)[0]
    return int(head) if head.isdigit() else 0


def _fsync_dir(directory: Path) -> None:
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _encode(entry: SpoolEntry) -> bytes:
    """The entry as npz bytes: arrays by name, the rest in a JSON header."""
    arrays: dict[str, np.ndarray] = {}
    slews = []
    for i, (a, b, r) in enumerate(entry.slews):
        slews.append({"first": int(a), "second": int(b), "samples": int(r.samples),
                      "dropped": r.dropped, "reference": r.reference is not None,
                      "groups": r.groups is not None})  # fmt: skip
        if r.reference is not None:
            arrays[f"s{i}_reference"] = np.asarray(r.reference, np.float64)
        if r.groups is not None:
            for part, value in zip("nSWC", r.groups, strict=True):
                arrays[f"s{i}_{part}"] = np.asarray(value)
    for name, col in entry.columns.items():
        arrays[f"c_{name}"] = np.asarray(col)
    header = {"format": FORMAT, "key": entry.key, "session_id": int(entry.session_id),
              "previous_key": entry.previous_key, "period_s": entry.period_s,
              "columns": list(entry.columns), "slews": slews}  # fmt: skip
    arrays["header"] = np.frombuffer(json.dumps(header).encode(), np.uint8)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def read_entry(path: Path) -> SpoolEntry:
    """One spool file back as an entry (ValueError if it is not one this code can read)."""
    with np.load(path, allow_pickle=False) as z:
        header = json.loads(z["header"].tobytes().decode())
        if header.get("format") != FORMAT:
            raise ValueError(f"spool format {header.get('format')!r}, this code reads {FORMAT}")
        columns = {name: z[f"c_{name}"] for name in header["columns"]}
        slews = []
        for i, s in enumerate(header["slews"]):
            ref = z[f"s{i}_reference"] if s["reference"] else None
            groups = tuple(z[f"s{i}_{p}"] for p in "nSWC") if s["groups"] else None
            r = ReducedSlew(None, None, ref, s["samples"], groups, s["dropped"])
            slews.append((s["first"], s["second"], r))
    return SpoolEntry(header["session_id"], columns, slews, header["previous_key"],
                      header["period_s"], header["key"], path)  # fmt: skip


def default_spool_dir(database_url: str, state_dir: str | os.PathLike[str]) -> Path | None:
    """Where the spool lives when ``spool_dir`` is unset: ``FILE.spool`` beside a SQLite
    database ``FILE``; for a database server ``STATE_DIR/spool/HOST_PORT_DB`` (the daemon's
    state folder, never the working folder), one folder per database so a spool is never
    replayed into another; None (no spool) for an in-memory SQLite database, which a restart
    loses anyway."""
    import re

    from sqlalchemy.engine import make_url

    try:
        url = make_url(database_url)
    except Exception:  # noqa: BLE001 - the Store reports a bad URL
        return None
    if url.get_backend_name() == "sqlite":
        db = url.database
        return None if db in (None, "", ":memory:") else Path(f"{db}.spool")
    name = re.sub(r"[^A-Za-z0-9.-]+", "_", f"{url.host}_{url.port or ''}_{url.database}")
    return Path(state_dir) / "spool" / name
