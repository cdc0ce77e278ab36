"""Publisher: atomic file, subscribers in order, slow subscribers dropping their oldest items."""

from __future__ import annotations

import json
import os
import queue
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from service.publish import Publisher, payload
from service.store.records import CalibrationRecord

MakeRecord = Callable[..., CalibrationRecord]


def test_file_holds_the_published_object(tmp_path: Path, make_record: MakeRecord) -> None:
    pub = Publisher(tmp_path / "out" / "coefficients.json")  # the folder is created
    record = make_record(version=7)
    obj = pub.publish(record)
    on_disk = json.loads(pub.path.read_text())
    assert on_disk == obj == pub.latest
    assert set(obj) == {"version", "created_at", "coefficients", "status", "uncertainty", "held",
                        "schema", "model", "calibration_temperature_c"}  # fmt: skip
    assert obj["schema"] == "recal.published/1"  # docs/apply.md#the-published-file
    assert obj["model"]["reference_temperature_c"] == record.document["coefficients"]["t0_c"]
    assert obj["model"]["units"]["gyro.bias"] == {"symbol": "b_g", "unit": "deg/h"}
    assert obj["held"] is None  # a document from before jobs recorded what they held
    assert obj["version"] == 7 and obj["created_at"] == record.created_at.isoformat()
    assert obj["coefficients"] == record.document["coefficients"]
    assert obj["uncertainty"] == record.document["uncertainty"]
    assert os.stat(pub.path).st_mode & 0o777 == 0o644
    assert os.listdir(pub.path.parent) == ["coefficients.json"]  # no temporary files left


def test_the_file_carries_what_was_held_at_the_prior(
    tmp_path: Path, make_record: MakeRecord, document: dict
) -> None:
    held = {"gyro.scale.Kz": {"prior": 645.2, "prior_sigma": 0.0645}}
    record = make_record(version=2, document={**document, "held": held})
    obj = Publisher(tmp_path / "c.json").publish(record)
    assert obj["held"] == held and obj["status"] == document["status"]


def test_a_failed_write_keeps_the_old_file(
    tmp_path: Path, make_record: MakeRecord, monkeypatch: pytest.MonkeyPatch
) -> None:
    pub = Publisher(tmp_path / "coefficients.json")
    pub.publish(make_record(version=1))
    before = pub.path.read_bytes()
    sub = pub.subscribe()

    def broken_fsync(fd: int) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", broken_fsync)
    with pytest.raises(OSError, match="No space left"):
        pub.publish(make_record(version=2))
    assert pub.path.read_bytes() == before
    assert os.listdir(tmp_path) == ["coefficients.json"]
    assert sub.get_nowait()["version"] == 1  # a new subscriber first gets the current version
    assert sub.empty()  # nothing announced that is not on disk
    assert pub.latest is not None and pub.latest["version"] == 1


def test_unstored_record_is_refused(make_record: MakeRecord) -> None:
    with pytest.raises(ValueError, match="with a version"):
        payload(make_record())


def test_subscribers_get_every_object_in_order(tmp_path: Path, make_record: MakeRecord) -> None:
    pub = Publisher(tmp_path / "c.json", queue_size=1000)
    subs = [pub.subscribe() for _ in range(3)]
    received: list[int] = []

    def consume() -> None:  # a live consumer while publishing goes on
        while (item := subs[0].get(timeout=5)) is not None:
            received.append(item["version"])

    consumer = threading.Thread(target=consume)
    consumer.start()
    for v in range(1, 101):
        pub.publish(make_record(version=v))
    pub.close()
    consumer.join(5)
    assert received == list(range(1, 101))
    for sub in subs[1:]:
        versions = []
        while (item := sub.get_nowait()) is not None:
            versions.append(item["version"])
        assert versions == list(range(1, 101))
    assert pub.dropped == 0 and pub.subscriber_count == 0


def test_slow_subscriber_drops_oldest_and_never_blocks(
    tmp_path: Path, make_record: MakeRecord
) -> None:
    pub = Publisher(tmp_path / "c.json")
    slow = pub.subscribe(maxsize=2)
    fast = pub.subscribe(maxsize=100)
    started = time.monotonic()
    for v in range(1, 7):
        pub.publish(make_record(version=v))
    assert time.monotonic() - started < 2  # publish never waited for the slow reader
    assert [slow.get_nowait()["version"] for _ in range(2)] == [5, 6]
    assert slow.dropped == 4 and fast.dropped == 0 and pub.dropped == 4
    assert [fast.get_nowait()["version"] for _ in range(6)] == [1, 2, 3, 4, 5, 6]


def test_unsubscribe_and_close(tmp_path: Path, make_record: MakeRecord) -> None:
    pub = Publisher(tmp_path / "c.json")
    gone = pub.subscribe()
    pub.unsubscribe(gone)
    pub.unsubscribe(gone)  # twice is harmless
    pub.publish(make_record(version=1))
    assert gone.empty()
    pub.close()
    late = pub.subscribe()
    assert pub.closed and late.get_nowait() is None
    pub.publish(make_record(version=2))  # the file still follows after close
    assert json.loads(pub.path.read_text())["version"] == 2
    with pytest.raises(queue.Empty):
        late.get_nowait()


def test_sync_makes_the_file_follow_the_database(tmp_path: Path, make_record: MakeRecord) -> None:
    pub = Publisher(tmp_path / "c.json")
    assert pub.sync(None) is False and not pub.path.exists()  # nothing accepted yet
    record = make_record(version=3)
    assert pub.sync(record) is True  # e.g. a crash between commit and write
    assert json.loads(pub.path.read_text())["version"] == 3
    assert pub.sync(record) is False  # already equal: nothing written
    pub.path.write_text("{}")  # edited by hand, or truncated
    assert pub.sync(record) is True
    assert json.loads(pub.path.read_text())["version"] == 3
    pub.path.unlink()
    assert pub.sync(record) is True and pub.path.exists()


def test_a_failing_sync_is_recorded_and_retried(tmp_path: Path, make_record: MakeRecord) -> None:
    pub = Publisher(tmp_path / "c.json")
    pub.path.mkdir()  # the write cannot replace a directory
    assert pub.sync(make_record(version=1)) is False
    assert pub.error is not None and "cannot write" in pub.error
    pub.path.rmdir()
    assert pub.sync(make_record(version=1)) is True and pub.error is None


def test_new_subscribers_first_get_the_current_version(
    tmp_path: Path, make_record: MakeRecord
) -> None:
    pub = Publisher(tmp_path / "c.json")
    pub.publish(make_record(version=4))
    sub = pub.subscribe()
    assert sub.get_nowait()["version"] == 4
    pub.publish(make_record(version=4))  # rewritten, same version: not news
    assert sub.empty()
    assert pub.subscribe(current=False).empty()


@pytest.mark.parametrize("bad", ["dir", "under_file"])
def test_unusable_publish_path_is_one_line_at_start(tmp_path: Path, bad: str) -> None:
    from recal.errors import RecalInputError

    (tmp_path / "file").write_text("x")
    path = tmp_path if bad == "dir" else tmp_path / "file" / "c.json"
    with pytest.raises(RecalInputError, match="publish_path"):
        Publisher(path)
