"""Fleet test fixtures: a shore store on a SQLite file and on PostgreSQL (the shared
``postgres_url`` of tests/conftest.py, its fleet_* tables dropped after each test), and a real
shore server (uvicorn in a thread on a free port) over it."""

from __future__ import annotations

import contextlib
import gzip
import json
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
from sqlalchemy import create_engine, text

from service.fleet.config import ShoreApiSettings
from service.fleet.migrations import VERSION_TABLE
from service.fleet.schema import FleetBase
from service.fleet.store import FleetStore

ADMIN_TOKEN = "admin-token-0123456789abcdef"


@pytest.fixture(params=["sqlite", "postgresql"])
def fleet_url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """Each shore test runs on a SQLite file and on PostgreSQL."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'fleet.db'}"
        return
    url = request.getfixturevalue("postgres_url")
    yield url
    drop_fleet(url)


def drop_fleet(url: str) -> None:
    """The shore's tables and its revision record, gone (the vessel's are left alone)."""
    engine = create_engine(url)
    FleetBase.metadata.drop_all(engine)
    with engine.begin() as conn:
        conn.execute(text(f"DROP TABLE IF EXISTS {VERSION_TABLE}"))
    engine.dispose()


@pytest.fixture
def fleet_store(fleet_url: str) -> Iterator[FleetStore]:
    store = FleetStore(fleet_url)
    store.create_schema()
    yield store
    store.close()


@dataclass
class Shore:
    url: str
    store: FleetStore
    client: httpx.Client
    priors: Any = None  # the app's FleetPriors (its background recompute)

    def post(self, token: str | None, body: bytes, gzipped: bool = True) -> httpx.Response:
        headers = {"Content-Type": "application/json"}
        if gzipped:
            headers["Content-Encoding"] = "gzip"
        if token is not None:
            headers["Authorization"] = f"Bearer {token}"
        return self.client.post(f"{self.url}/fleet/ingest", content=body, headers=headers)

    def send(self, token: str, batch: dict[str, Any]) -> httpx.Response:
        return self.post(token, gzip.compress(json.dumps(batch).encode()))

    def get(self, token: str | None, path: str, **params: Any) -> httpx.Response:
        headers = {} if token is None else {"Authorization": f"Bearer {token}"}
        return self.client.get(f"{self.url}{path}", headers=headers, params=params)


@contextlib.contextmanager
def running(server: Any) -> Iterator[int]:
    """A uvicorn ``server`` run in a thread for the block; yields the port it bound."""
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 30
        while not server.started:
            assert thread.is_alive() and time.monotonic() < deadline, "server did not start"
            time.sleep(0.01)
        yield server.servers[0].sockets[0].getsockname()[1]
    finally:
        server.should_exit = True
        thread.join(15)


@pytest.fixture
def run_server() -> Any:
    """:func:`running`, for test modules: ``with run_server(uvicorn.Server(...)) as port``."""
    return running


@pytest.fixture
def shore(fleet_store: FleetStore) -> Iterator[Shore]:
    """A real shore server (uvicorn, HTTP on 127.0.0.1) over ``fleet_store``, with the
    administrator's token ADMIN_TOKEN and a 64 KiB batch limit."""
    import uvicorn

    from service.fleet.api import create_app

    api = ShoreApiSettings(token=ADMIN_TOKEN, max_batch_bytes=64 * 1024)
    app = create_app(fleet_store, api)
    config = uvicorn.Config(app, host="127.0.0.1", port=0, log_level="warning")
    with running(uvicorn.Server(config)) as port, httpx.Client(timeout=30) as client:
        yield Shore(f"http://127.0.0.1:{port}", fleet_store, client, app.state.fleet_priors)


class Wire:
    """Batches of the wire format (docs/fleet.md), as a vessel sends them."""

    @staticmethod
    def version_doc(version: int, accepted: bool = True, created: str = "2026-11-26T12:00:00Z"):
        """What a vessel's GET /coefficients/{version} returns (the fields the shore reads)."""
        return {
            "version": version,
            "created_at": created,
            "trigger": "drift",
            "method": "nafsa",
            "accepted": accepted,
            "reasons": [],
            "document": {"coefficients": {"gyro": {"bias": [0.1, 0.2, 0.3]}}},
            "positions_used": [1, 2, 3],
            "prior_version": None,
        }

    @staticmethod
    def batch(unit: str, rows: list[dict[str, Any]]) -> dict[str, Any]:
        return {"format": 1, "unit": unit, "sent_at": "2026-11-27T01:00:00Z", "rows": rows}

    @staticmethod
    def rows_of(n_windows: int = 3, first: int = 1, day: int = 26) -> list[dict[str, Any]]:
        """A session, ``n_windows`` windows, a slew, two versions and an event, as a vessel sends."""
        at = f"2026-11-{day:02d}T11:00:00Z"
        out = [{"kind": "session", "id": first, "at": at,
                "data": {"source": "loop://", "meta": {}, "started_at": at}}]  # fmt: skip
        for i in range(n_windows):
            out.append({"kind": "window", "id": first + i, "at": f"2026-11-{day:02d}T11:{i:02d}:00Z",
                        "data": {"session": first, "accel_x": 0.01 * i, "gyro_z": 1e-5}})  # fmt: skip
        out.append({"kind": "slew", "id": first, "at": at,
                    "data": {"first_id": first, "second_id": first + 1}})  # fmt: skip
        out.append(
            {"kind": "version", "id": first, "at": at, "data": Wire.version_doc(first, True, at)}
        )
        out.append({"kind": "version", "id": first + 1, "at": f"2026-11-{day:02d}T12:00:00Z",
                    "data": Wire.version_doc(first + 1, False, f"2026-11-{day:02d}T12:00:00Z")})  # fmt: skip
        out.append({"kind": "event", "id": first, "at": at,
                    "data": {"kind": "published", "message": "v1", "data": {}, "created_at": at}})  # fmt: skip
        return out


@pytest.fixture
def wire() -> type[Wire]:
    return Wire


# ---- a small ageing fleet, as the vessels would send it (the overview, prior and dashboard) ----
MONTH_S = 365.25 / 12 * 86400


def calibration_doc(names: list[str], values: Any, sigma: Any) -> dict[str, Any]:
    """A calibration document (conventions, section 5) from flat values and 1-sigma."""
    axis = {"x": 0, "y": 1, "z": 2}
    coefficients: dict[str, Any] = {}
    uncertainty: dict[str, Any] = {}
    for name, v, s in zip(names, values, sigma, strict=True):
        sensor, key, param = name.split(".")
        for out, x in ((coefficients, v), (uncertainty, s)):
            block = out.setdefault(sensor, {})
            if key == "misalignment":
                block.setdefault(key, {})[param] = float(x)
            else:
                block.setdefault(key, [0.0, 0.0, 0.0])[axis[param[-1]]] = float(x)
    return {"coefficients": coefficients, "uncertainty": uncertainty, "chi2_red": 1.0,
            "navigation": {"after": {"heading_error_deg_rms": 0.05}}}  # fmt: skip


def simulated_fleet(units: int = 8, outliers: int = 1, seed: int = 3) -> dict[str, Any]:
    """``{serial: rows}`` in the wire format: ``units`` KVH-1750 units ageing over two years
    (recal.fleet.simulate_fleet; ``outliers`` of them ten times faster), each version an
    accepted version row dated by its months of service from 2024-11-01, then a session, a few
    windows, events (a steady drift look) and the unit's link."""
    from datetime import UTC, datetime, timedelta

    import numpy as np

    from recal.fleet.history import is_relative
    from recal.fleet.simulate import simulate_fleet
    from service.fleet.priors import coefficient_names

    names = coefficient_names()
    nominal = np.array([1.0 if is_relative(n) else 1e-3 for n in names])
    sigma = np.array([2e-6 if is_relative(n) else 1e-5 for n in names])
    fleet = simulate_fleet(names, nominal, 2 * sigma, sigma, units=units, years=2.0,
                           interval_months=(2.0, 5.0), outliers=outliers, outlier_factor=10.0,
                           seed=seed, prefix="KVH-1750-SN")  # fmt: skip
    table = fleet.versions
    start = datetime(2024, 11, 1, tzinfo=UTC)
    out: dict[str, Any] = {"outliers": fleet.outliers, "units": {}}
    for i, serial in enumerate(table.units):
        rows: list[dict[str, Any]] = []
        mine = np.flatnonzero(table.unit == i)
        for k, j in enumerate(mine, start=1):
            at = (start + timedelta(seconds=float(table.months[j]) * MONTH_S)).isoformat()
            at = at.replace("+00:00", "Z")
            data = {"version": k, "created_at": at, "trigger": "information" if k > 1 else "count",
                    "method": "lm", "accepted": True, "reasons": [], "prior_version": k - 1 or None,
                    "document": calibration_doc(names, table.values[j], table.sigma[j]),
                    "positions_used": [1, 2, 3]}  # fmt: skip
            rows.append({"kind": "version", "id": k, "at": at, "data": data})
        out["units"][serial] = rows
    return out


@pytest.fixture(name="simulated_fleet")
def simulated_fleet_fixture() -> Any:
    return simulated_fleet
