"""The shore at fleet scale (issue 28): a generated fleet of ``--units`` units over ``--years``
years, its ingest throughput, storage, the p95 of the API's queries and the fleet-wide
re-analysis on 1 and 2 processes.

    python benchmarks/bench_fleet.py                       # 1000 units x 5 years: ~51 GB, ~2 h
    python benchmarks/bench_fleet.py --quick               # 4 units x 60 days: 30 s
    python benchmarks/bench_fleet.py --database-url postgresql+psycopg://... --keep

Without ``--database-url`` a throwaway PostgreSQL database is created (on
``RECAL_TEST_POSTGRES``'s server, default ``postgresql://postgres@127.0.0.1:5432``) and
dropped at the end (``--keep`` leaves it).

**Rates per unit (averages), and why.**

* Static windows: 12 a day. A hull-fixed FOG finds still periods in calm water under way and
  several an hour at berth (docs/static.md); the daemon's drift threshold assumes 24 a day
  before it has measured the rate. Half that is a vessel at sea most of the time. A window is
  the vessel's ``positions`` row (27 columns and its session, about 900 bytes of JSON), values
  simulated from the unit's last accepted coefficients (24 windows per unit, repeated).
* Slews: 2 a day (a turn between two windows), 12 groups of 10 sums each (about 2.6 KiB).
* Events: 20 a day: a drift test at every window (the daemon's ``drift`` event, about 600
  bytes), the information trigger's checks, the detector and noise-floor notes; a job's start,
  end and its version's verdict on the days of a version.
* Calibration versions: one every 2 to 6 weeks (uniform), a quarter of them rejected by the
  gate: about 87 a unit in 5 years (65 accepted). Each is the real document of ``recal demo
  --vessel`` (``benchmarks/data/fleet_version.json``, 29.8 kB: covariance, observability,
  residuals, navigation) with the unit's coefficients and 1-sigma (a random walk of
  recal.fleet.simulate, 1 % of units ageing five times faster).
* Sessions: a daemon start every 14 days (port calls, power cycles).
* Ingest log: a batch every 4 hours (a satellite link billed by session).

**What is measured how.** ``--ingest-units`` units (default 10) send their whole history as a
vessel catching up does, batch after batch (at most 500 rows and 256 KiB of JSON a batch): all
but one through ``FleetStore.ingest`` (the figure: rows/s and batches/s of the store), the
last through HTTP (gzip, a real ``recal fleet serve``) to show the HTTP overhead. The other
units are bulk-loaded by PostgreSQL itself (``INSERT ... SELECT generate_series`` of the same
rows, versions by COPY), in time order across units as the fleet's batches arrive (a unit's
rows spread over the table), with the indexes built after; that load's rate is printed too
but is not the ingest figure. Then: sizes per table (``pg_total_relation_size``), and the
API's queries through HTTP with the administrator's token, each repeated ``--repeat`` times
on random units and times (median, p95, max; target p95 < 1 s), and the fleet-wide
re-analysis (service.fleet.reanalysis) on 1 and then 2 worker processes.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import gzip
import json
import os
import secrets
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from stopping import stop_on_sigterm  # noqa: E402

from recal import CoefficientSet, simulate_fleet, simulate_positions  # noqa: E402
from recal.fleet.history import MONTH_DAYS, flat_section, flat_version, is_relative  # noqa: E402
from service.fleet.batch import overview_columns, read_batch  # noqa: E402
from service.fleet.priors import coefficient_names  # noqa: E402
from service.fleet.reanalysis import flat_names  # noqa: E402
from service.fleet.store import FleetStore, Unit, token_hash  # noqa: E402

TEMPLATE = ROOT / "benchmarks" / "data" / "fleet_version.json"
ADMIN_TOKEN = "bench-admin-token-0123456789"
PG_SERVER = os.environ.get("RECAL_TEST_POSTGRES", "postgresql://postgres@127.0.0.1:5432/test")
START = datetime(2021, 11, 27, tzinfo=UTC)
MODELS = ("KVH-1750", "KVH-1775", "EMCORE-EN300")
TARGET_S = 1.0
BATCH_ROWS, BATCH_BYTES = 500, 256 * 1024


@dataclass(frozen=True)
class Rates:
    """Rows per unit and day (averages; see the module docstring)."""

    windows: int = 12
    slews: int = 2
    events: int = 20
    session_days: int = 14
    batches: int = 6
    version_weeks: tuple[float, float] = (2.0, 6.0)
    rejected: float = 0.25
    template_windows: int = 24


# ---- the generated fleet ---------------------------------------------------------------------
def set_flat(section: dict[str, Any], names: list[str], values: np.ndarray) -> None:
    axis = {"x": 0, "y": 1, "z": 2}
    for name, value in zip(names, values):
        sensor, key, param = name.split(".", 2)
        entry = section[sensor][key]
        if isinstance(entry, dict):
            entry[param] = float(value)
        else:
            entry[axis[param[-1]]] = float(value)


@dataclass
class UnitPlan:
    index: int
    serial: str
    model: str
    token: str
    versions: list[tuple[int, datetime, bool, str]] = field(default_factory=list)  # id, at, ok, doc
    windows: list[dict[str, Any]] = field(default_factory=list)  # the unit's window templates


class Fleet:
    """The generated fleet: units, their versions (documents) and window templates."""

    def __init__(self, units: int, years: float, seed: int = 0, rates: Rates = Rates()) -> None:
        self.rates, self.years = rates, years
        self.days = int(round(years * 365.25))
        self.template = json.loads(TEMPLATE.read_text())
        coeffs = self.template["document"]["coefficients"]
        self.names = [n for n in flat_names(coeffs)
                      if np.isfinite(flat_section(coeffs.get("uncertainty") or {}, [n])[0])]  # fmt: skip
        nominal = np.array(flat_section(coeffs, self.names))
        sigma = np.array(flat_section(coeffs["uncertainty"], self.names))
        rel = np.array([is_relative(n) for n in self.names])
        rng = np.random.default_rng(seed)
        rates_ = np.where(rel, sigma / np.abs(nominal), sigma) * rng.uniform(0.3, 3.0, len(nominal))
        lo, hi = (w * 7 / MONTH_DAYS for w in rates.version_weeks)
        self.sim = simulate_fleet(self.names, nominal, rates_, sigma, units=units, years=years,
                                  interval_months=(lo, hi), outliers=max(1, units // 100),
                                  seed=seed)  # fmt: skip
        self.rng = rng
        self.units = [
            UnitPlan(i, f"{MODELS[i % 3]}-SN{i:04d}", MODELS[i % 3], f"bench-unit-token-{i:05d}")
            for i in range(units)
        ]
        self._events = _event_templates()
        self._slew = _slew_template()

    def plan(self, u: UnitPlan) -> UnitPlan:
        """Fill ``u``'s versions (documents as JSON text) and window templates."""
        table = self.sim.versions
        rows = np.flatnonzero(table.unit == u.index)
        rng = np.random.default_rng(1000 + u.index)
        entries: list[tuple[datetime, bool, np.ndarray, np.ndarray]] = []
        for k, r in enumerate(rows):
            at = START + timedelta(days=float(table.months[r]) * MONTH_DAYS, hours=3)
            if k and rng.random() < self.rates.rejected / (1 - self.rates.rejected):
                # a rejected attempt before this accepted one: a jump the gate refused
                before = at - timedelta(days=rng.uniform(1, 6))
                jump = table.values[r] + 8 * table.sigma[r] * rng.standard_normal(len(self.names))
                entries.append((before, False, jump, table.sigma[r]))
            entries.append((at, True, table.values[r], table.sigma[r]))
        entries.sort(key=lambda e: e[0])
        last_ok: dict[str, Any] | None = None
        accepted_before: int | None = None
        for number, (at, ok, values, sigma) in enumerate(entries, start=1):
            doc = self.document(number, at, ok, values, sigma, accepted_before, rng)
            u.versions.append((number, at, ok, json.dumps(doc, separators=(",", ":"))))
            if ok:
                accepted_before, last_ok = number, doc
        if last_ok is not None:
            u.windows = self.window_templates(last_ok, u.index)
        return u

    def document(self, number, at, ok, values, sigma, prior, rng) -> dict[str, Any]:
        doc = copy.deepcopy(self.template)
        when = at.isoformat().replace("+00:00", "Z")
        doc.update(version=number, created_at=when, accepted=ok, prior_version=prior,
                   trigger=str(rng.choice(["information", "drift", "count", "schedule"])))  # fmt: skip
        if not ok:
            doc["reasons"] = ["gyro.bias.bz jumped 8.1 sigma since version "
                              f"{prior} (limit 5.0, ageing allowed: none)"]  # fmt: skip
        calib = doc["document"]
        set_flat(calib["coefficients"], self.names, values)
        set_flat(calib["coefficients"]["uncertainty"], self.names, sigma)
        set_flat(calib["uncertainty"], self.names, sigma)
        calib["chi2_red"] = float(rng.uniform(0.6, 1.6))
        calib["positions"] = int(rng.integers(8, 40))
        doc["positions_used"] = list(range(1, calib["positions"] + 1))
        return doc

    def window_templates(self, doc: dict[str, Any], seed: int) -> list[dict[str, Any]]:
        calib = doc["document"]
        truth = CoefficientSet.from_json_dict(calib["coefficients"], source="bench")
        p = simulate_positions(truth, design="random", n_positions=self.rates.template_windows,
                               latitude_deg=calib["latitude_deg"], seed=seed)  # fmt: skip
        out = []
        for i in range(len(p)):
            row = {n: float(v[i]) for n, v in p.columns.items()}
            for s in ("gyro", "accel"):
                for a in "xyz":
                    row[f"{s}_{a}_sem"] = row[f"{s}_{a}_std"] / np.sqrt(row["samples"])
            row.update(frames_lost=0.0, frames_invalid=0.0, gyro_still=1.0)
            out.append(row)
        return out

    # ---- one unit's rows in wire format, in time order (the measured ingest) ----------------
    def wire_rows(self, u: UnitPlan) -> Iterator[dict[str, Any]]:
        r = self.rates
        versions = iter(u.versions)
        pending = next(versions, None)
        rng = np.random.default_rng(2000 + u.index)
        for d in range(self.days):
            day = START + timedelta(days=d)
            if d % r.session_days == 0:
                yield _row("session", d // r.session_days + 1, day, session_data(d, r, day))
            todays = []
            while pending is not None and pending[1] < day + timedelta(days=1):
                todays.append(pending)
                pending = next(versions, None)
            for k in range(r.windows):
                at = day + timedelta(days=(k + rng.random()) / r.windows)
                wid = d * r.windows + k + 1
                yield _row("window", wid, at, window_data(u.windows, wid, d, k, r))
                if k < r.slews:
                    yield _row("slew", d * r.slews + k + 1, at, slew_data(self._slew, wid))
            for j, (kind, message, data) in enumerate(self._events):
                at = day + timedelta(days=(j + 0.5) / len(self._events))
                yield _row("event", d * r.events + j + 1, at,
                           event_data(kind, message, data, round(float(rng.random()) * 10, 4), at))  # fmt: skip
            for number, at, _ok, text in todays:
                yield {"kind": "version", "id": number, "at": _iso(at), "data": json.loads(text)}


def _iso(t: datetime) -> str:
    return t.isoformat().replace("+00:00", "Z")


def _row(kind: str, ident: int, at: datetime, data: dict[str, Any]) -> dict[str, Any]:
    return {"kind": kind, "id": ident, "at": _iso(at), "data": data}


def session_data(d: int, r: Rates, day: datetime) -> dict[str, Any]:
    return {"source": "serial:///dev/ttyUSB0?baud=921600&format=kvh-a",
            "meta": {"device": "KVH-1750", "rate_hz": 1000, "session_day": d},
            "started_at": _iso(day)}  # fmt: skip


def window_data(templates, wid: int, d: int, k: int, r: Rates) -> dict[str, Any]:
    row = dict(templates[wid % len(templates)])
    start = ((d % r.session_days) * r.windows + k) * 7200.0
    row.update(start_s=start, end_s=start + 600.0, session=d // r.session_days + 1)
    return row


def slew_data(template: dict[str, Any], wid: int) -> dict[str, Any]:
    return {**template, "first_id": wid, "second_id": wid + 1}


def event_data(kind: str, message: str, data: dict[str, Any], x: float, at: datetime):
    data = {**data, "statistic": x} if kind == "drift" else data
    return {"kind": kind, "message": message, "data": data, "created_at": _iso(at)}


def _slew_template() -> dict[str, Any]:
    rng = np.random.default_rng(5)
    values = [round(float(v), 9) for v in rng.standard_normal(3 + 12 * 10)]
    return {"period_s": 0.001, "samples": 30000, "groups": 12, "dropped": None, "data": values}


def _event_templates() -> list[tuple[str, str, dict[str, Any]]]:
    """A day's 20 events: 12 drift tests, 4 information checks, 2 detector, 2 noise notes."""
    drift = {"version": 7, "threshold": 16.2131, "windows": 30, "first_id": 5, "last_id": 34,
             "last_end_s": 7799.95, "alarm_window": None, "alarm_id": None, "change_id": 8,
             "suspect": "accel misalignment Eyx, about +1.24e+04 micro-rad",
             "windows_per_day": 12.0, "windows_per_day_measured": True}  # fmt: skip
    info = {"trigger": "information", "gain": 0.12, "coefficient": "gyro.bias.bz",
            "windows": 8, "slews": 0, "threshold": 0.25}  # fmt: skip
    out = [("drift", "steady: statistic over 30 windows since version 7", drift)] * 12
    out += [("information", "no trigger: gyro.bias.bz 1-sigma would fall 12 % (25 %)", info)] * 4
    out += [("detector", "still period ended: 2 windows stored", {"windows": 2})] * 2
    out += [("noise", "noise floor updated", {"device": "kvh", "arw": 0.0007})] * 2
    return out


# ---- batches as a vessel sends them ----------------------------------------------------------
def batches(serial: str, rows: Iterator[dict[str, Any]]) -> Iterator[bytes]:
    """Format-1 batches (JSON, uncompressed): at most BATCH_ROWS rows and about BATCH_BYTES."""
    head = {"format": 1, "unit": serial, "sent_at": "2026-11-27T01:00:00Z"}
    part, size = [], 0
    for r in rows:
        text = json.dumps(r, separators=(",", ":"))
        if part and (len(part) >= BATCH_ROWS or size + len(text) > BATCH_BYTES):
            yield _body(head, part)
            part, size = [], 0
        part.append(text)
        size += len(text) + 1
    if part:
        yield _body(head, part)


def _body(head: dict[str, Any], rows: list[str]) -> bytes:
    return (json.dumps(head)[:-1] + ', "rows": [' + ",".join(rows) + "]}").encode()


# ---- database --------------------------------------------------------------------------------
def _admin():
    import psycopg
    from sqlalchemy.engine import make_url

    url = make_url(PG_SERVER).set(drivername="postgresql", database="postgres")
    return psycopg.connect(url.render_as_string(hide_password=False), autocommit=True)


@contextlib.contextmanager
def database(url: str | None, keep: bool) -> Iterator[str]:
    """``url``, or a throwaway database created here and dropped after (unless ``keep``)."""
    if url is not None:
        yield url
        return
    from psycopg import sql
    from sqlalchemy.engine import make_url

    name = f"recal_bench_fleet_{secrets.token_hex(4)}"
    with _admin() as admin:
        admin.execute(sql.SQL("CREATE DATABASE {}").format(sql.Identifier(name)))
    made = make_url(PG_SERVER).set(drivername="postgresql+psycopg", database=name)
    try:
        yield made.render_as_string(hide_password=False)
    finally:
        if keep:
            print(f"kept database {name}")
        else:
            with _admin() as admin:
                admin.execute(sql.SQL("DROP DATABASE {} WITH (FORCE)").format(sql.Identifier(name)))


def psycopg_url(url: str) -> str:
    from sqlalchemy.engine import make_url

    return make_url(url).set(drivername="postgresql").render_as_string(hide_password=False)


def add_units(conn, fleet: Fleet) -> None:
    now = datetime.now(UTC)
    with conn.cursor().copy(
        "COPY fleet_units (id, serial, model, token_hash, created_at) FROM STDIN"
    ) as cp:
        for u in fleet.units:
            cp.write_row((u.index + 1, u.serial, u.model, token_hash(u.token), now))
    conn.execute("SELECT setval('fleet_units_id_seq', (SELECT max(id) FROM fleet_units))")


# ---- ingest (measured) -----------------------------------------------------------------------
@dataclass
class IngestFigures:
    rows: int = 0
    batches: int = 0
    raw_bytes: int = 0
    gz_bytes: int = 0
    seconds: float = 0.0

    def line(self, what: str) -> str:
        s = max(self.seconds, 1e-9)
        return (f"{what}: {self.rows} rows in {self.batches} batches, {self.seconds:.1f} s: "
                f"{self.rows / s:,.0f} rows/s, {self.batches / s:.1f} batches/s "
                f"({self.raw_bytes / 2**20:.1f} MiB JSON, {self.gz_bytes / 2**20:.1f} MiB gzip)")  # fmt: skip


def ingest_store(store: FleetStore, fleet: Fleet, units: list[UnitPlan]) -> IngestFigures:
    """Every row of ``units`` through FleetStore.ingest, batch after batch; only the store's
    calls are timed (parsing included: ``read_batch`` as the API does)."""
    fig = IngestFigures()
    for u in units:
        unit = Unit(u.index + 1, u.serial, u.model)
        for raw in batches(u.serial, fleet.wire_rows(u)):
            gz = gzip.compress(raw, 6)
            t0 = time.perf_counter()
            batch = read_batch(gz, "gzip", 4 * 2**20)
            stored, *_ = store.ingest(unit, batch, len(gz))
            fig.seconds += time.perf_counter() - t0
            fig.rows += stored
            fig.batches += 1
            fig.raw_bytes += len(raw)
            fig.gz_bytes += len(gz)
    return fig


def ingest_http(base: str, fleet: Fleet, units: list[UnitPlan]) -> IngestFigures:
    import httpx

    fig = IngestFigures()
    with httpx.Client(timeout=60) as client:
        for u in units:
            headers = {"Authorization": f"Bearer {u.token}", "Content-Type": "application/json",
                       "Content-Encoding": "gzip"}  # fmt: skip
            for raw in batches(u.serial, fleet.wire_rows(u)):
                gz = gzip.compress(raw, 6)
                t0 = time.perf_counter()
                answer = client.post(f"{base}/fleet/ingest", content=gz, headers=headers)
                fig.seconds += time.perf_counter() - t0
                answer.raise_for_status()
                fig.rows += answer.json()["stored"]
                fig.batches += 1
                fig.raw_bytes += len(raw)
                fig.gz_bytes += len(gz)
    return fig


# ---- bulk load (not the ingest figure) ------------------------------------------------------
SECONDARY = {  # dropped during the bulk load, built after it
    "fleet_windows": ["ix_fleet_windows_unit_at_id"],
    "fleet_events": ["ix_fleet_events_unit_at_id", "ix_fleet_events_kind_at"],
    "fleet_slews": ["ix_fleet_slews_unit_at_id"],
    "fleet_ingest_log": ["ix_fleet_ingest_log_unit_at"],
}


UNIT_COUNTS = """
    UPDATE fleet_units SET
      n_versions = (SELECT count(*) FROM fleet_versions v WHERE v.unit_id = fleet_units.id),
      n_rejected = (SELECT count(*) FROM fleet_versions v
                    WHERE v.unit_id = fleet_units.id AND NOT v.accepted),
      n_windows = (SELECT count(*) FROM fleet_windows w WHERE w.unit_id = fleet_units.id),
      current_version = (SELECT v.vessel_id FROM fleet_versions v
                         WHERE v.unit_id = fleet_units.id AND v.accepted
                         ORDER BY v.at DESC, v.vessel_id DESC LIMIT 1),
      current_at = (SELECT v.at FROM fleet_versions v
                    WHERE v.unit_id = fleet_units.id AND v.accepted
                    ORDER BY v.at DESC, v.vessel_id DESC LIMIT 1),
      current_instance = '', instance = ''
    WHERE id BETWEEN %s AND %s"""  # as ingest keeps them (the newest accepted by time)


def fill_unit_state(conn: Any) -> None:
    """What ingest keeps for the overview (the unit's newest rows, the link's days), computed
    from the rows by migration 0009's own statements: the bulk load bypasses ingest."""
    import importlib

    state = importlib.import_module("service.fleet.migrations.versions.0009_unit_state")
    conn.execute(state.FILL_UNITS)
    conn.execute("DELETE FROM fleet_link_days")
    conn.execute(state.FILL_DAYS.format(day=state.DAY["postgresql"]))


def bulk_load(url: str, fleet: Fleet, units: list[UnitPlan], chunk_days: int) -> dict[str, Any]:
    """Every row of ``units`` written by PostgreSQL itself, in time order across units: the
    same rows ``Fleet.wire_rows`` sends (versions by COPY of their documents)."""
    import psycopg

    if not units:
        return {}
    t_all = time.perf_counter()
    r = fleet.rates
    ids = [u.index + 1 for u in units]
    lo, hi = min(ids), max(ids)
    assert ids == list(range(lo, hi + 1))
    with psycopg.connect(psycopg_url(url), autocommit=True) as conn:
        definitions = {}
        for names in SECONDARY.values():
            for name in names:
                definitions[name] = conn.execute(
                    "SELECT indexdef FROM pg_indexes WHERE indexname = %s", (name,)
                ).fetchone()[0]
                conn.execute(f"DROP INDEX {name}")
        # the templates: windows per unit, the day's events, the slew
        conn.execute("CREATE TABLE bench_window_tpl (unit_id int, tk int, data jsonb)")
        with conn.cursor().copy("COPY bench_window_tpl FROM STDIN") as cp:
            for u in units:
                for k, w in enumerate(u.windows):
                    cp.write_row((u.index + 1, k, json.dumps(w)))
        conn.execute("CREATE TABLE bench_event_tpl (j int, kind text, message text, data jsonb)")
        with conn.cursor().copy("COPY bench_event_tpl FROM STDIN") as cp:
            for j, (kind, message, data) in enumerate(fleet._events):
                cp.write_row((j, kind, message, json.dumps(data)))
        conn.execute("ANALYZE bench_window_tpl; ANALYZE bench_event_tpl")
        slew = json.dumps(fleet._slew)
        n_tpl = r.template_windows
        counts = dict.fromkeys(["session", "window", "slew", "event", "version", "ingest_log"], 0)
        start = START.isoformat()
        t0 = time.perf_counter()
        for d0 in range(0, fleet.days, chunk_days):
            d1 = min(fleet.days, d0 + chunk_days) - 1
            p = {"d0": d0, "d1": d1, "lo": lo, "hi": hi, "start": start, "w": r.windows,
                 "s": r.slews, "e": r.events, "sd": r.session_days, "ntpl": n_tpl, "slew": slew,
                 "b": r.batches}  # fmt: skip
            day = "(%(start)s::timestamptz + d * interval '1 day')"
            counts["session"] += conn.execute(f"""
                INSERT INTO fleet_sessions (unit_id, vessel_id, at, received_at, data)
                SELECT u, d / %(sd)s::int + 1, {day}, {day} + interval '1 hour',
                       jsonb_build_object('source', 'serial:///dev/ttyUSB0?baud=921600&format=kvh-a',
                         'meta', jsonb_build_object('device', 'KVH-1750', 'rate_hz', 1000,
                                                    'session_day', d),
                         'started_at', to_char({day} AT TIME ZONE 'UTC', 'YYYY-MM-DD"T"HH24:MI:SS"Z"'))
                FROM generate_series(%(d0)s::int, %(d1)s::int) d, generate_series(%(lo)s::int, %(hi)s::int) u
                WHERE d %% %(sd)s::int = 0""", p).rowcount  # fmt: skip
            counts["window"] += conn.execute(f"""
                INSERT INTO fleet_windows (unit_id, vessel_id, at, received_at, data)
                SELECT u, d * %(w)s::int + k + 1, t, t + interval '1 hour',
                       tpl.data || jsonb_build_object('start_s', ((d %% %(sd)s::int) * %(w)s::int + k) * 7200.0,
                         'end_s', ((d %% %(sd)s::int) * %(w)s::int + k) * 7200.0 + 600.0,
                         'session', d / %(sd)s::int + 1)
                FROM generate_series(%(d0)s::int, %(d1)s::int) d, generate_series(%(lo)s::int, %(hi)s::int) u,
                     generate_series(0, %(w)s::int - 1) k,
                     LATERAL (SELECT {day} + (k + random()) * interval '1 day' / %(w)s::int AS t) tt,
                     bench_window_tpl tpl
                WHERE tpl.unit_id = u AND tpl.tk = (d * %(w)s::int + k + 1) %% %(ntpl)s::int""", p).rowcount  # fmt: skip
            counts["slew"] += conn.execute(f"""
                INSERT INTO fleet_slews (unit_id, vessel_id, at, received_at, data)
                SELECT u, d * %(s)s::int + k + 1, {day} + (k + 0.5) * interval '1 day' / %(w)s::int,
                       {day} + interval '1 hour',
                       %(slew)s::jsonb || jsonb_build_object('first_id', d * %(w)s::int + k + 1,
                                                             'second_id', d * %(w)s::int + k + 2)
                FROM generate_series(%(d0)s::int, %(d1)s::int) d, generate_series(%(lo)s::int, %(hi)s::int) u,
                     generate_series(0, %(s)s::int - 1) k""", p).rowcount  # fmt: skip
            counts["event"] += conn.execute(f"""
                INSERT INTO fleet_events (unit_id, vessel_id, at, received_at, data, kind)
                SELECT u, d * %(e)s::int + j + 1, t, t + interval '1 hour',
                       jsonb_build_object('kind', e.kind, 'message', e.message,
                         'data', CASE WHEN e.kind = 'drift' THEN e.data || jsonb_build_object(
                                   'statistic', round((random() * 10)::numeric, 4))
                                 ELSE e.data END,
                         'created_at', to_char(t AT TIME ZONE 'UTC', 'YYYY-MM-DD"T"HH24:MI:SS"Z"')),
                       e.kind
                FROM generate_series(%(d0)s::int, %(d1)s::int) d, generate_series(%(lo)s::int, %(hi)s::int) u,
                     bench_event_tpl e,
                     LATERAL (SELECT {day} + (e.j + 0.5) * interval '1 day' / %(e)s::int AS t) tt""",
                p).rowcount  # fmt: skip
            counts["ingest_log"] += conn.execute(f"""
                INSERT INTO fleet_ingest_log (unit_id, at, compressed_bytes, rows, stored)
                SELECT u, {day} + (b + 1) * interval '1 day' / %(b)s::int,
                       3000 + (random() * 30000)::int, 8, 8
                FROM generate_series(%(d0)s::int, %(d1)s::int) d, generate_series(%(lo)s::int, %(hi)s::int) u,
                     generate_series(0, %(b)s::int - 1) b""", p).rowcount  # fmt: skip
            done = d1 + 1
            rate = sum(counts.values()) / (time.perf_counter() - t0)
            print(f"  bulk: day {done}/{fleet.days}, {sum(counts.values()):,} rows, "
                  f"{rate:,.0f} rows/s", flush=True)  # fmt: skip
        t_rows = time.perf_counter() - t0
        t1 = time.perf_counter()
        with conn.cursor().copy(
            "COPY fleet_versions (unit_id, vessel_id, at, received_at, data, accepted, trigger,"
            " method, flat, heading_error_deg_rms, reasons) FROM STDIN"
        ) as cp:
            for u in units:
                for number, at, ok, text in u.versions:
                    doc = json.loads(text)
                    flat = json.dumps(flat_version(doc["document"], coefficient_names()))
                    shown = overview_columns(doc)
                    reasons = None if shown["reasons"] is None else json.dumps(shown["reasons"])
                    cp.write_row((u.index + 1, number, at, at + timedelta(hours=1), text, ok,
                                  doc["trigger"], doc["method"], flat,
                                  shown["heading_error_deg_rms"], reasons))  # fmt: skip
                    counts["version"] += 1
        t_versions = time.perf_counter() - t1
        t2 = time.perf_counter()
        for definition in definitions.values():
            conn.execute(definition)
        conn.execute("DROP TABLE bench_window_tpl, bench_event_tpl")
        conn.execute(UNIT_COUNTS, (lo, hi))  # what ingest keeps on the unit's row (0003)
        fill_unit_state(conn)  # and for the overview (0009)
        conn.execute("UPDATE fleet_units SET last_contact = %s WHERE id BETWEEN %s AND %s",
                     (START + timedelta(days=fleet.days), lo, hi))  # fmt: skip
        t_index = time.perf_counter() - t2
        t3 = time.perf_counter()
        conn.execute("VACUUM ANALYZE")
        t_vacuum = time.perf_counter() - t3
    total = sum(counts.values())
    print(f"bulk load (PostgreSQL generate_series, not the ingest figure): {total:,} rows in "
          f"{t_rows:.0f} s ({total / max(t_rows, 1e-9):,.0f} rows/s), versions by COPY "
          f"{t_versions:.0f} s, indexes {t_index:.0f} s, VACUUM ANALYZE {t_vacuum:.0f} s, "
          f"in all {time.perf_counter() - t_all:.0f} s")  # fmt: skip
    return counts


# ---- the server, the queries -----------------------------------------------------------------
def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def serve(url: str, folder: Path) -> Iterator[str]:
    """A real ``recal fleet serve`` on a free port; its base URL."""
    import httpx

    port = free_port()
    config = folder / "shore.toml"
    config.write_text(f'database_url = "{url}"\n\n[api]\nhost = "127.0.0.1"\nport = {port}\n'
                      f'token = "{ADMIN_TOKEN}"\n')  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "service.cli.main", "fleet", "serve",
                             "--config", str(config)], env=env, stderr=subprocess.PIPE)  # fmt: skip
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 1800  # its migrations, on a loaded database
        while True:
            try:
                if httpx.get(f"{base}/openapi.json", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"recal fleet serve did not start: {proc.stderr.read()!r}")
            time.sleep(0.2)
        yield base
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()


def stats(times: list[float]) -> tuple[float, float, float]:
    a = np.asarray(times)
    return float(np.median(a)), float(np.percentile(a, 95)), float(a.max())


def measure_queries(base: str, fleet: Fleet, repeat: int, extra: bool) -> list[tuple]:
    """Each API query ``repeat`` times on random units and times: (name, median, p95, max,
    bytes of the last answer)."""
    import httpx

    rng = np.random.default_rng(11)
    headers = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
    span = timedelta(days=fleet.days)

    def unit() -> str:
        return fleet.units[int(rng.integers(len(fleet.units)))].serial

    def when() -> str:
        return _iso(START + span * float(rng.uniform(0.0, 1.0)))

    queries: list[tuple[str, Any]] = [
        ("GET /fleet/units", lambda: ("/fleet/units", {})),
        ("GET /fleet/units/{unit}", lambda: (f"/fleet/units/{unit()}", {})),
        ("GET /fleet/units/{unit}/versions", lambda: (f"/fleet/units/{unit()}/versions", {})),
        ("GET /fleet/units/{unit}/windows?since=", lambda: (
            f"/fleet/units/{unit()}/windows", {"since": when()})),
        ("GET /fleet/units/{unit}/events?since=&kind=drift", lambda: (
            f"/fleet/units/{unit()}/events", {"since": when(), "kind": "drift"})),
        ("GET /fleet/units/{unit}/events?since=", lambda: (
            f"/fleet/units/{unit()}/events", {"since": when()})),
        ("GET /fleet/versions?model=&since=", lambda: (
            "/fleet/versions", {"model": MODELS[int(rng.integers(3))], "since": when()})),
    ]  # fmt: skip
    if extra:
        queries += [
            ("GET /fleet/overview", lambda: ("/fleet/overview", {})),
            ("GET /fleet/prior?model=", lambda: (
                "/fleet/prior", {"model": MODELS[int(rng.integers(3))]})),
        ]  # fmt: skip
    out = []
    with httpx.Client(base_url=base, headers=headers, timeout=120) as client:
        for name, make in queries:
            times, size, status = [], 0, 200
            for i in range(repeat + 1):
                path, params = make()
                t0 = time.perf_counter()
                answer = client.get(path, params=params)
                took = time.perf_counter() - t0
                status = answer.status_code
                if status != 200:
                    break
                size = len(answer.content)
                if i:  # the first one warms the connection
                    times.append(took)
            if status != 200:
                out.append((name, None, None, None, status))
                print(f"  {name:48s} HTTP {status}: not measured")
                continue
            med, p95, worst = stats(times)
            verdict = "PASS" if p95 < TARGET_S else "MISS"
            out.append((name, med, p95, worst, size))
            print(f"  {name:48s} median {med * 1e3:7.1f} ms  p95 {p95 * 1e3:7.1f} ms  "
                  f"max {worst * 1e3:7.1f} ms  ({size / 1e3:.0f} kB)  {verdict}", flush=True)  # fmt: skip
    return out


def storage(url: str) -> None:
    import psycopg

    with psycopg.connect(psycopg_url(url)) as conn:
        rows = conn.execute("""
            SELECT c.relname, c.reltuples::bigint, pg_relation_size(c.oid),
                   pg_total_relation_size(c.oid) - pg_relation_size(c.oid) - pg_indexes_size(c.oid),
                   pg_indexes_size(c.oid), pg_total_relation_size(c.oid)
            FROM pg_class c JOIN pg_namespace n ON n.oid = c.relnamespace
            WHERE n.nspname = 'public' AND c.relkind IN ('r', 'p') AND c.relname LIKE 'fleet_%%'
            ORDER BY pg_total_relation_size(c.oid) DESC""").fetchall()  # fmt: skip
        db = conn.execute("SELECT pg_database_size(current_database())").fetchone()[0]
    print("storage (pg_total_relation_size = table + TOAST + indexes):")
    print(f"  {'table':18s} {'rows':>12s} {'table':>10s} {'toast':>10s} {'indexes':>10s} "
          f"{'total':>10s} {'per row':>8s}")  # fmt: skip
    for name, n, heap, toast, idx, total in rows:
        per = total / n if n > 0 else 0
        print(f"  {name:18s} {n:12,d} {_mb(heap)} {_mb(toast)} {_mb(idx)} {_mb(total)} "
              f"{per:7.0f}B")  # fmt: skip
    print(f"  database: {_mb(db)}")


def _mb(n: int) -> str:
    return f"{n / 2**20:8.0f}MB" if n >= 2**20 else f"{n / 2**10:8.1f}kB"


def reanalysis(url: str, workers: list[int], limit_units: int | None) -> None:
    from service.fleet.reanalysis import reanalyse

    took = {}
    for n in workers:
        t0 = time.perf_counter()
        report = reanalyse(url, workers=n, units=limit_units)
        took[n] = time.perf_counter() - t0
        flagged = [u["unit"] for u in report["units"] if u["outlier"]]
        alarms = [u["unit"] for u in report["units"] if u.get("drift_alarm")]
        print(f"  {n} worker(s): {len(report['units'])} units, {report['versions']} versions, "
              f"{report['windows']} windows in {took[n]:.1f} s; outliers {len(flagged)}, "
              f"drift alarms {len(alarms)}", flush=True)  # fmt: skip
    if 1 in took and 2 in took:
        print(f"  speed-up 1 -> 2 workers: {took[1] / took[2]:.2f}x")


def load_versions(url: str, fleet: Fleet) -> None:
    """Only the units and their versions (COPY, with the flat part ingest keeps): ``--prior``."""
    import psycopg

    with psycopg.connect(psycopg_url(url), autocommit=True) as conn:
        add_units(conn, fleet)
        t0 = time.perf_counter()
        with conn.cursor().copy(
            "COPY fleet_versions (unit_id, vessel_id, at, received_at, data, accepted, trigger,"
            " method, flat, heading_error_deg_rms, reasons) FROM STDIN"
        ) as cp:
            for u in fleet.units:
                for number, at, ok, text in u.versions:
                    doc = json.loads(text)
                    flat = json.dumps(flat_version(doc["document"], coefficient_names()))
                    shown = overview_columns(doc)
                    reasons = None if shown["reasons"] is None else json.dumps(shown["reasons"])
                    cp.write_row((u.index + 1, number, at, at + timedelta(hours=1), text, ok,
                                  doc["trigger"], doc["method"], flat,
                                  shown["heading_error_deg_rms"], reasons))  # fmt: skip
        conn.execute(UNIT_COUNTS, (1, len(fleet.units)))
        conn.execute("VACUUM ANALYZE")
    print(f"versions loaded by COPY in {time.perf_counter() - t0:.0f} s", flush=True)


def load_overview(url: str, fleet: Fleet) -> None:
    """What ``GET /fleet/overview`` reads, at the fleet's full depth (``--overview``): the units
    and their versions (COPY of the documents, as ``load_versions``), a drift evaluation per unit
    and day (the newest is the row's drift state; the daemon's other 19 events of a day share
    the index and are not read) and the ingest log (a batch every 4 hours: the link's last days
    and the backlog of the last batch). Windows and slews are not loaded: the overview reads
    only their count, kept on the unit's row."""
    import psycopg

    load_versions(url, fleet)
    t0 = time.perf_counter()
    drift = json.dumps(_event_templates()[0][2])
    p = {"days": fleet.days, "n": len(fleet.units), "start": START.isoformat(), "drift": drift,
         "b": fleet.rates.batches}  # fmt: skip
    day = "(%(start)s::timestamptz + d * interval '1 day')"
    with psycopg.connect(psycopg_url(url), autocommit=True) as conn:
        events = conn.execute(f"""
            INSERT INTO fleet_events (unit_id, vessel_id, at, received_at, data, kind)
            SELECT u, d * 20 + 1, t, t + interval '1 hour',
                   jsonb_build_object('kind', 'drift', 'message', 'steady',
                     'data', %(drift)s::jsonb || jsonb_build_object(
                        'statistic', round((random() * 10)::numeric, 4),
                        'alarm_window', CASE WHEN random() < 0.02 THEN 30 END),
                     'created_at', to_char(t AT TIME ZONE 'UTC', 'YYYY-MM-DD"T"HH24:MI:SS"Z"')),
                   'drift'
            FROM generate_series(0, %(days)s::int - 1) d, generate_series(1, %(n)s::int) u,
                 LATERAL (SELECT {day} + random() * interval '1 day' AS t) tt
            ORDER BY d, u""", p).rowcount  # fmt: skip
        log = conn.execute(f"""
            INSERT INTO fleet_ingest_log (unit_id, at, compressed_bytes, rows, stored, backlog)
            SELECT u, {day} + (b + 1) * interval '1 day' / %(b)s::int,
                   3000 + (random() * 30000)::int, 8, 8, (random() * 40)::int
            FROM generate_series(0, %(days)s::int - 1) d, generate_series(1, %(n)s::int) u,
                 generate_series(0, %(b)s::int - 1) b""", p).rowcount  # fmt: skip
        conn.execute("UPDATE fleet_units SET last_contact = %s",
                     (START + timedelta(days=fleet.days),))  # fmt: skip
        conn.execute("VACUUM ANALYZE")
    print(f"drift events {events:,} and ingest log {log:,} rows loaded in "
          f"{time.perf_counter() - t0:.0f} s", flush=True)  # fmt: skip


#: The shore before migration 0009 (the overview looking each unit's newest rows up, 0008's
#: columns; before 0008, ef908de, it read the version documents): ``--overview``'s "before".
OVERVIEW_BEFORE = "efa7be2"


def module_before(path: str) -> Any:
    """``path`` (a module of the repository) as it was at OVERVIEW_BEFORE, loaded apart."""
    import types

    text = subprocess.run(["git", "show", f"{OVERVIEW_BEFORE}:{path}"], cwd=ROOT, check=True,
                          capture_output=True, text=True).stdout  # fmt: skip
    module = types.ModuleType(f"before_{Path(path).stem}")
    sys.modules[module.__name__] = module  # its dataclasses look themselves up there
    exec(compile(text, f"{path}@{OVERVIEW_BEFORE}", "exec"), module.__dict__)  # noqa: S102
    return module


def overview_timing(url: str, runs: int) -> None:
    """``GET /fleet/overview`` through the app (FastAPI's TestClient: the route and its JSON
    encoding, no network) as it was before migration 0009 (service/fleet/api.py and
    overview.py at OVERVIEW_BEFORE) and as it is, alternately ``runs`` times each after one
    warm-up call each, on the same database; first migrations 0008 and 0009 (adding and
    filling what the overview reads) timed on these rows, and the two answers compared at the
    same ``now``."""
    import hashlib

    from alembic import command
    from fastapi.testclient import TestClient

    from service.fleet.api import create_app
    from service.fleet.config import ShoreApiSettings
    from service.fleet.migrations import alembic_config
    from service.fleet.overview import overview as after
    from service.fleet.priors import FleetPriors

    store = FleetStore(url)
    with store._engine.connect() as conn, conn.begin():
        command.downgrade(alembic_config(conn), "0007")
    t0 = time.perf_counter()
    store.create_schema()
    print(f"migrations 0008 and 0009 (add and fill what the overview reads): "
          f"{time.perf_counter() - t0:.1f} s", flush=True)  # fmt: skip
    import psycopg

    with psycopg.connect(psycopg_url(url), autocommit=True) as conn:  # as autovacuum would
        conn.execute("VACUUM ANALYZE fleet_versions")
        conn.execute("VACUUM ANALYZE fleet_units")
    old_api = module_before("service/fleet/api.py")
    before = old_api.fleet_overview = module_before("service/fleet/overview.py").overview
    priors = FleetPriors(store)
    priors.current(list(MODELS))  # computed once and stored, as a running shore has them
    now = datetime.now(UTC)
    same = before(store, priors, now=now) == after(store, priors, now=now)
    print(f"the same answer before and after: {same}", flush=True)
    settings = ShoreApiSettings(token_sha256=hashlib.sha256(ADMIN_TOKEN.encode()).hexdigest())
    times: dict[str, list[float]] = {"before": [], "after": []}
    apps = {"before": old_api.create_app(store, settings), "after": create_app(store, settings)}
    headers = {"Authorization": f"Bearer {ADMIN_TOKEN}"}
    with TestClient(apps["before"]) as old, TestClient(apps["after"]) as new:
        answers = {}
        for i in range(runs + 1):
            for name, client in (("before", old), ("after", new)):
                t0 = time.perf_counter()
                answer = client.get("/fleet/overview", headers=headers)
                took = time.perf_counter() - t0
                answer.raise_for_status()
                answers[name] = answer.content
                if i:  # the first of each warms the caches
                    times[name].append(took)
    size = len(answers["after"])
    load = os.getloadavg()
    print(f"GET /fleet/overview ({size / 1e6:.1f} MB), {runs} runs each, alternately, load "
          f"average {load[0]:.2f}; target p95 <= 300 ms:", flush=True)  # fmt: skip
    for name, label in (("before", "before (per-unit lookups)"),
                        ("after", "after (0009's unit state)")):  # fmt: skip
        med, p95, worst = stats(times[name])
        verdict = "PASS" if p95 <= 0.3 else "MISS"
        print(f"  {label:28s} median {med * 1e3:7.1f} ms  p95 {p95 * 1e3:7.1f} ms  "
              f"max {worst * 1e3:7.1f} ms  {verdict}", flush=True)  # fmt: skip
    store.close()


def prior_from_documents(store: FleetStore, models: list[str]) -> dict[str, dict[str, Any]]:
    """The fleet prior as service.fleet.priors computed it before migration 0006: from every
    accepted version's document (its coefficients and uncertainty selected out of it)."""
    from collections import defaultdict

    from sqlalchemy import select

    from recal.fleet.compute import fleet_prior
    from recal.fleet.history import VersionTable
    from service.fleet.schema import UnitRow, VersionRow

    names = coefficient_names()
    query = (
        select(UnitRow.model, UnitRow.serial, VersionRow.at,
               VersionRow.data[("document", "coefficients")],
               VersionRow.data[("document", "uncertainty")])
        .join(UnitRow, UnitRow.id == VersionRow.unit_id)
        .where(VersionRow.accepted.is_(True), UnitRow.model.in_(models))
        .order_by(UnitRow.model, UnitRow.serial, VersionRow.at)
    )  # fmt: skip
    rows: dict[str, dict[str, list[Any]]] = {m: defaultdict(list) for m in models}
    with store._tx() as s:
        for model, serial, at, coefficients, uncertainty in s.execute(query):
            rows[model][serial].append(
                (at.astimezone(UTC), {"coefficients": coefficients, "uncertainty": uncertainty})
            )
    out = {}
    for model in models:
        table = VersionTable.from_documents(names, rows[model])
        out[model] = fleet_prior(table, model, created_at="-").to_json_dict()
    return out


def prior_recompute(url: str, runs: int) -> None:
    """The fleet prior of every model recomputed (what the first request after a new accepted
    version pays), from the documents (before 0006) and from ``fleet_versions.flat`` (after),
    alternately ``runs`` times; then migration 0006's backfill of the rows stored."""
    from alembic import command
    from sqlalchemy import delete, func, select, update

    from service.fleet.migrations import alembic_config
    from service.fleet.priors import FleetPriors
    from service.fleet.schema import PriorRow, VersionRow

    store = FleetStore(url)
    with store._tx() as s:
        accepted = s.scalar(select(func.count()).where(VersionRow.accepted.is_(True)))
        stored = s.scalar(select(func.count()).select_from(VersionRow))
    before, after = [], []
    for _ in range(runs):
        t0 = time.perf_counter()
        old = prior_from_documents(store, list(MODELS))
        before.append(time.perf_counter() - t0)
        with store._tx(write=True) as s:
            s.execute(delete(PriorRow))
        t0 = time.perf_counter()
        new = FleetPriors(store).current(list(MODELS))  # computed and stored
        after.append(time.perf_counter() - t0)
    same = all(
        {k: v for k, v in new[m].items() if k not in ("created_at", "version", "metadata")}
        == {k: v for k, v in old[m].items() if k not in ("created_at", "version", "metadata")}
        for m in MODELS
    )
    print(f"fleet prior recomputed, {len(MODELS)} models, {accepted:,} accepted versions, "
          f"{runs} runs each (median, max):\n"
          f"  from the documents (before 0006):   {np.median(before):6.2f} s  {max(before):6.2f} s\n"
          f"  from fleet_versions.flat (after):   {np.median(after):6.2f} s  {max(after):6.2f} s\n"
          f"  speed-up {np.median(before) / np.median(after):.0f}x; same priors: {same}",
          flush=True)  # fmt: skip
    # what a request pays when the priors are stale: the stored ones, the recompute left to
    # the background thread (FleetPriors.served); made stale as a new accepted version would
    priors, served, background = FleetPriors(store), [], []
    try:
        for _ in range(runs):
            with store._tx(write=True) as s:
                s.execute(update(PriorRow).values(inputs="stale"))
            priors._cache.clear()
            t0 = time.perf_counter()
            _, stale = priors.served(list(MODELS))
            served.append(time.perf_counter() - t0)
            assert stale == set(MODELS), stale
            assert priors.wait_idle(600)
            background.append(time.perf_counter() - t0)
    finally:
        priors.close()
    print(f"  a request while they are stale (the stored ones answered, marked stale): "
          f"{1000 * np.median(served):.0f} ms median, {1000 * max(served):.0f} ms max; the "
          f"background recompute done after {np.median(background):.2f} s", flush=True)  # fmt: skip
    with store._engine.connect() as conn, conn.begin():
        command.downgrade(alembic_config(conn), "0005")
    t0 = time.perf_counter()
    store.create_schema()
    print(f"migration 0006 (add and fill fleet_versions.flat of {stored:,} versions): "
          f"{time.perf_counter() - t0:.1f} s", flush=True)  # fmt: skip
    store.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, default=1000)
    ap.add_argument("--years", type=float, default=5.0)
    ap.add_argument("--database-url", default=None,
                    help="an empty PostgreSQL database (default: a throwaway one)")  # fmt: skip
    ap.add_argument("--keep", action="store_true", help="keep the throwaway database")
    ap.add_argument("--ingest-units", type=int, default=10,
                    help="units sent through the store (the last one through HTTP)")  # fmt: skip
    ap.add_argument("--repeat", type=int, default=30, help="runs of each query")
    ap.add_argument("--chunk-days", type=int, default=30)
    ap.add_argument("--reanalysis-units", type=int, default=None,
                    help="re-analyse only the first N units (default all)")  # fmt: skip
    ap.add_argument("--skip-load", action="store_true",
                    help="the database holds the fleet already (--keep of an earlier run)")  # fmt: skip
    ap.add_argument("--extra", action="store_true",
                    help="also /fleet/overview and /fleet/prior")  # fmt: skip
    ap.add_argument("--quick", action="store_true", help="4 units x 60 days, 3 runs a query")
    ap.add_argument("--overview", type=int, default=0, metavar="RUNS",
                    help="only what the overview reads: time GET /fleet/overview RUNS times "
                         "before migration 0009 and after")  # fmt: skip
    ap.add_argument("--prior", type=int, default=0, metavar="RUNS",
                    help="only the versions: time the fleet prior's recomputation RUNS times "
                         "from the documents and from fleet_versions.flat")  # fmt: skip
    args = ap.parse_args(argv)
    stop_on_sigterm()  # a timeout's SIGTERM stops the shore it started and drops its database
    if args.quick:
        args.units, args.years, args.ingest_units, args.repeat = 4, 60 / 365.25, 2, 3
    t_start = time.perf_counter()
    load = os.getloadavg()
    print(f"fleet: {args.units} units x {args.years:g} years; load average "
          f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f}", flush=True)  # fmt: skip
    fleet = Fleet(args.units, args.years)
    if args.overview:
        with database(args.database_url, args.keep) as url:
            if not args.skip_load:
                for u in fleet.units:
                    fleet.plan(u)
                FleetStore(url).create_schema()
                load_overview(url, fleet)
            overview_timing(url, args.overview)
        return 0
    if args.prior:
        with database(args.database_url, args.keep) as url:
            for u in fleet.units:
                fleet.plan(u)
            FleetStore(url).create_schema()
            load_versions(url, fleet)
            prior_recompute(url, args.prior)
        return 0
    with database(args.database_url, args.keep) as url, tempfile.TemporaryDirectory() as tmp:
        if not args.skip_load:
            t0 = time.perf_counter()
            for u in fleet.units:
                fleet.plan(u)
            print(f"generated the fleet's versions and window templates in "
                  f"{time.perf_counter() - t0:.0f} s", flush=True)  # fmt: skip
            print_totals(fleet)
            store = FleetStore(url)
            store.create_schema()
            import psycopg

            with psycopg.connect(psycopg_url(url), autocommit=True) as conn:
                add_units(conn, fleet)
            n_in = max(1, min(args.ingest_units, args.units))
            measured = fleet.units[:n_in]
            fig = ingest_store(store, fleet, measured[:-1] if n_in > 1 else measured)
            print(fig.line("ingest through FleetStore.ingest"), flush=True)
            if n_in > 1:
                with serve(url, Path(tmp)) as base:
                    fig = ingest_http(base, fleet, measured[-1:])
                print(fig.line("ingest through HTTP (gzip, recal fleet serve)"), flush=True)
            store.close()
            bulk_load(url, fleet, fleet.units[n_in:], args.chunk_days)
        storage(url)
        with serve(url, Path(tmp)) as base:
            print(f"API queries through HTTP (administrator's token), {args.repeat} runs each, "
                  f"target p95 < {TARGET_S:g} s:", flush=True)  # fmt: skip
            measure_queries(base, fleet, args.repeat, args.extra)
        print("fleet-wide re-analysis (service.fleet.reanalysis, processes):", flush=True)
        reanalysis(url, [1, 2], args.reanalysis_units)
    load = os.getloadavg()
    print(f"done in {time.perf_counter() - t_start:.0f} s; load average "
          f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")  # fmt: skip
    return 0


def print_totals(fleet: Fleet) -> None:
    """Rows per kind and bytes of JSON the fleet holds (before the database)."""
    r, n, days = fleet.rates, len(fleet.units), fleet.days
    sample = fleet.units[0]
    sizes = {
        "window": len(json.dumps(window_data(sample.windows, 1, 0, 0, r))),
        "slew": len(json.dumps(slew_data(fleet._slew, 1))),
        "event": int(
            np.mean(
                [len(json.dumps(event_data(k, m, d, 1.2345, START))) for k, m, d in fleet._events]
            )
        ),  # fmt: skip
        "session": len(json.dumps(session_data(0, r, START))),
    }
    versions = sum(len(u.versions) for u in fleet.units)
    vbytes = sum(len(t) for u in fleet.units for *_x, t in u.versions)
    counts = {
        "session": n * ((days - 1) // r.session_days + 1),
        "window": n * days * r.windows,
        "slew": n * days * r.slews,
        "event": n * days * r.events,
    }
    print("generated (rows, JSON bytes of data):")
    total_rows, total_bytes = versions, vbytes
    for kind, c in counts.items():
        print(
            f"  {kind:8s} {c:14,d} rows x {sizes[kind]:6,d} B = {c * sizes[kind] / 2**30:8.2f} GiB"
        )
        total_rows += c
        total_bytes += c * sizes[kind]
    rejected = sum(1 for u in fleet.units for v in u.versions if not v[2])
    print(f"  version  {versions:14,d} rows x {vbytes / max(versions, 1):6,.0f} B = "
          f"{vbytes / 2**30:8.2f} GiB ({rejected} rejected)")  # fmt: skip
    print(f"  ingest log {n * days * r.batches:12,d} rows")
    print(f"  in all   {total_rows:14,d} rows, {total_bytes / 2**30:.2f} GiB of JSON", flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
