"""The vessel's sync thread (service/sync/) against the real shore service (service/fleet/):
a vessel's history arrives whole, each row once, through a link that cuts the shore's answers
(the fault proxy) and past the shore's batch limit (413: the vessel halves its batches); the
versions on shore are the vessel's own documents."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from fastapi.testclient import TestClient
from fault_proxy import FaultProxy

from recal.model.coefficients import CoefficientSet
from recal.sim.simulate import simulate_positions
from service.api import create_app
from service.publish import Publisher
from service.store.records import CalibrationRecord
from service.store.repository import Store
from service.sync import SyncThread

UNIT = "KVH-1750-SN0042"
FAST = {"backoff_base_s": 0.05, "backoff_cap_s": 0.2, "connect_timeout_s": 2.0,
        "read_timeout_s": 5.0}  # fmt: skip


def wait_for(predicate: Any, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


def vessel(tmp_path: Path) -> Store:
    """A vessel's database: a session, 60 windows, 59 slews, an accepted and a rejected
    version and two events (the outbox holds them all)."""
    import numpy as np

    from recal.detect.slew_collect import ReducedSlew

    store = Store(f"sqlite:///{tmp_path / 'vessel.db'}")
    store.create_schema()
    sid = store.add_session("replay:///capture.bin", {"rate_hz": 1000.0})
    table = simulate_positions(CoefficientSet.seed_truth(), "random", n_positions=60, seed=1)
    rng = np.random.default_rng(0)
    slews = [(i, i + 1, ReducedSlew(None, None, rng.normal(size=3), 400,
                                    (np.array([3, 4]), rng.normal(size=(2, 3)),
                                     rng.normal(size=(2, 3)), rng.normal(size=(2, 3))), None))
             for i in range(59)]  # fmt: skip
    ids = store.add_positions(sid, dict(table.columns), slews, 0.001)
    doc = {"coefficients": {"gyro": {"bias": [0.1, 0.2, float("nan")]}}, "chi2_red": 1.1}
    v1 = store.add_calibration(CalibrationRecord(trigger="auto", method="lm", accepted=True,
                                                 document=doc, positions_used=ids))  # fmt: skip
    store.add_calibration(CalibrationRecord(trigger="auto", method="lm", accepted=False,
                                            reasons=["chi2_red 9 > 4"], document=doc,
                                            prior_version=v1))  # fmt: skip
    store.add_event("start", "service started", {"session": sid})
    store.add_event("reader_error", "no frame for 2 s")
    return store


def test_the_vessel_history_reaches_the_real_shore_once_through_lost_answers(
    shore: Any, tmp_path: Path
) -> None:
    token = shore.store.add_unit(UNIT, "KVH-1750")
    store = vessel(tmp_path)
    total = store.outbox_count()
    port = int(shore.url.rsplit(":", 1)[1])
    with FaultProxy(("127.0.0.1", port), seed=1) as proxy:
        proxy.set(drop_response=1.0)  # the shore commits, the vessel never hears
        thread = SyncThread(store, proxy.url, UNIT, token, **FAST)
        thread.start()
        try:
            wait_for(lambda: proxy.stats.cuts.get("response", 0) >= 3)
            proxy.clear()
            wait_for(lambda: store.outbox_count() == 0)
        finally:
            assert thread.stop()
    unit = shore.get(token, f"/fleet/units/{UNIT}").json()
    assert unit["rows"] == {"session": 1, "window": 60, "slew": 59, "version": 2, "event": 2}
    link = unit["link"]
    assert sum(d["stored"] for d in link) == total
    # the shore's 64 KiB limit: 413, and the vessel halved its batches
    assert thread.max_json_bytes < 64 * 1024

    versions = shore.get(token, f"/fleet/units/{UNIT}/versions").json()
    app = create_app(store, Publisher(tmp_path / "coefficients.json"))
    with TestClient(app) as http:
        for v in versions:
            assert v["document"] == http.get(f"/coefficients/{v['version']}").json()
    assert [v["accepted"] for v in versions] == [True, False]
    store.close()
