"""Fleet-wide re-analysis over every unit's history, in parallel over units on Dask (issues 28, 37).

For every unit of the shore's database: its accepted versions (the coefficients and 1-sigma of
each calibration, ``data->'document'``) and a drift test (recal.diagnose.drift) of its newest
windows against its current version; then, per model, the fleet prior's rates
(recal.fleet.fleet_prior) and each unit's outlier statistic under them
(recal.fleet.outliers: chi-square of its changes, p-value, flagged or not). With ``effects``
(catalogue names, or a plugin's terms), each unit's windows are also re-fitted with and without
each effect, and each model gets a verdict on it (service.fleet.workbench).

The client (this process) reads each unit's rows and sends them with the task: the per-unit
part (:func:`analyse_unit`: the drift test, the refit) runs on Dask workers that need
fog-recal installed but no database. ``scheduler`` None and ``workers`` 1: in this process;
``scheduler`` None and more workers: a local Dask cluster of that many worker processes (one
thread each); ``scheduler`` ``tcp://HOST:8786``: that cluster's workers, however many it has.
The per-model part is one vectorised fit over all units' changes and stays in the client.
``recal fleet reanalyse --config shore.toml`` prints the result (docs/fleet.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from datetime import UTC, datetime
from typing import Any

import numpy as np
from sqlalchemy import select

from service.fleet.schema import UnitRow, VersionRow, WindowRow

#: Newest windows since the current version a unit's drift test (and refit) reads.
DRIFT_WINDOWS = 200
#: The drift test's false-alarm period (the vessel's [scheduler] default).
DRIFT_FALSE_ALARM_DAYS = 30.0
#: How long the client waits to reach a scheduler, s.
CONNECT_TIMEOUT_S = 20


class ClusterError(RuntimeError):
    """No Dask (not installed), or a scheduler that cannot be reached: one line."""


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


def flat_values(section: Mapping[str, Any], names: Sequence[str]) -> list[float]:
    """A coefficients section's values by the flat names of :func:`flat_names` (NaN where
    absent)."""
    axis = {"x": 0, "y": 1, "z": 2}
    out = []
    for name in names:
        sensor, key, param = name.split(".", 2)
        entry = (section.get(sensor) or {}).get(key)
        leaf = None
        if isinstance(entry, Mapping):
            leaf = entry.get(param)
        elif isinstance(entry, list | tuple) and len(entry) == 3 and param[-1:] in axis:
            leaf = entry[axis[param[-1]]]
        out.append(float(leaf) if isinstance(leaf, int | float) else math.nan)
    return out


def read_unit(
    store: Any, unit_id: int, windows: int = DRIFT_WINDOWS, any_windows: bool = False
) -> tuple[list[tuple[float, dict, dict]], dict[str, Any]]:
    """One unit's accepted versions (time, coefficients, 1-sigma), oldest first, and its task's
    data: the current version's document and the columns of its newest ``windows`` windows
    since that version, by time (without a version: none, or with ``any_windows`` its newest)."""
    from service.fleet.workbench import window_columns
    from service.store.codec import as_utc

    doc = VersionRow.data["document"]
    accepted = (VersionRow.unit_id == unit_id, VersionRow.accepted.is_(True))
    order = (VersionRow.at, VersionRow.id)
    with store._tx() as s:
        versions = s.execute(
            select(VersionRow.at, doc["coefficients"], doc["uncertainty"])
            .where(*accepted)
            .order_by(*order)
        ).all()
        current = None
        query = select(WindowRow.data).where(WindowRow.unit_id == unit_id)
        if versions:
            current = s.execute(
                select(doc).where(*accepted).order_by(*(o.desc() for o in order)).limit(1)
            ).scalar_one()
            query = query.where(WindowRow.at >= versions[-1][0])
        rows: list[dict[str, Any]] = []
        if versions or any_windows:
            found = s.scalars(
                query.order_by(WindowRow.at.desc(), WindowRow.id.desc()).limit(windows)
            ).all()
            rows = list(reversed(found))
    history = [(as_utc(at).timestamp(), c or {}, u or {}) for at, c, u in versions]
    task = {"unit_id": unit_id, "current": current, "columns": window_columns(rows),
            "windows": len(rows)}  # fmt: skip
    return history, task


def analyse_unit(task: Mapping[str, Any], spec: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The per-unit part, on a Dask worker (or here): the drift test of the task's windows
    against its current version, and with ``spec["effects"]`` the refit
    (service.fleet.workbench.refit_unit). Reads no database."""
    from recal.runtime.allocator import tune_allocator
    from service.fleet.workbench import refit_unit

    # A Dask worker starts with MALLOC_TRIM_THRESHOLD_ set (distributed's nanny
    # pre-spawn-environ), which pins glibc's mmap threshold: every temporary array of the
    # tests then costs fresh pages, and a unit took 1.14 s there against 0.59 s in this
    # process (docs/fleet.md, "Fleet analysis on Dask"). Once per process.
    tune_allocator()

    columns, current = task["columns"], task["current"]
    out: dict[str, Any] = {"unit_id": task["unit_id"], "windows": task["windows"],
                           "drift": None, "refit": None}  # fmt: skip
    if current is not None and task["windows"] >= 2:
        out["drift"] = _drift(columns, current)
    if spec and spec.get("effects"):
        out["refit"] = refit_unit(columns, current, spec, source=f"unit {task.get('serial', '')}")
    return out


def _drift(columns: Mapping[str, np.ndarray], current: dict[str, Any]) -> dict[str, Any]:
    """The drift test (recal.diagnose.drift) of the windows ``columns`` against the
    calibration ``current``."""
    from recal.diagnose.drift import DriftConfig, drift_inputs, drift_test
    from recal.model.coefficients import CoefficientSet
    from recal.model.positions import Positions

    cols = {k: v for k, v in columns.items() if np.isfinite(v).all()}  # every row has it
    n = len(next(iter(cols.values())))
    try:
        coefficients = CoefficientSet.from_json_dict(current["coefficients"], source="shore")
        inputs = drift_inputs(Positions(columns=cols, source="shore"), coefficients,
                              current.get("covariance"), float(current.get("latitude_deg", 45.0)),
                              float(current.get("height_m", 0.0)))  # fmt: skip
        span_days = (
            (cols["end_s"].max() - cols["start_s"].min()) / 86400.0 if "end_s" in cols else 0
        )
        per_day = n / span_days if span_days > 0 else 24.0
        result = drift_test(inputs, DriftConfig.per_days(DRIFT_FALSE_ALARM_DAYS, per_day))
    except Exception as exc:  # a unit whose rows the test cannot read: said, not fatal
        return {"error": f"{type(exc).__name__}: {exc}"}
    return {
        "statistic": round(float(result.statistic[-1]), 4),
        "threshold": round(float(result.threshold), 4),
        "alarm": result.alarm_window is not None,
        "suspect": (result.suspects[0].get("name") if result.suspects else None),
    }


def connect(scheduler: str | None, workers: int) -> tuple[Any, Any]:
    """A Dask client and the local cluster it owns (None for an existing ``scheduler``);
    :class:`ClusterError` without Dask, for a scheduler that cannot be reached, or one with
    no worker."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise ClusterError(
            "Dask is not installed: pip install 'fog-recal[fleet]' (dask[distributed]), or "
            "run with --workers 1 and no --scheduler"
        ) from None
    if scheduler is None:
        import warnings

        with warnings.catch_warnings():  # its health server on another port when 8787 is taken
            warnings.filterwarnings("ignore", "Port .* is already in use", UserWarning)
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   dashboard_address=None)  # fmt: skip
        return Client(cluster), cluster
    try:
        client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError, ValueError) as exc:
        raise ClusterError(f"cannot reach the Dask scheduler {scheduler}: {exc}") from None
    try:
        client.wait_for_workers(1, timeout=CONNECT_TIMEOUT_S)
    except TimeoutError:
        client.close()
        raise ClusterError(
            f"the Dask scheduler {scheduler} has no worker after {CONNECT_TIMEOUT_S} s: start "
            f"some with `dask worker {scheduler}`"
        ) from None
    return client, None


def _run(
    tasks: Iterator[dict[str, Any]],
    spec: Mapping[str, Any] | None,
    workers: int,
    scheduler: str | None,
    progress: Callable[[int], None] | None,
) -> tuple[list[dict[str, Any]], int]:
    """Every task's result, and the number of workers that ran them. Tasks are sent as the
    client reads them, so the cluster works while the database is read."""
    if scheduler is None and workers <= 1:
        out = []
        for t in tasks:
            out.append(analyse_unit(t, spec))
            if progress:
                progress(1)
        return out, 1
    client, cluster = connect(scheduler, workers)
    try:
        from distributed import as_completed

        n = len(client.scheduler_info().get("workers", {})) or workers
        futures = [client.submit(analyse_unit, t, spec, pure=False) for t in tasks]
        for f in as_completed(futures):
            if f.status == "error":
                f.result()  # raises the task's exception here
            if progress:
                progress(1)
        return client.gather(futures), n
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def reanalyse(
    url: str,
    *,
    workers: int = 1,
    units: int | None = None,
    model: str | None = None,
    windows: int = DRIFT_WINDOWS,
    false_alarm: float = 0.01,
    scheduler: str | None = None,
    effects: Sequence[str] = (),
    plugins: Sequence[tuple[str, str]] = (),
    method: str = "lm",
    mc: int = 100,
    progress: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Every unit (of ``model``; the first ``units`` by serial) re-analysed: per unit its
    versions, outlier statistic (``statistic``, ``dof``, ``p_value``, ``outlier``) and drift
    test (``drift``); per model the fleet prior's rates. With ``effects`` (names; ``plugins``
    (path, source) add their terms), per unit ``refit`` and per model ``refit.models`` (the
    verdicts, service.fleet.workbench). ``workers`` / ``scheduler``: where the per-unit part
    runs (module doc)."""
    from scipy.stats import chi2

    from recal.fleet.compute import fleet_prior
    from recal.fleet.history import VersionTable
    from recal.fleet.outliers import unit_statistics
    from service.fleet.store import FleetStore
    from service.fleet.workbench import check_effects, verdicts

    effects = list(effects)
    if plugins and not effects:  # a plugin alone: its terms are the effects tried
        from service.fleet.workbench import plugin_terms

        effects = [t.name for t in plugin_terms(plugins)]
    spec = None
    if effects or plugins:
        check_effects(effects, plugins)
        spec = {"effects": effects, "plugins": [tuple(p) for p in plugins], "method": method,
                "mc": mc, "seed": 0}  # fmt: skip
    store = FleetStore(url)
    query = select(UnitRow.id, UnitRow.serial, UnitRow.model).order_by(UnitRow.serial)
    if model is not None:
        query = query.where(UnitRow.model == model)
    histories_by_id: dict[int, list] = {}
    try:
        with store._tx() as s:
            listed = s.execute(query).all()
        listed = listed[:units] if units is not None else listed

        def tasks() -> Iterator[dict[str, Any]]:
            for uid, serial, _m in listed:
                history, task = read_unit(store, uid, windows, any_windows=spec is not None)
                histories_by_id[uid] = history
                yield {**task, "serial": serial}

        results, ran_on = _run(tasks(), spec, workers, scheduler, progress)
    finally:
        store.close()
    by_id = {r["unit_id"]: {**r, "versions": histories_by_id[r["unit_id"]]} for r in results}
    results = list(by_id.values())
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
            values = np.reshape([flat_values(c, names) for _t, c, _u in v], (-1, len(names)))
            sigma = np.reshape([flat_values(u, names) for _t, _c, u in v], (-1, len(names)))
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
            row = {
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
            }  # fmt: skip
            if spec is not None:
                row["refit"] = r["refit"]
            out_units.append(row)
    out_units.sort(key=lambda u: u["unit"])
    report: dict[str, Any] = {
        "created_at": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "workers": workers if scheduler is None else ran_on,
        "scheduler": scheduler,
        "versions": sum(len(r["versions"]) for r in results),
        "windows": sum(r["windows"] for r in results),
        "models": priors,
        "units": out_units,
    }
    if spec is not None:
        refits = [{**u["refit"], "model": u["model"]} for u in out_units]
        report["refit"] = {
            "effects": effects,
            "plugins": [path for path, _src in plugins],
            "method": method,
            "windows": windows,
            "models": verdicts(refits, effects),
        }
    return report


def _names_of(results: Sequence[dict[str, Any]]) -> list[str]:
    for r in results:
        for _t, coefficients, _u in r["versions"]:
            names = flat_names(coefficients)
            if names:
                return names
    return []


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None
