"""The shore at scale (issue 28): the units' counts kept by ingest and filled in by migration
0003, the fleet-wide re-analysis in parallel processes, and the benchmark's generated batches
(benchmarks/bench_fleet.py) as the shore reads them."""

from __future__ import annotations

import gzip
import importlib.util
import json
import sys
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

from recal import CoefficientSet, simulate_fleet, simulate_positions
from recal.fleet.history import MONTH_DAYS, flat_section
from service.fleet.batch import read_batch
from service.fleet.migrations import alembic_config
from service.fleet.reanalysis import flat_names, reanalyse
from service.fleet.store import FleetStore

PROJECT = Path(__file__).resolve().parents[2]
START = datetime(2024, 1, 1, tzinfo=UTC)


def _send(store: FleetStore, serial: str, rows: list[dict]) -> None:
    body = gzip.compress(json.dumps({"format": 1, "unit": serial, "rows": rows}).encode())
    store.ingest(store.unit_by_serial(serial), read_batch(body, "gzip", 1 << 24), len(body))


def test_unit_counts_kept_by_ingest_and_filled_in_by_the_migration(fleet_store, wire) -> None:
    fleet_store.add_unit("SN-A", "KVH-1750")
    fleet_store.add_unit("SN-B")
    _send(fleet_store, "SN-A", wire.rows_of(3, 11, 25))
    _send(fleet_store, "SN-A", wire.rows_of(4, 1, 24))
    _send(fleet_store, "SN-A", wire.rows_of(4, 1, 24))  # a replay counts nothing
    kept = fleet_store.units()
    assert [(u["versions"], u["windows"], u["current_version"]) for u in kept] == [
        (4, 7, 11),
        (0, 0, None),
    ]
    from alembic import command

    with fleet_store._engine.begin() as conn:  # back to 0002 and up again: counted afresh
        command.downgrade(alembic_config(conn), "0002")
        command.upgrade(alembic_config(conn), "head")
    assert fleet_store.units() == kept


def _document(coeffs: dict, names, values, sigma) -> dict:
    section = json.loads(json.dumps(coeffs))
    uncertainty = json.loads(json.dumps(coeffs))
    axis = {"x": 0, "y": 1, "z": 2}
    for target, numbers in ((section, values), (uncertainty, sigma)):
        for name, v in zip(names, numbers):
            sensor, key, param = name.split(".", 2)
            entry = target[sensor][key]
            if isinstance(entry, dict):
                entry[param] = float(v)
            else:
                entry[axis[param[-1]]] = float(v)
    return {"coefficients": section, "uncertainty": uncertainty, "latitude_deg": 45.0}


def test_reanalysis_flags_the_fast_ageing_unit_on_one_or_two_processes(fleet_store, fleet_url):
    coeffs = CoefficientSet.seed_truth().to_json_dict()
    names = [n for n in flat_names(coeffs) if np.isfinite(flat_section(coeffs, [n])[0])]
    nominal = np.array(flat_section(coeffs, names))
    sigma = np.full(len(names), 1e-5)
    rates = np.full(len(names), 1e-5)
    fleet = simulate_fleet(names, nominal, rates, sigma, units=8, years=3.0, outliers=1,
                           outlier_factor=30.0, seed=3)  # fmt: skip
    table = fleet.versions
    for i, serial in enumerate(table.units):
        fleet_store.add_unit(serial, "M1")
        rows, last = [], None
        for n, r in enumerate(np.flatnonzero(table.unit == i), start=1):
            at = (START + timedelta(days=float(table.months[r]) * MONTH_DAYS)).isoformat()
            last = _document(coeffs, names, table.values[r], table.sigma[r])
            doc = {"version": n, "accepted": True, "created_at": at, "document": last}
            rows.append({"kind": "version", "id": n, "at": at, "data": doc})
        if i == 0:  # windows after its last version, as its last version sees them
            truth = CoefficientSet.from_json_dict(last["coefficients"], source="test")
            p = simulate_positions(truth, design="random", n_positions=12, seed=1)
            for k in range(len(p)):
                data = {c: float(v[k]) for c, v in p.columns.items()}
                rows.append({"kind": "window", "id": k + 1, "at": "2030-01-01T00:00:00Z",
                             "data": data})  # fmt: skip
        _send(fleet_store, serial, rows)
    one = reanalyse(fleet_url, workers=1)
    two = reanalyse(fleet_url, workers=2)
    assert [u["outlier"] for u in one["units"]] == [u in fleet.outliers for u in table.units]
    for a, b in zip(one["units"], two["units"]):
        assert a == b
    first = one["units"][0]
    assert first["windows"] == 12 and first["drift"]["alarm"] is False
    assert first["drift"]["statistic"] < first["drift"]["threshold"]
    assert all(u["drift"] is None for u in one["units"][1:])
    assert one["versions"] == len(table.unit) and one["models"]["M1"]["outliers"] == list(
        fleet.outliers
    )


def _bench():
    spec = importlib.util.spec_from_file_location(
        "bench_fleet", PROJECT / "benchmarks" / "bench_fleet.py"
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules["bench_fleet"] = module
    spec.loader.exec_module(module)
    return module


def test_the_benchmarks_batches_are_what_the_shore_reads() -> None:
    bench = _bench()
    fleet = bench.Fleet(2, 20 / 365.25)
    unit = fleet.plan(fleet.units[1])
    kinds: dict[str, int] = {}
    for raw in bench.batches(unit.serial, fleet.wire_rows(unit)):
        batch = read_batch(raw, None, 1 << 22)
        assert len(batch.rows) <= bench.BATCH_ROWS and len(raw) <= bench.BATCH_BYTES + 40_000
        for r in batch.rows:
            kinds[r.kind] = kinds.get(r.kind, 0) + 1
    r = fleet.rates
    assert kinds["window"] == 20 * r.windows and kinds["event"] == 20 * r.events
    assert kinds["slew"] == 20 * r.slews and kinds["session"] == 2
    assert kinds.get("version", 0) == sum(
        1 for v in unit.versions if v[1] < bench.START + timedelta(days=20)
    )
