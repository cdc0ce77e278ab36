"""Fleet sync, the vessel side (docs/fleet.md): a real Store and a real HTTP shore (the
``shore`` fixture, tests/service/conftest.py): every row arrives once; a failing or refusing
shore leaves the outbox as it was and /health says why; a lost acknowledgement is sent again
and stores nothing twice; a backlog drains batch after batch; stopping never waits on a dead
link."""

from __future__ import annotations

import time
from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from recal.detect.slew_collect import ReducedSlew
from recal.model.coefficients import CoefficientSet
from recal.sim.simulate import simulate_positions
from service.api import create_app
from service.events import Events
from service.publish import Publisher
from service.store.records import CalibrationRecord
from service.store.repository import Store
from service.sync import SyncThread

FAST = {"backoff_base_s": 0.05, "backoff_cap_s": 0.2, "connect_timeout_s": 2.0,
        "read_timeout_s": 5.0}  # fmt: skip


def reduced(seed: int) -> ReducedSlew:
    rng = np.random.default_rng(seed)
    groups = (rng.integers(1, 9, 4), rng.normal(size=(4, 3)), rng.normal(size=(4, 3)),
              rng.normal(size=(4, 3)))  # fmt: skip
    return ReducedSlew(None, None, rng.normal(size=3), 400, groups, None)


def history(store: Store, make_record: Callable[..., CalibrationRecord], windows: int = 12
            ) -> set[tuple[str, int]]:  # fmt: skip
    """A vessel's history: a session, windows with slews between them, an accepted and a
    rejected version, events. Returns every (kind, id) stored."""
    sid = store.add_session("replay:///capture.bin", {"rate_hz": 1000.0})
    table = simulate_positions(CoefficientSet.seed_truth(), "random", n_positions=windows, seed=1)
    slews = [(i, i + 1, reduced(i)) for i in range(windows - 1)]
    ids = store.add_positions(sid, dict(table.columns), slews, 0.001)
    v1 = store.add_calibration(make_record(positions_used=ids))
    v2 = store.add_calibration(make_record(accepted=False, reasons=["chi2_red 9.1 > 4"],
                                           prior_version=v1))  # fmt: skip
    events = [store.add_event("start", "service started", {"session": sid}),
              store.add_event("reader_error", "no frame for 2 s")]  # fmt: skip
    return ({("session", sid), ("version", v1), ("version", v2)} | {("window", i) for i in ids}
            | {("slew", i) for i in range(1, windows)} | {("event", e) for e in events})  # fmt: skip


def client(store: Store, shore: Any, **kw: Any) -> SyncThread:
    args = FAST | {"interval_s": 60.0} | kw
    interval = args.pop("interval_s")
    return SyncThread(store, shore.url, shore.unit, shore.token, interval, **args)


def wait_for(predicate: Callable[[], Any], timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


def health_of(store: Store, thread: SyncThread | None, tmp_path: Any) -> dict[str, Any]:
    """The vessel API's /health with this sync thread."""
    parts = None if thread is None else (lambda: {"sync": thread.health(store.outbox_count())})
    app = create_app(store, Publisher(tmp_path / "coefficients.json"), health=parts)
    with TestClient(app) as http:
        return http.get("/health").json()


def test_every_row_arrives_exactly_once_in_the_wire_format(
    store: Store, shore: Any, make_record: Callable[..., CalibrationRecord], tmp_path: Any
) -> None:
    sent = history(store, make_record)
    thread = client(store, shore, max_rows=7)  # several batches
    thread.start()
    try:
        wait_for(lambda: store.outbox_count() == 0)
    finally:
        assert thread.stop()
    stored = shore.rows()
    assert {(k, i) for k, i, _ in stored} == sent
    assert all(r["status"] == 200 for r in shore.requests)
    assert sum(r["rows"] for r in shore.requests) == len(sent)  # none sent twice
    assert [r["rows"] for r in shore.requests] == [7, 7, 7, 7]  # 28 rows

    by_key = {(k, i): d for k, i, d in stored}
    app = create_app(store, Publisher(tmp_path / "coefficients.json"))
    with TestClient(app) as http:  # a version is the vessel's own GET /coefficients/{version}
        for version in (i for k, i in sent if k == "version"):
            assert by_key["version", version] == http.get(f"/coefficients/{version}").json()
    table, ids = store.positions()
    window = by_key["window", ids[3]]
    assert window["session"] == 1 and window["gyro_x"] == table.columns["gyro_x"][3]
    slew = by_key["slew", 2]
    assert (slew["first_id"], slew["second_id"], slew["dropped"]) == (ids[1], ids[2], None)
    np.testing.assert_array_equal(slew["groups"]["S"], reduced(1).groups[1])
    assert by_key["event", 1] | {"created_at": None} == {
        "kind": "start", "message": "service started", "data": {"session": 1},
        "created_at": None}  # fmt: skip
    assert by_key["session", 1]["meta"] == {"rate_hz": 1000.0}

    sync = health_of(store, thread, tmp_path)["sync"]
    assert sync["state"] == "up" and sync["backlog"] == 0 and sync["last_error"] is None
    assert sync["unit"] == shore.unit and sync["url"] == shore.url
    assert sync["last_contact"].endswith("Z") and sync["bytes_today"] > 0
    assert [d["day"] for d in sync["bytes_per_day"]][-1] == datetime.now(UTC).date().isoformat()
    assert sync["bytes_per_day"][-1]["rows"] == len(sent)


def test_a_failing_shore_leaves_the_outbox_and_health_says_down(
    sqlite_store: Store, shore: Any, make_record: Callable[..., CalibrationRecord], tmp_path: Any
) -> None:
    sent = history(sqlite_store, make_record, windows=4)
    shore.mode = "fail"
    thread = client(sqlite_store, shore, events=Events(sqlite_store))
    thread.start()
    try:
        wait_for(lambda: len(shore.requests) >= 3)  # backed off and tried again
        waiting = len(sent) + 1  # and the "down" event
        assert sqlite_store.outbox_count() == waiting and shore.rows() == []
        health = health_of(sqlite_store, thread, tmp_path)
        assert health["status"] == "ok"  # a link down at sea is no fault of the unit
        sync = health["sync"]
        assert sync["state"] == "down" and sync["backlog"] == waiting
        assert "500" in sync["last_error"] and "database unavailable" in sync["last_error"]
        assert sync["bytes_today"] > 0  # the attempts used the link too

        shore.mode = "ok"  # the shore is back: the backlog goes at the next try
        # then the "up" event the link stored, at once (not after interval_s)
        wait_for(lambda: len(shore.rows()) == len(sent) + 2)
        assert thread.health()["state"] == "up" and thread.health()["last_error"] is None
    finally:
        assert thread.stop()
    assert sqlite_store.outbox_count() == 0
    events = [
        (e["id"], e["data"]["state"]) for e in sqlite_store.events(100) if e["kind"] == "sync"
    ]
    assert [state for _, state in events] == ["up", "down"]  # per change, not per retry
    assert {(k, i) for k, i, _ in shore.rows()} == sent | {("event", i) for i, _ in events}


def test_no_shore_listening_is_down_with_the_reason(sqlite_store: Store, shore: Any) -> None:
    sqlite_store.add_session("s")
    url = shore.url
    shore.close()  # nothing listens there any more
    thread = SyncThread(sqlite_store, url, shore.unit, shore.token, **FAST)
    thread.start()
    try:
        wait_for(lambda: thread.health()["last_error"] is not None)
        sync = thread.health()
        assert sync["state"] == "down" and "cannot connect to 127.0.0.1" in sync["last_error"]
        assert sqlite_store.outbox_count() == 1
    finally:
        assert thread.stop()


@pytest.mark.parametrize(
    "trouble, words",
    [
        ("token", ["401", "check [sync] token"]),
        ("unit", ["403", "not for unit OTHER-UNIT", "check [sync] unit"]),
        ("row", ["422", "rows[1] (window 1): not storable"]),
    ],
)
def test_a_refusal_is_not_retried_blindly_and_says_why(
    sqlite_store: Store, shore: Any, tmp_path: Any, trouble: str, words: list[str]
) -> None:
    sid = sqlite_store.add_session("s")
    sqlite_store.add_positions(sid, dict(simulate_positions(CoefficientSet.seed_truth(),
                                                            seed=1).columns))  # fmt: skip
    before = sqlite_store.outbox_count()
    token, unit = shore.token, shore.unit
    if trouble == "token":
        token = "another-token-0123456789"
    elif trouble == "unit":
        unit = "OTHER-UNIT"
    else:
        shore.bad_rows = {("window", 1)}
    thread = SyncThread(sqlite_store, shore.url, unit, token, **FAST)
    thread.start()
    try:
        wait_for(lambda: thread.health()["state"] == "rejected")
        time.sleep(0.5)  # ten back-offs' worth: a refusal is not retried at that pace
        assert len(shore.requests) == 1 and shore.rows() == []
        assert sqlite_store.outbox_count() == before
        health = health_of(sqlite_store, thread, tmp_path)
    finally:
        assert thread.stop()
    error = health["sync"]["last_error"]
    assert all(w in error for w in words), error
    assert health["sync"]["last_contact"] is not None  # the shore did answer


def test_a_lost_acknowledgement_is_sent_again_and_stored_once(
    sqlite_store: Store, shore: Any, make_record: Callable[..., CalibrationRecord]
) -> None:
    sent = history(sqlite_store, make_record, windows=6)
    shore.mode = "lose_ack"  # commits the batch, then drops the connection unanswered
    thread = client(sqlite_store, shore)
    thread.start()
    try:
        wait_for(lambda: sqlite_store.outbox_count() == 0)
    finally:
        assert thread.stop()
    lost, again = shore.requests
    assert (lost["status"], lost["rows"]) == ("lost", len(sent))
    assert again["status"] == 200 and again["body"] == {"stored": 0, "duplicates": len(sent)}
    assert len(shore.rows()) == len(sent)


def test_a_backlog_drains_in_successive_batches_without_waiting(
    sqlite_store: Store, shore: Any
) -> None:
    sid = sqlite_store.add_session("s")
    truth = CoefficientSet.seed_truth()
    for seed in range(5):  # 1200 windows
        table = simulate_positions(truth, "random", n_positions=240, seed=seed)
        sqlite_store.add_positions(sid, dict(table.columns))
    thread = client(sqlite_store, shore, interval_s=600.0, max_json_bytes=128 * 1024)
    thread.start()
    try:
        wait_for(lambda: sqlite_store.outbox_count() == 0, timeout_s=30)  # not 600 s apart
    finally:
        assert thread.stop()
    sizes = [r["rows"] for r in shore.requests]
    assert sum(sizes) == 1201 and all(r["status"] == 200 for r in shore.requests)
    assert len(sizes) >= 6  # 128 KiB of JSON is ~200 windows, fewer than 500 rows
    assert all(r["json_bytes"] <= 128 * 1024 for r in shore.requests)
    assert [i for _, i, _ in shore.rows("window")] == list(range(1, 1201))


def test_a_batch_too_large_for_the_shore_is_halved(sqlite_store: Store, shore: Any) -> None:
    sid = sqlite_store.add_session("s")
    table = simulate_positions(CoefficientSet.seed_truth(), "random", n_positions=60, seed=3)
    sqlite_store.add_positions(sid, dict(table.columns))
    shore.max_json_bytes = 12_000
    thread = client(sqlite_store, shore)
    thread.start()
    try:
        wait_for(lambda: sqlite_store.outbox_count() == 0)
    finally:
        assert thread.stop()
    assert shore.requests[0]["status"] == 413
    assert len(shore.rows()) == 61 and thread.max_rows < 61


def test_stopping_does_not_wait_on_a_dead_link(sqlite_store: Store, shore: Any) -> None:
    sqlite_store.add_session("s")
    shore.mode = "hang"  # accepts the request and never answers
    thread = client(sqlite_store, shore, read_timeout_s=30.0)
    thread.start()
    wait_for(lambda: len(shore.requests) == 1)
    time.sleep(0.1)  # the request is in flight, waiting for its answer
    started = time.monotonic()
    assert thread.stop(wait_s=5.0)
    assert time.monotonic() - started < 1.0
    assert sqlite_store.outbox_count() == 1


def test_a_shore_that_never_answers_times_out(sqlite_store: Store, shore: Any) -> None:
    sqlite_store.add_session("s")
    shore.mode = "hang"
    thread = client(sqlite_store, shore, read_timeout_s=0.3)
    thread.start()
    try:
        wait_for(lambda: thread.health()["last_error"] is not None, timeout_s=5)
    finally:
        assert thread.stop()
    assert "did not answer within 0.3 s" in thread.health()["last_error"]


def test_the_link_traffic_survives_a_restart(sqlite_store: Store, shore: Any) -> None:
    sqlite_store.add_session("s")
    first = client(sqlite_store, shore)
    first.start()
    try:
        wait_for(lambda: sqlite_store.outbox_count() == 0)
    finally:
        assert first.stop()
    before = first.health()
    again = client(sqlite_store, shore)
    again.stats.load(sqlite_store)  # what the thread does first
    after = again.health()
    assert after["bytes_today"] == before["bytes_today"] > 0
    assert after["bytes_per_day"] == before["bytes_per_day"] and len(after["bytes_per_day"]) == 7
    assert after["last_contact"] == before["last_contact"]
    assert after["state"] == "down"  # until the shore answers this run


def test_without_sync_health_says_off_with_the_backlog(sqlite_store: Store, tmp_path: Any) -> None:
    sqlite_store.add_session("s")
    sync = health_of(sqlite_store, None, tmp_path)["sync"]
    assert sync == {"state": "off", "url": None, "unit": None, "backlog": 1,
                    "last_contact": None, "last_error": None, "bytes_today": 0,
                    "bytes_per_day": []}  # fmt: skip
