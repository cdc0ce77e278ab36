"""The durable spool (service/spool.py) under Ingest: a detected window is on disk before it
counts, survives a restart and is replayed in order, is never stored twice, waits on disk (not
in memory) while the database refuses it, and a full disk loses nothing already detected.

The database refuses writes for real: a SQLite file opened read-only (``mode=ro``; permission
bits would not stop root), or a PostgreSQL database closed to connections. The full disk is a
tiny tmpfs when this machine lets the test mount one.
"""

from __future__ import annotations

import errno
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from recal.detect.slew_collect import ReducedSlew
from recal.detect.static_config import DetectorConfig
from service.config import DetectorSettings, DeviceSettings, SchedulerSettings, Settings
from service.daemon import build_service
from service.events import Events
from service.pipeline import Ingest
from service.spool import (
    FORMAT,
    Spool,
    SpoolEntry,
    SpoolWriteError,
    default_spool_dir,
    read_entry,
)
from service.store.repository import Store

RATE = 100.0
CONFIG = DetectorConfig(accel_threshold=1e-6, gyro_threshold=1e4, sample_rate_hz=RATE)


def feed(ingest: Ingest, batch, part: slice = slice(None)) -> None:
    """Frames ``part`` in 1 s batches, as the reader hands them over."""
    batch = batch[part]
    for lo in range(0, len(batch), int(RATE)):
        ingest.feed(batch[lo : lo + int(RATE)])


def database(path: Path) -> tuple[Store, Store, int]:
    """A SQLite database with one session: a writable Store and one that refuses writes."""
    store = Store(f"sqlite:///{path}")
    store.create_schema()
    session = store.add_session("replay://unit")
    return store, Store(f"sqlite:///file:{path}?mode=ro&uri=true"), session


def reference(tmp_path: Path, frames) -> tuple[np.ndarray, int]:
    """What an Ingest with a working database stores from every frame, without a flush (the
    last window stays open): window starts, and slews."""
    store, _, session = database(tmp_path / "reference.db")
    ingest = Ingest(store, session, CONFIG)
    feed(ingest, frames)
    positions, ids = store.positions(session_id=session)
    out = positions.columns["start_s"], len(store.slews(ids))
    store.close()
    return out


def reduced(seed: int, dropped: str | None = None) -> ReducedSlew:
    rng = np.random.default_rng(seed)
    if dropped is not None:
        return ReducedSlew(None, None, rng.normal(size=3), 0, None, dropped)
    groups = (rng.integers(1, 9, 4), rng.normal(size=(4, 3)), rng.normal(size=(4, 3)),
              rng.normal(size=(4, 3)))  # fmt: skip
    return ReducedSlew(None, None, rng.normal(size=3), 400, groups, None)


# ---- the spool files ------------------------------------------------------------------------


def test_an_entry_comes_back_exactly_in_order_without_pickle(tmp_path: Path) -> None:
    spool = Spool(tmp_path / "spool")
    cols = {"start_s": np.array([1.0, 20.5]), "gyro_x": np.array([-0.0, np.nan])}
    first = SpoolEntry(7, cols, [(-1, 0, reduced(1)), (0, 1, reduced(2, "too_long"))], "k0",
                       0.01)  # fmt: skip
    second = SpoolEntry(7, {"start_s": np.array([40.0])}, [], first.key, 0.01)
    spool.append(first)
    spool.append(second)
    assert first.path.exists() and not list(spool.directory.glob(".tmp-*"))
    # a crash while writing leaves a temporary file: never counted, removed at the next start
    (spool.directory / ".tmp-000000000003.dead.npz").write_bytes(b"half")
    again = Spool(spool.directory)  # a restart
    got = again.load()
    assert [e.key for e in got] == [first.key, second.key]
    assert not list(spool.directory.glob(".tmp-*"))
    a = got[0]
    assert (a.session_id, a.previous_key, a.period_s) == (7, "k0", 0.01)
    assert a.columns["start_s"].tolist() == [1.0, 20.5]
    assert np.signbit(a.columns["gyro_x"][0]) and np.isnan(a.columns["gyro_x"][1])
    (r0a, r0b, r0), (r1a, r1b, r1) = a.slews
    assert (r0a, r0b, r1a, r1b) == (-1, 0, 0, 1)
    for got_part, want_part in zip(r0.groups, reduced(1).groups, strict=True):
        np.testing.assert_array_equal(got_part, want_part)
    assert (r0.samples, r0.dropped, r1.groups, r1.dropped) == (400, None, None, "too_long")
    with np.load(a.path, allow_pickle=False) as z:  # plain arrays only, a versioned header
        assert b'"format": %d' % FORMAT in z["header"].tobytes()
    # new entries go after the old ones, and a removed entry is gone for good
    third = SpoolEntry(7, {"start_s": np.array([60.0])})
    again.append(third)
    again.remove(got[0])
    assert [e.key for e in Spool(spool.directory).load()] == [second.key, third.key]
    assert read_entry(third.path).columns["start_s"].tolist() == [60.0]


def test_a_failed_write_names_the_folder_and_leaves_nothing(tmp_path, monkeypatch) -> None:
    spool = Spool(tmp_path / "spool")

    def full(fd: int, data: bytes) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr("service.spool.os.write", full)
    entry = SpoolEntry(1, {"start_s": np.array([1.0])})
    with pytest.raises(SpoolWriteError) as e:
        spool.append(entry)
    assert str(spool.directory) in str(e.value) and "ENOSPC" in str(e.value)
    assert entry.path is None and list(spool.directory.iterdir()) == []


def test_the_spool_folder_is_made_or_refused_clearly(tmp_path: Path) -> None:
    deep = tmp_path / "a" / "b" / "spool"
    Spool(deep)
    assert deep.is_dir()
    (tmp_path / "file").write_text("x")
    from recal.errors import RecalInputError

    with pytest.raises(RecalInputError, match="spool_dir .*file.* cannot be created"):
        Spool(tmp_path / "file" / "spool")
    state = tmp_path / "state"
    db = f"sqlite:///{tmp_path}/recal.db"
    assert default_spool_dir(db, state) == tmp_path / "recal.db.spool"
    assert default_spool_dir("sqlite://", state) is None  # in memory: a restart loses it all
    pg = default_spool_dir("postgresql+psycopg://u:secret@db.local:5433/recal", state)
    # one per database, no secret, under the state folder (never the working folder)
    assert pg == state / "spool" / "db.local_5433_recal"


# ---- through Ingest ---------------------------------------------------------------------------


def test_spooled_windows_survive_a_restart_and_are_replayed_in_order(tmp_path, frames) -> None:
    want, want_slews = reference(tmp_path, frames)
    store, refusing, session = database(tmp_path / "r.db")
    spool = Spool(tmp_path / "spool")
    first = Ingest(refusing, session, CONFIG, spool=spool)
    feed(first, frames)
    # every closed window is on disk, none in memory, none stored; the last one is still open
    assert first.windows == 0 and first.store_error is not None
    assert first.detected == len(want) == first.spooled
    assert (
        first.windows_in_memory == 0 and first.spool_health()["windows_on_disk"] == first.detected
    )
    assert len(spool) == first.spool_health()["batches_on_disk"] > 1
    del first  # kill -9: nothing more runs in that process

    # the restart: a new session; the old windows go in first, in order, then the new ones
    session2 = store.add_session("replay://unit")
    stored = []
    second = Ingest(store, session2, CONFIG, lambda ids: stored.append(ids),
                    spool=Spool(tmp_path / "spool"))  # fmt: skip
    replayed = second.replay()
    assert len(replayed) == len(want) == second.replayed and second.spooled == 0
    assert len(spool) == 0
    positions, ids = store.positions(session_id=session)
    np.testing.assert_array_equal(positions.columns["start_s"], want)
    assert ids == sorted(ids) == replayed
    # the slews between replayed batches were chained by key: none missing
    assert len(store.slews(ids)) == want_slews
    feed(second, frames[:3000])
    second.flush()
    assert min(store.positions(session_id=session2)[1]) > max(ids)
    assert stored[0] == replayed
    store.close()


def test_a_kill_between_commit_and_delete_stores_nothing_twice(tmp_path, frames) -> None:
    store, refusing, session = database(tmp_path / "r.db")
    spool = Spool(tmp_path / "spool")
    first = Ingest(refusing, session, CONFIG, spool=spool)
    feed(first, frames)
    entries = Spool(tmp_path / "spool").load()
    # the database committed the first two batches, then the process died before deleting them
    for entry in entries[:2]:
        store.add_positions(entry.session_id, entry.columns, [], None, spool_key=entry.key)
    committed = store.count_positions(session)
    assert committed > 0 and len(spool) == len(entries)
    second = Ingest(store, store.add_session("replay://unit"), CONFIG, spool=spool)
    second.replay()
    assert len(spool) == 0
    positions, _ = store.positions(session_id=session)
    starts = positions.columns["start_s"]
    assert len(starts) == first.detected and len(np.unique(starts)) == len(starts)
    assert second.replayed == first.detected - committed
    # and the Store itself refuses a key twice, in the same transaction
    again = store.add_positions(session, entries[0].columns, [], None, spool_key=entries[0].key)
    assert again == store.keyed_positions(entries[0].key) and store.count_positions(session) == len(
        starts
    )
    store.close()


def _tiny_tmpfs(path: Path) -> bool:
    path.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=16k", "tmpfs", str(path)],
                          capture_output=True)  # fmt: skip
    return done.returncode == 0


@pytest.fixture
def full_folder(tmp_path: Path):
    """A folder on a filesystem with no space left (a 16 kB tmpfs, filled)."""
    path = tmp_path / "full"
    if not _tiny_tmpfs(path):
        pytest.skip("cannot mount a tmpfs here (not root?)")
    try:
        fd = os.open(path / "filler", os.O_WRONLY | os.O_CREAT)
        try:
            while True:
                os.write(fd, b"\0" * 4096)
        except OSError as exc:
            assert exc.errno == errno.ENOSPC
        finally:
            os.close(fd)
        yield path
    finally:
        subprocess.run(["umount", str(path)], check=False)


def test_a_full_disk_is_said_clearly_and_loses_nothing(tmp_path, frames, full_folder) -> None:
    want, _ = reference(tmp_path, frames)
    store, refusing, session = database(tmp_path / "r.db")
    events = Events(store)
    ingest = Ingest(store, session, CONFIG, events=events, spool=Spool(full_folder))
    ingest.replay()  # at start: the full folder is said before any window needs it
    assert ingest.spool_error is not None and ingest.detected == 0
    half = len(frames) // 2
    feed(ingest, frames, slice(0, half))
    # the database is up: each window went straight to it
    assert ingest.spool_error is not None and "ENOSPC" in ingest.spool_error
    assert str(full_folder) in ingest.spool_error
    assert ingest.windows == ingest.detected > 0 and ingest.spooled == 0
    event = store.last_event("spool")
    assert (
        event is not None and "ENOSPC" in event["message"] and str(full_folder) in event["message"]
    )
    store.close()

    # the database refuses too: held in memory, counted, nothing dropped
    other = Ingest(refusing, session, CONFIG, spool=Spool(full_folder))
    feed(other, frames, slice(half, None))
    other.flush()
    # (not durable yet, so not counted as detected: a kill now would lose them, and /health says so)
    assert other.windows_in_memory == other.spooled > 0 and other.detected == 0
    assert other.windows_dropped == 0
    health = other.spool_health()
    assert health["windows_in_memory"] == other.spooled and health["dir"] == str(full_folder)


# ---- the daemon, its database refused (PostgreSQL closed to connections) -------------------------


def test_a_kill_during_a_database_outage_loses_no_detected_window(
    tmp_path, frames, pg_database, block_database
) -> None:
    name, url = pg_database
    settings = Settings(
        database_url=url,
        publish_path=str(tmp_path / "c.json"),
        spool_dir=str(tmp_path / "spool"),
        device=DeviceSettings(url="replay://unit", rate_hz=RATE),
        detector=DetectorSettings(accel_threshold=1e-6, gyro_threshold=1e4),
        scheduler=SchedulerSettings(min_positions=1000, min_new_positions=1000),
    )
    service = build_service(settings, with_reader=False)
    half = len(frames) // 2
    feed(service.ingest, frames, slice(0, half))
    before = service.store.count_positions()
    assert before > 3
    block_database(name, allow=False)
    feed(service.ingest, frames, slice(half, None))
    waiting = service.ingest.spooled
    assert waiting > 0 and service.ingest.windows_in_memory == 0  # on disk, not in memory
    health = service.health()
    assert health["spool"]["windows_on_disk"] == waiting
    assert health["spool"]["dir"] == str(tmp_path / "spool") and health["status"] == "degraded"
    detected = service.ingest.detected
    # kill -9: no flush, no store; what was open is lost, what was detected is on disk
    service.scheduler.shutdown(wait_s=0)
    service.store.close()
    block_database(name, allow=True)
    restarted = build_service(settings, with_reader=False)
    try:
        assert restarted.ingest.replayed == waiting and restarted.ingest.spooled == 0
        assert restarted.store.count_positions(service.session_id) == detected == before + waiting
        assert not list((tmp_path / "spool").iterdir())
    finally:
        restarted.close(wait_s=0)
