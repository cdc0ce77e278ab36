"""The outbox (fleet sync, docs/fleet.md): every Store write of a session, a window, a slew, a
calibration version or an event adds its outbox row in the same transaction, and only then."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from recal.detect.slew_collect import ReducedSlew
from recal.model.coefficients import CoefficientSet
from recal.sim.simulate import simulate_positions
from service.store.errors import StoreError, UnknownSessionError
from service.store.records import CalibrationRecord
from service.store.repository import Store


def reduced(seed: int) -> ReducedSlew:
    rng = np.random.default_rng(seed)
    groups = (rng.integers(1, 9, 4), rng.normal(size=(4, 3)), rng.normal(size=(4, 3)),
              rng.normal(size=(4, 3)))  # fmt: skip
    return ReducedSlew(None, None, rng.normal(size=3), 400, groups, None)


def columns(n: int, seed: int = 1) -> dict[str, Any]:
    table = simulate_positions(CoefficientSet.seed_truth(), "random", n_positions=n, seed=seed)
    return dict(table.columns)


def keys(store: Store) -> list[tuple[str, int]]:
    return [(e.kind, e.ref_id) for e in store.outbox(100_000)]


def test_every_write_adds_its_outbox_rows_in_order(
    store: Store, make_record: Callable[..., CalibrationRecord]
) -> None:
    sid = store.add_session("replay:///x.bin", {"rate_hz": 1000.0})
    ids = store.add_positions(sid, columns(3), [(0, 1, reduced(1)), (1, 2, reduced(2))], 0.001)
    more = store.add_positions(sid, columns(1, seed=2), [(-1, 0, reduced(3))], 0.001,
                               previous_id=ids[-1])  # fmt: skip
    v1 = store.add_calibration(make_record())
    v2 = store.add_calibration(make_record(accepted=False, reasons=["chi2_red 9 > 4"]))
    e = store.add_event("start", "service started", {"session": sid})
    store.save_noise_floor(
        "dev", {"accel": 1e-4, "gyro": 1e-6, "window_samples": 100, "source": "x"}
    )  # fmt: skip  (not synced)
    assert keys(store) == [
        ("session", sid),
        *(("window", i) for i in ids),
        ("slew", 1),
        ("slew", 2),
        ("window", more[0]),
        ("slew", 3),
        ("version", v1),
        ("version", v2),  # rejected versions go too
        ("event", e),
    ]
    assert store.outbox_count() == 11
    found = store.outbox_rows(store.outbox(100))
    assert found["slew", 3]["slew"].first_id == ids[-1]
    assert found["version", v2]["record"].accepted is False


def test_a_refused_write_adds_no_outbox_row(store: Store) -> None:
    sid = store.add_session("s")
    with pytest.raises(UnknownSessionError):
        store.add_positions(sid + 99, columns(2))
    store.add_positions(sid, columns(2), spool_key="batch-1")
    before = keys(store)
    assert store.add_positions(sid, columns(2), spool_key="batch-1") == [1, 2]  # a replay
    assert keys(store) == before == [("session", sid), ("window", 1), ("window", 2)]


def test_acknowledging_deletes_exactly_those_rows_and_counts_the_traffic(store: Store) -> None:
    sid = store.add_session("s")
    store.add_positions(sid, columns(4))
    head = store.outbox(3)
    assert store.sync_acknowledge([e.seq for e in head[1:]], day="2026-11-27", sent_bytes=900,
                                  rows=2, contact=None) == 2  # fmt: skip
    store.sync_traffic_add("2026-11-27", 100)
    store.sync_traffic_add("2026-11-26", 50)
    assert keys(store) == [("session", sid), ("window", 3), ("window", 4)]
    assert store.sync_acknowledge([head[1].seq]) == 0  # already gone: nothing else deleted
    assert store.sync_traffic("2026-11-27") == [
        {"day": "2026-11-27", "bytes": 1000, "rows": 2, "batches": 0}
    ]
    assert [d["day"] for d in store.sync_traffic("2026-01-01")] == ["2026-11-26", "2026-11-27"]
    assert store.sync_last_contact() is None


def test_a_write_and_its_outbox_row_roll_back_together(tmp_path: Any) -> None:
    st = Store(f"sqlite:///{tmp_path / 'r.db'}")
    st.create_schema()
    sid = st.add_session("s")
    with pytest.raises(StoreError):  # a value JSON cannot hold: the insert fails
        st.add_event("bad", "x", {"when": object()})
    assert keys(st) == [("session", sid)]
    st.close()
