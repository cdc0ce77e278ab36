"""What the fleet manager sees (issue 28) over real HTTP, on SQLite and PostgreSQL: the
overview's rows and their order, who sees what, a fixed number of queries whatever the number
of units, and the fleet prior (versioned, stored, cached) with its outliers."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

import pytest
from sqlalchemy import event, func, select

from recal.fleet.prior import read_fleet_prior
from service.fleet.overview import overview
from service.fleet.priors import FleetPriors
from service.fleet.schema import PriorRow

ADMIN = "admin-token-0123456789abcdef"
DSP = "DSP-1760-SN0201"
QUIET = "DSP-1760-SN0202"


def _dsp_rows(wire: Any) -> list[dict[str, Any]]:
    """A DSP-1760 whose second version was rejected after the drift test alarmed."""
    v1 = {**wire.version_doc(1, True, "2026-11-20T10:00:00Z"), "trigger": "count"}
    v1["document"] = {**v1["document"], "navigation": {"after": {"heading_error_deg_rms": 0.21}}}
    v2 = {**wire.version_doc(2, False, "2026-11-26T10:00:00Z"), "trigger": "drift",
          "reasons": ["chi2_red 312 exceeds 4", "gyro.bias.bz moved 40 sigma"]}  # fmt: skip
    drift = {"kind": "drift", "message": "DRIFT", "created_at": "2026-11-26T09:00:00Z",
             "data": {"version": 1, "statistic": 41.0, "threshold": 17.0, "alarm_window": 3,
                      "suspect": "gyro z bias, about +0.4 deg/h"}}  # fmt: skip
    return [
        {"kind": "version", "id": 1, "at": v1["created_at"], "data": v1},
        {"kind": "version", "id": 2, "at": v2["created_at"], "data": v2},
        {"kind": "event", "id": 5, "at": "2026-11-26T09:00:00Z", "data": drift},
        *[r for r in wire.rows_of(3, 1, 25) if r["kind"] in ("session", "window")],
    ]


@pytest.fixture
def fleet(shore: Any, wire: Any, simulated_fleet: Any) -> dict[str, Any]:
    """Eight KVH-1750 ageing over two years (one ten times faster), a DSP-1760 with a rejected
    version and drift, and a DSP-1760 that never called: each sent through POST /fleet/ingest."""
    sim = simulated_fleet()
    tokens = {}
    for serial, rows in sim["units"].items():
        tokens[serial] = shore.store.add_unit(serial, "KVH-1750")
        batch = {**wire.batch(serial, rows), "backlog": 7}
        assert shore.send(tokens[serial], batch).json() == {
            "stored": len(rows),
            "duplicates": 0,
            "conflicts": 0,
        }
    tokens[DSP] = shore.store.add_unit(DSP, "DSP-1760")
    assert shore.send(tokens[DSP], wire.batch(DSP, _dsp_rows(wire))).status_code == 200
    tokens[QUIET] = shore.store.add_unit(QUIET, "DSP-1760")
    # each batch with accepted versions started a recompute of the prior in the background: a
    # new version of it whenever its inputs had changed by then
    assert shore.priors.wait_idle(60)
    version = shore.get(ADMIN, "/fleet/prior", model="KVH-1750").json()["version"]
    return {"tokens": tokens, "outliers": sim["outliers"], "units": sim["units"],
            "prior_version": version}  # fmt: skip


def test_the_overview_rows_attention_first(shore, fleet) -> None:
    r = shore.get(ADMIN, "/fleet/overview")
    assert r.status_code == 200
    view = r.json()
    rows = {u["unit"]: u for u in view["units"]}
    assert len(rows) == 10
    (outlier,) = fleet["outliers"]
    # rejected and drift first, then the outlier, then the unit never heard from
    assert [u["unit"] for u in view["units"][:3]] == [DSP, outlier, QUIET]
    assert view["units"][0]["attention"] == ["rejected", "drift"]
    assert all(u["attention"] == [] for u in view["units"][3:])

    dsp = rows[DSP]
    assert (dsp["current_version"], dsp["versions"], dsp["last_version"]) == (1, 2, 2)
    assert dsp["last_trigger"] == "drift" and dsp["last_accepted"] is False
    assert dsp["rejected"] == {"count": 1, "last_version": 2, "last_at": "2026-11-26T10:00:00Z",
                               "last_reasons": ["chi2_red 312 exceeds 4",
                                                "gyro.bias.bz moved 40 sigma"]}  # fmt: skip
    assert dsp["heading_error_deg_rms"] == 0.21
    assert dsp["drift"]["state"] == "drift" and dsp["drift"]["statistic"] == 41.0
    assert dsp["drift"]["suspect"].startswith("gyro z bias")
    age = (datetime.now(UTC) - datetime(2026, 11, 20, 10, tzinfo=UTC)).total_seconds() / 86400
    assert dsp["age_days"] == pytest.approx(age, abs=0.01)
    assert dsp["windows"] == 3 and dsp["link"]["state"] == "up"
    assert dsp["link"]["backlog"] is None  # this batch did not say

    kvh = rows["KVH-1750-SN0000"]
    n = len(fleet["units"]["KVH-1750-SN0000"])
    assert (kvh["versions"], kvh["current_version"], kvh["rejected"]["count"]) == (n, n, 0)
    assert kvh["drift"]["state"] == "unknown" and kvh["heading_error_deg_rms"] == 0.05
    link = kvh["link"]
    assert link["backlog"] == 7 and link["hours_since_contact"] < 1
    assert len(link["bytes_per_day"]) == 7 and link["bytes_per_day"][-1]["bytes"] > 0
    assert link["bytes_7d"] == sum(d["bytes"] for d in link["bytes_per_day"])
    assert kvh["outlier"] == {"flagged": False, "prior_version": fleet["prior_version"]}
    flagged = rows[outlier]["outlier"]
    assert flagged["flagged"] and flagged["statistic"] > flagged["dof"] * 10

    quiet = rows[QUIET]
    assert quiet["link"]["state"] == "never" and quiet["current_version"] is None
    assert quiet["attention"] == ["never"] and quiet["age_days"] is None

    t = view["totals"]
    assert (t["units"], t["rejected"], t["drift"], t["outliers"], t["attention"]) == (
        10,
        1,
        1,
        1,
        3,
    )
    assert view["models"]["KVH-1750"]["prior_version"] == fleet["prior_version"]
    assert view["models"]["KVH-1750"]["prior_stale"] is False
    assert "DSP-1760" not in view["models"]  # one accepted version: no change to learn from

    # a unit's token: its own row alone; no token: 401
    mine = shore.get(fleet["tokens"][DSP], "/fleet/overview").json()
    assert [u["unit"] for u in mine["units"]] == [DSP] and mine["totals"]["units"] == 1
    assert shore.get(None, "/fleet/overview").status_code == 401


def test_the_overview_takes_a_fixed_number_of_queries(shore, fleet, wire) -> None:
    """No query per unit: twice the units, the same statements (the fleet has 1000)."""
    store = shore.store
    priors = FleetPriors(store)
    statements: list[str] = []

    def count(*args: Any) -> None:
        statements.append(args[2])

    event.listen(store._engine, "before_cursor_execute", count)
    try:
        overview(store, priors)  # computes the KVH-1750 prior
        first = len(statements)
        statements.clear()
        overview(store, priors)  # the prior is cached: its inputs' digest only
        warm = len(statements)
        for i in range(10):  # ten more units, with rows
            serial = f"SN-MORE-{i}"
            token = store.add_unit(serial, "DSP-1760")
            assert shore.send(token, wire.batch(serial, wire.rows_of(2, 1, 26))).status_code == 200
        assert shore.priors.wait_idle(60)
        overview(store, priors)  # DSP-1760 now has a prior to compute
        statements.clear()
        overview(store, priors)
        assert len(statements) == warm
        statements.clear()
        view = overview(store, FleetPriors(store))  # a new process: the stored priors
        assert len(statements) <= first
    finally:
        event.remove(store._engine, "before_cursor_execute", count)
    assert len(view["units"]) == 20 and warm <= 8


def test_the_fleet_prior_is_versioned_stored_and_cached(shore, fleet, wire) -> None:
    tokens = fleet["tokens"]
    r = shore.get(ADMIN, "/fleet/prior", model="KVH-1750")
    assert r.status_code == 200
    doc = r.json()
    prior = read_fleet_prior(doc, source="GET /fleet/prior")
    v0 = fleet["prior_version"]  # 1 or more: recomputed while the units' batches came
    assert doc["format"] == "recal.fleet_prior/1" and prior.version == v0 >= 1
    assert r.headers["X-Fleet-Prior-Stale"] == "false"
    assert prior.model == "KVH-1750" and len(prior.coefficients) == 27
    assert (
        prior.coefficients["gyro.scale.Kx"].relative
        and prior.coefficients["gyro.bias.bx"].units == 7
    )
    assert [o.unit for o in prior.outliers] == list(fleet["outliers"])
    # asked again (and by a unit of the model): the same prior, not recomputed; the unit sees
    # no other unit flagged (issue 37: its own outlier status alone)
    mine = shore.get(tokens["KVH-1750-SN0001"], "/fleet/prior", model="KVH-1750").json()
    itself = [o for o in doc["outliers"] if o["unit"] == "KVH-1750-SN0001"]
    assert mine == {**doc, "outliers": itself}
    again = FleetPriors(shore.store).current(["KVH-1750"])["KVH-1750"]
    assert again["version"] == v0 and again["created_at"] == doc["created_at"]
    with shore.store._tx() as s:
        assert s.scalar(select(func.count()).select_from(PriorRow)) == v0  # one row a version

    # a new accepted version: new inputs, version 2
    serial = "KVH-1750-SN0001"
    k = len(fleet["units"][serial]) + 1
    row = dict(fleet["units"][serial][-1], id=k)
    row["data"] = {**row["data"], "version": k, "created_at": "2026-11-26T00:00:00Z"}
    row["at"] = "2026-11-26T00:00:00Z"
    assert shore.send(tokens[serial], wire.batch(serial, [row])).json()["stored"] == 1
    # recomputed in the background: until then a request answers the old version, marked stale
    early = shore.get(ADMIN, "/fleet/prior", model="KVH-1750")
    assert (early.json()["version"], early.headers["X-Fleet-Prior-Stale"]) in {
        (v0, "true"),
        (v0 + 1, "false"),
    }
    assert shore.priors.wait_idle(60)
    fresh = shore.get(ADMIN, "/fleet/prior", model="KVH-1750")
    assert (fresh.json()["version"], fresh.headers["X-Fleet-Prior-Stale"]) == (v0 + 1, "false")
    # a rejected version changes nothing
    bad = {**row, "id": k + 1, "data": {**row["data"], "version": k + 1, "accepted": False}}
    assert shore.send(tokens[serial], wire.batch(serial, [bad])).json()["stored"] == 1
    assert shore.priors.wait_idle(60)
    assert shore.get(ADMIN, "/fleet/prior", model="KVH-1750").json()["version"] == v0 + 1

    # who may read which prior
    assert shore.get(tokens[DSP], "/fleet/prior", model="KVH-1750").status_code == 404
    none = shore.get(ADMIN, "/fleet/prior", model="DSP-1760")
    assert none.status_code == 404 and "two accepted versions" in none.json()["detail"]
    assert shore.get(ADMIN, "/fleet/prior", model="NOPE").status_code == 404
    assert shore.get(None, "/fleet/prior", model="KVH-1750").status_code == 401
    assert shore.get(ADMIN, "/fleet/prior").status_code == 404  # the admin has no model

    # the outliers: every flagged unit for the administrator, itself alone for a unit
    (outlier,) = fleet["outliers"]
    found = shore.get(ADMIN, "/fleet/outliers", model="KVH-1750").json()
    assert found["prior_version"] == v0 + 1 and [o["unit"] for o in found["outliers"]] == [outlier]
    assert found["outliers"][0]["p_value"] < 0.01 and found["outliers"][0]["statistic"] > 0
    assert shore.get(tokens[outlier], "/fleet/outliers", model="KVH-1750").json()["outliers"]
    assert shore.get(tokens[serial], "/fleet/outliers", model="KVH-1750").json()["outliers"] == []


def test_the_sync_client_reports_its_backlog(tmp_path) -> None:
    """Each batch says how many outbox rows the vessel still holds besides it (the overview's
    backlog)."""
    import gzip
    import json

    from service.store.repository import Store
    from service.sync.batch import build

    store = Store(f"sqlite:///{tmp_path / 'vessel.db'}")
    try:
        store.create_schema()
        store.add_session("test")
        for i in range(4):
            store.add_event("test", f"event {i}", None)
        total = store.outbox_count()
        batch = build(store, "SN-1", max_rows=2)
        sent = json.loads(gzip.decompress(batch.body))
        assert len(sent["rows"]) == 2 and sent["backlog"] == total - 2 == 3
    finally:
        store.close()


def test_the_prior_reads_the_flat_column_as_it_would_the_documents(shore, fleet) -> None:
    """``fleet_versions.flat`` (kept at ingest, migration 0006) gives the very table, and so
    the very prior, that the accepted versions' documents give."""
    import numpy as np

    from recal.fleet.compute import fleet_prior
    from recal.fleet.history import VersionTable, flat_version
    from service.fleet.priors import coefficient_names
    from service.fleet.schema import UnitRow, VersionRow

    names = coefficient_names()
    query = (
        select(UnitRow.serial, VersionRow.at, VersionRow.data, VersionRow.flat)
        .join(UnitRow, UnitRow.id == VersionRow.unit_id)
        .where(VersionRow.accepted.is_(True), UnitRow.model == "KVH-1750")
        .order_by(UnitRow.serial, VersionRow.at)
    )
    documents: dict[str, list[Any]] = {}
    flats: dict[str, list[Any]] = {}
    with shore.store._tx() as s:
        for serial, at, data, flat in s.execute(query):
            at = at.replace(tzinfo=UTC) if at.tzinfo is None else at
            documents.setdefault(serial, []).append((at, data["document"]))
            flats.setdefault(serial, []).append((at, flat))
            assert flat == flat_version(data["document"], names)
    assert sum(len(v) for v in flats.values()) > 50
    old = VersionTable.from_documents(names, documents)
    new = VersionTable.from_flat(names, flats)
    assert old.units == new.units
    for field in ("unit", "months", "values", "sigma"):
        np.testing.assert_array_equal(getattr(new, field), getattr(old, field))
    stamp = {"version": 1, "created_at": "2026-11-27T00:00:00Z"}
    assert (
        fleet_prior(new, "KVH-1750", **stamp).to_json_dict()
        == fleet_prior(old, "KVH-1750", **stamp).to_json_dict()
    )
    served = FleetPriors(shore.store).current(["KVH-1750"])["KVH-1750"]
    expected = fleet_prior(old, "KVH-1750", version=served["version"], created_at=served["created_at"],
                           metadata=served.get("metadata"))  # fmt: skip
    assert served == expected.to_json_dict()


def test_a_request_never_waits_for_a_recompute(shore, fleet, wire, monkeypatch) -> None:
    """A new accepted version makes the prior stale: a request answers the stored one at once,
    says so, and the recompute runs in the background thread; then the new version is served."""
    import json
    import threading

    from service.fleet.batch import read_batch

    v0 = fleet["prior_version"]
    serial = "KVH-1750-SN0002"
    k = len(fleet["units"][serial]) + 1
    row = dict(fleet["units"][serial][-1], id=k, at="2026-11-27T00:00:00Z")
    row["data"] = {**row["data"], "version": k, "created_at": "2026-11-27T00:00:00Z"}
    body = json.dumps(wire.batch(serial, [row])).encode()
    unit = shore.store.unit_by_serial(serial)
    assert shore.store.ingest(unit, read_batch(body, None, len(body)), len(body)) == (1, 0, 0)

    computed_in: list[str] = []
    compute = FleetPriors._compute

    def spy(self: FleetPriors, *args: Any) -> Any:
        computed_in.append(threading.current_thread().name)
        return compute(self, *args)

    monkeypatch.setattr(FleetPriors, "_compute", spy)
    priors = FleetPriors(shore.store)  # another process: nothing cached
    try:
        documents, stale = priors.served(["KVH-1750"])
        assert documents["KVH-1750"]["version"] == v0 and stale == {"KVH-1750"}
        assert priors.wait_idle(60)
        assert computed_in == ["fleet-prior-refresh"]  # not the caller's thread
        documents, stale = priors.served(["KVH-1750"])
        assert documents["KVH-1750"]["version"] == v0 + 1 and stale == set()
        assert computed_in == ["fleet-prior-refresh"]  # and not again
    finally:
        priors.close()


def _drift_event(ident: int, at: str, version: int, alarm: int | None) -> dict[str, Any]:
    data = {"version": version, "statistic": float(ident), "threshold": 17.0,
            "alarm_window": alarm, "suspect": None}  # fmt: skip
    return {"kind": "event", "id": ident, "at": at,
            "data": {"kind": "drift", "message": "m", "created_at": at, "data": data}}  # fmt: skip


def test_what_ingest_keeps_for_the_overview_is_what_the_rows_say(fleet_store, wire) -> None:
    """The overview reads what ingest keeps on the unit's row and per link day (migration
    0009). Rows arriving out of time order, from two database instances, in batches sent in
    shuffled order: the kept state must be what migration 0009 computes afresh from the rows
    stored (the current version is the newest accepted by time, not the last received)."""
    import json
    import random

    from alembic import command

    from service.fleet.batch import read_batch
    from service.fleet.migrations import alembic_config, head

    rng = random.Random(5)
    for serial in ("OOO-1", "OOO-2"):
        fleet_store.add_unit(serial, "KVH-1750")
        unit = fleet_store.unit_by_serial(serial)
        rows = []
        for v in range(1, 9):  # versions of days 1..8, every third rejected
            at = f"2026-11-{v:02d}T10:00:00Z"
            doc = wire.version_doc(v, v % 3 != 0, at) | {"reasons": [f"reason {v}"]}
            doc["document"] = doc["document"] | {
                "navigation": {"after": {"heading_error_deg_rms": 0.1 * v}}
            }
            rows.append({"kind": "version", "id": v, "at": at, "data": doc})
            rows.append(_drift_event(v, f"2026-11-{v:02d}T09:00:00Z", v - 1, 3 if v == 5 else None))
        rng.shuffle(rows)
        batches = [rows[i : i + 3] for i in range(0, len(rows), 3)]
        for k, part in enumerate(batches):
            batch = wire.batch(serial, part) | {"backlog": len(batches) - k,
                                                "instance": "a" * 8 if k % 2 else "b" * 8}  # fmt: skip
            body = json.dumps(batch).encode()
            assert fleet_store.ingest(unit, read_batch(body, None, 10**6), 100 + k).stored
    now = datetime.now(UTC)  # the link's days are the batches' (received now)
    kept = overview(fleet_store, FleetPriors(fleet_store), now=now)
    row = {r["unit"]: r for r in kept["units"]}["OOO-1"]
    assert row["current_version"] == 8 and row["last_version"] == 8  # the newest by time
    assert row["rejected"]["last_version"] == 6 and row["rejected"]["count"] == 2
    assert row["drift"]["statistic"] == 8.0 and row["drift"]["state"] == "steady"
    assert row["link"]["backlog"] == 1
    assert sum(d["rows"] for d in row["link"]["bytes_per_day"]) == 16
    with fleet_store._engine.connect() as conn, conn.begin():
        command.downgrade(alembic_config(conn), "0008")
    fleet_store.create_schema()
    assert fleet_store.schema_revision() == head()
    assert overview(fleet_store, FleetPriors(fleet_store), now=now) == kept
