"""Fleet-wide re-analysis over every unit's history, in parallel over units (issue 28).

For every unit of the shore's database: its accepted versions (the coefficients and 1-sigma of
each calibration, ``data->'document'``) and a drift test (recal.diagnose.drift) of its newest
windows against its current version; then, per model, the fleet prior's rates
(recal.fleet.fleet_prior) and each unit's outlier statistic under them
(recal.fleet.outliers: chi-square of its changes, p-value, flagged or not).

The per-unit part (reading the unit's rows, decoding them, the drift test) runs in
``workers`` processes (:class:`concurrent.futures.ProcessPoolExecutor`), each with its own
database connection; the per-model part is one vectorised fit over all units' changes and
stays in the parent. ``recal fleet reanalyse --config shore.toml --workers N`` prints the
result as JSON.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from datetime import UTC, datetime
from typing import Any

import numpy as np
from sqlalchemy import select

from service.fleet.schema import UnitRow, VersionRow, WindowRow

#: Newest windows since the current version a unit's drift test reads.
DRIFT_WINDOWS = 200
#: The drift test's false-alarm period (the vessel's [scheduler] default).
DRIFT_FALSE_ALARM_DAYS = 30.0

_store: Any = None  # the worker's FleetStore


def flat_names(section: dict[str, Any]) -> list[str]:
    """The conventions' flat names (``gyro.scale.Kx``, ``accel.misalignment.Exz``) present in
    a coefficients section (docs/reference.md, section 5)."""
    letters = {"scale": "K", "bias": "b", "quadratic": "K2"}
    names = []
    for sensor in ("gyro", "accel"):
        for key, entry in (section.get(sensor) or {}).items():
            if isinstance(entry, dict):
                names += [f"{sensor}.{key}.{p}" for p in entry]
            elif isinstance(entry, list) and len(entry) == 3 and key in letters:
                names += [f"{sensor}.{key}.{letters[key]}{a}" for a in "xyz"]
    return names


def _init(url: str) -> None:
    global _store
    from service.fleet.store import FleetStore

    _store = FleetStore(url)


def unit_history(unit_id: int, windows: int = DRIFT_WINDOWS) -> dict[str, Any]:
    """One unit's accepted versions (time, coefficients, 1-sigma) and the drift test of its
    newest ``windows`` windows since its current version (in a worker process)."""
    doc = VersionRow.data["document"]
    query = (
        select(VersionRow.vessel_id, VersionRow.at, doc["coefficients"], doc["uncertainty"])
        .where(VersionRow.unit_id == unit_id, VersionRow.accepted.is_(True))
        .order_by(VersionRow.vessel_id)
    )
    with _store._tx() as s:
        versions = s.execute(query).all()
        current = None
        rows: list[dict[str, Any]] = []
        if versions:
            number, at = versions[-1][0], versions[-1][1]
            current = s.execute(
                select(VersionRow.data["document"]).where(
                    VersionRow.unit_id == unit_id, VersionRow.vessel_id == number
                )
            ).scalar_one()
            found = s.scalars(
                select(WindowRow.data)
                .where(WindowRow.unit_id == unit_id, WindowRow.at >= at)
                .order_by(WindowRow.vessel_id.desc())
                .limit(windows)
            ).all()
            rows = list(reversed(found))
    out: dict[str, Any] = {
        "unit_id": unit_id,
        "versions": [
            (at.astimezone(UTC).timestamp(), c or {}, u or {}) for _n, at, c, u in versions
        ],
        "windows": len(rows),
        "drift": None,
    }
    if current is not None and len(rows) >= 2:
        out["drift"] = _drift(rows, current)
    return out


def _drift(rows: list[dict[str, Any]], current: dict[str, Any]) -> dict[str, Any]:
    """The drift test (recal.diagnose.drift) of ``rows`` against the calibration ``current``."""
    from recal.diagnose.drift import DriftConfig, drift_inputs, drift_test
    from recal.model.coefficients import CoefficientSet
    from recal.model.positions import Positions

    names = [k for k, v in rows[0].items() if isinstance(v, int | float) and k != "session"]
    names = [k for k in names if all(isinstance(r.get(k), int | float) for r in rows)]
    cols = {k: np.array([float(r[k]) for r in rows]) for k in names}
    try:
        coefficients = CoefficientSet.from_json_dict(current["coefficients"], source="shore")
        inputs = drift_inputs(Positions(columns=cols, source="shore"), coefficients,
                              current.get("covariance"), float(current.get("latitude_deg", 45.0)),
                              float(current.get("height_m", 0.0)))  # fmt: skip
        span_days = (
            (cols["end_s"].max() - cols["start_s"].min()) / 86400.0 if "end_s" in cols else 0
        )
        per_day = len(rows) / span_days if span_days > 0 else 24.0
        result = drift_test(inputs, DriftConfig.per_days(DRIFT_FALSE_ALARM_DAYS, per_day))
    except Exception as exc:  # a unit whose rows the test cannot read: said, not fatal
        return {"error": f"{type(exc).__name__}: {exc}"}
    return {
        "statistic": round(float(result.statistic[-1]), 4),
        "threshold": round(float(result.threshold), 4),
        "alarm": result.alarm_window is not None,
        "suspect": (result.suspects[0].get("name") if result.suspects else None),
    }


def _unit_job(args: tuple[int, int]) -> dict[str, Any]:
    return unit_history(*args)


def reanalyse(
    url: str,
    *,
    workers: int = 1,
    units: int | None = None,
    model: str | None = None,
    windows: int = DRIFT_WINDOWS,
    false_alarm: float = 0.01,
) -> dict[str, Any]:
    """Every unit (of ``model``; the first ``units`` by serial) re-analysed: per unit its
    versions, outlier statistic (``statistic``, ``dof``, ``p_value``, ``outlier``) and drift
    test (``drift``); per model the fleet prior's rates. ``workers`` processes read and test
    the units in parallel."""
    from scipy.stats import chi2

    from recal.fleet.compute import fleet_prior
    from recal.fleet.history import VersionTable, _flat
    from recal.fleet.outliers import unit_statistics
    from service.fleet.store import FleetStore

    store = FleetStore(url)
    query = select(UnitRow.id, UnitRow.serial, UnitRow.model).order_by(UnitRow.serial)
    if model is not None:
        query = query.where(UnitRow.model == model)
    try:
        with store._tx() as s:
            listed = s.execute(query).all()
    finally:
        store.close()
    listed = listed[:units] if units is not None else listed
    jobs = [(uid, windows) for uid, _s, _m in listed]
    if workers <= 1:
        _init(url)
        results = [_unit_job(j) for j in jobs]
    else:
        chunk = max(1, len(jobs) // (8 * workers))
        with ProcessPoolExecutor(workers, initializer=_init, initargs=(url,)) as pool:
            results = list(pool.map(_unit_job, jobs, chunksize=chunk))
    by_id = {r["unit_id"]: r for r in results}
    names = _names_of(results)
    out_units: list[dict[str, Any]] = []
    priors: dict[str, Any] = {}
    models = sorted({m or "" for _i, _s, m in listed})
    for m in models:
        members = [(uid, serial) for uid, serial, mm in listed if (mm or "") == m]
        histories: dict[str, Any] = {}
        for uid, serial in members if names else ():
            v = by_id[uid]["versions"]
            months = [t / 86400.0 / (365.25 / 12.0) for t, _c, _u in v]
            values = np.reshape([_flat(c, names) for _t, c, _u in v], (-1, len(names)))
            sigma = np.reshape([_flat(u, names) for _t, _c, u in v], (-1, len(names)))
            histories[serial] = (months, values, sigma)
        table = VersionTable.from_histories(names, histories)
        changes = table.changes()
        stat = dof = p = None
        if names and len(changes):
            prior = fleet_prior(changes, m or "unknown", false_alarm=false_alarm)
            rate, _sigma = prior.rates(names)
            stat, dof = unit_statistics(changes, np.nan_to_num(rate))
            p = np.where(dof > 0, chi2.sf(stat, np.maximum(dof, 1)), 1.0)
            priors[m] = {"changes": len(changes), "outliers": [o.unit for o in prior.outliers]}
        flagged = set(priors.get(m, {}).get("outliers", []))
        for uid, serial in members:
            i = table.units.index(serial) if serial in table.units else -1
            r = by_id[uid]
            out_units.append({
                "unit": serial,
                "model": m or None,
                "versions": len(r["versions"]),
                "windows": r["windows"],
                "statistic": None if stat is None or i < 0 else round(float(stat[i]), 3),
                "dof": None if dof is None or i < 0 else int(dof[i]),
                "p_value": None if p is None or i < 0 else _finite(float(p[i])),
                "outlier": serial in flagged,
                "drift": r["drift"],
                "drift_alarm": bool(r["drift"] and r["drift"].get("alarm")),
            })  # fmt: skip
    return {
        "created_at": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "workers": workers,
        "versions": sum(len(r["versions"]) for r in results),
        "windows": sum(r["windows"] for r in results),
        "models": priors,
        "units": sorted(out_units, key=lambda u: u["unit"]),
    }


def _names_of(results: Sequence[dict[str, Any]]) -> list[str]:
    for r in results:
        for _t, coefficients, _u in r["versions"]:
            names = flat_names(coefficients)
            if names:
                return names
    return []


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None
