"""``recal demo --fleet``: a shore service and three simulated vessels that sync to it.

The shore (:mod:`service.fleet`, on embedded SQLite in the demo folder) is served on
127.0.0.1; three units are registered (two KVH-1750, one DSP-1760, each its own seed). Each
vessel's daemon (:func:`service.daemon.build_service`, its own SQLite database) reads a short
simulated 24-position session through ``replay://`` -- detector, windows, LM recalibrations in
a worker process, the gate, versions -- with ``[sync]`` pointed at the shore. The third unit's
session goes on after its first calibration with a unit that has aged abruptly (its gyro biases
and accelerometer scale moved far beyond the first version's 1-sigma): the drift test alarms
and the gate rejects the new version, so the fleet dashboard has something to show. The demo
waits until every vessel's outbox is empty, compares what each vessel stored with what the
shore holds, and prints the dashboard's URL and the administrator's token; ``--serve`` keeps
the shore up for the browser until Ctrl-C.
"""

from __future__ import annotations

import argparse
import secrets
import shutil
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: The shore's port with --serve (docs/fleet.md: the shore's default); otherwise a free one.
SHORE_PORT = 8760
#: The short session each vessel replays: 24 holds of HOLD_S joined by SLEW_S slews at RATE_HZ.
RATE_HZ = 25.0
HOLD_S = 16.0
SLEW_S = 4.0
FIRST_HOLD_S = 30.0
#: How the ageing unit changes between its two sessions (in its own units: deg/h, fraction),
#: and the effect it grows that the model lacks (times its typical size, under a temperature
#: swing): the drift test alarms, and the fit of the new windows fails the gate's chi2 limit.
AGEING = {"gyro.bias": 0.4, "accel.scale": 4e-4}
AGEING_EFFECT = ("gyro.bias_temperature", 20.0)
AGEING_SWING_C, AGEING_PERIOD_H = 8.0, 0.1
#: Seconds to wait for every outbox to empty.
DRAIN_S = 60.0


@dataclass(frozen=True)
class Vessel:
    serial: str
    model: str
    seed: int
    ages: bool = False  # a second session after an abrupt change


VESSELS = (
    Vessel("KVH-1750-SN0101", "KVH-1750", 11),
    Vessel("KVH-1750-SN0102", "KVH-1750", 12, ages=True),
    Vessel("DSP-1760-SN0201", "DSP-1760", 21),
)
#: The vessel's tables behind each kind of the wire format, and the shore's.
VESSEL_TABLES = {"session": "sessions", "window": "positions", "slew": "slews",
                 "version": "calibrations", "event": "events"}  # fmt: skip


def _say(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def run_fleet(args: argparse.Namespace) -> int:
    from recal.errors import RecalInputError
    from service.fleet.config import ShoreApiSettings, ShoreSettings
    from service.fleet.server import make_server, open_store

    t0 = time.monotonic()
    folder = Path(args.dir).resolve()
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RecalInputError(f"cannot create {folder}: {exc.strerror}") from None
    for stale in folder.glob("*.db*"):  # each demo starts from empty databases and spools
        if stale.is_dir():
            shutil.rmtree(stale)
        else:
            stale.unlink()
    port = (args.port if args.port is not None else SHORE_PORT) if args.serve else 0
    if args.serve:
        from service.startup import check_api_port

        check_api_port("127.0.0.1", port)
    admin = _admin_token()
    settings = ShoreSettings(
        database_url=f"sqlite:///{folder / 'fleet.db'}",
        api=ShoreApiSettings(host="127.0.0.1", port=port, token=admin),
    )
    store = open_store(settings)
    server = make_server(settings, store, log_level="warning")
    thread = threading.Thread(target=server.run, name="shore", daemon=True)
    thread.start()
    services: list[Any] = []
    try:
        while not server.started:
            if not thread.is_alive():
                raise RecalInputError(f"the shore cannot listen on 127.0.0.1:{port}")
            time.sleep(0.02)
        bound = server.servers[0].sockets[0].getsockname()[1]
        shore = f"http://127.0.0.1:{bound}"
        _say(f"recal demo --fleet: shore service at {shore} on {settings.database_url}")
        for v in VESSELS:  # one after the other; each keeps syncing while the next sails
            token = store.add_unit(v.serial, v.model)
            services.append(_start_vessel(folder, v, shore, token, args.latitude))
            _finish_vessel(v, services[-1])
        drained = _drain(services)
        counts = {
            v.serial: vessel_counts(s.settings.database_url)
            for v, s in zip(VESSELS, services, strict=True)
        }
        for s in services:
            s.close()
        services = []
        shore_counts = _shore_counts(store)
        _print_summary(store, counts, shore_counts, shore, admin, drained, time.monotonic() - t0)
        if not args.serve:  # the shore stops with the demo: say how to look at its dashboard
            print(f"(the shore stops now: recal demo --fleet --serve keeps it up; the fleet's "
                  f"database stays in {folder / 'fleet.db'})")  # fmt: skip
        if args.serve:
            print(f"\nserving the shore until Ctrl-C: {shore}/fleet/dashboard", flush=True)
            try:
                while thread.is_alive():
                    thread.join(0.5)
            except KeyboardInterrupt:
                pass
        ok = drained and all(counts[u] == shore_counts.get(u) for u in counts)
        return 0 if ok else 1
    finally:
        for s in services:
            s.close()
        server.should_exit = True
        thread.join(15)
        store.close()


def _start_vessel(folder: Path, v: Vessel, shore: str, token: str, latitude: float) -> Any:
    """One vessel's daemon on its capture, syncing to ``shore``: reading and sending."""
    from service.config import DetectorSettings, DeviceSettings, SchedulerSettings, Settings
    from service.daemon import build_service

    capture = folder / f"{v.serial}.bin"
    size = _capture(v, capture, latitude)
    settings = Settings(
        database_url=f"sqlite:///{folder / f'{v.serial}.db'}",
        publish_path=str(folder / f"{v.serial}.json"),
        device=DeviceSettings(
            url=f"replay://{capture}?speed=max&rate={RATE_HZ:g}", rate_hz=RATE_HZ
        ),  # fmt: skip
        site={"latitude_deg": latitude},
        detector=DetectorSettings(init_still_s=20.0, min_duration_s=5.0, edge_trim_s=1.0),
        # one LM job at the end of the session (most of a job is its worker process starting);
        # the ageing unit's second session: the drift test's job
        scheduler=SchedulerSettings(min_positions=24, min_new_positions=24, method="lm"),
        api={"port": 0, "token": secrets.token_urlsafe(24)},
        sync={"url": shore, "unit": v.serial, "token": token, "interval_s": 0.5},
    )
    service = build_service(settings)
    service.demo_bytes = size
    service.sync.start()
    service.reader.start()
    return service


def _finish_vessel(v: Vessel, service: Any) -> None:
    """Wait for the end of the vessel's capture and its last job."""
    t0 = time.monotonic()
    while service.reader.health().counters.bytes_in < service.demo_bytes:
        time.sleep(0.05)
        if time.monotonic() - t0 > 120:
            raise RuntimeError(f"{v.serial}: replay did not finish within 120 s")
    service.reader.stop()
    service.end_of_input()
    service.scheduler.wait(timeout=120)
    service.reader = None
    history = service.store.history(limit=50)
    verdicts = ", ".join(f"v{r.version} {r.trigger} {'accepted' if r.accepted else 'REJECTED'}"
                         for r in reversed(history)) or "no version"  # fmt: skip
    _say(f"recal demo --fleet: {v.serial} ({v.model}, seed {v.seed}): "
         f"{service.store.count_positions()} windows, {verdicts}")  # fmt: skip


def _capture(v: Vessel, path: Path, latitude: float) -> int:
    """The vessel's session as KVH bytes; an ageing unit has a second session after a jump."""
    import numpy as np

    from recal.sim.session import simulate_session
    from service.capture_sim import kvh_like_truth, session_to_kvh

    truth = kvh_like_truth(v.seed)
    kw = {"latitude_deg": latitude, "rate_hz": RATE_HZ, "window_s": HOLD_S, "slew_s": SLEW_S}
    session = simulate_session(truth, "24", seed=v.seed, first_hold_s=FIRST_HOLD_S, **kw)
    data, _ = session_to_kvh(session, rng=v.seed)
    if v.ages:
        aged = truth.copy()
        rng = np.random.default_rng(v.seed)
        for name, step in AGEING.items():
            sign = rng.choice([-1.0, 1.0], size=3)
            base = np.asarray(aged.values[name], float)
            aged.values[name] = base * (1 + sign * step) if ".scale" in name else base + sign * step
        from recal.model.terms import catalogue_terms
        from recal.sim.simulate import TemperatureSpec

        effect = catalogue_terms()[AGEING_EFFECT[0]]
        aged.values[effect.name] = np.asarray(effect.typical, float) * AGEING_EFFECT[1]
        swing = TemperatureSpec(20.0, 0.0, AGEING_SWING_C, AGEING_PERIOD_H)
        later = simulate_session(aged, "24", seed=v.seed + 1000, first_hold_s=HOLD_S,
                                 temperature=swing, hidden=[effect], **kw)  # fmt: skip
        more, _ = session_to_kvh(later, rng=v.seed + 1000)
        data += more
    path.write_bytes(data)
    return len(data)


def _drain(services: list[Any]) -> bool:
    """Wait until every vessel's outbox is empty (its sync thread sends it); True if so."""
    deadline = time.monotonic() + DRAIN_S
    while time.monotonic() < deadline:
        if all(s.store.outbox_count() == 0 for s in services):
            for s in services:
                s.sync.stop()
            # a state change is an event, stored (and queued) after the acknowledgement
            if all(s.store.outbox_count() == 0 for s in services):
                return True
            for s in services:
                s.sync = _restart(s)
        for s in services:
            s.sync.poke()
        time.sleep(0.1)
    return False


def _restart(service: Any) -> Any:
    from service.sync import SyncThread

    sync = SyncThread.from_settings(service.store, service.settings.sync, service.events)
    sync.start()
    return sync


def vessel_counts(url: str) -> dict[str, int]:
    """Rows of each kind a vessel's database holds (what its outbox sends)."""
    from sqlalchemy import create_engine, text

    engine = create_engine(url)
    try:
        with engine.connect() as conn:
            return {k: conn.execute(text(f"SELECT count(*) FROM {t}")).scalar_one()
                    for k, t in VESSEL_TABLES.items()}  # fmt: skip
    finally:
        engine.dispose()


def _shore_counts(store: Any) -> dict[str, dict[str, int]]:
    """Rows of each kind the shore holds, per unit."""
    from sqlalchemy import func, select

    from service.fleet.schema import KINDS, UnitRow

    out: dict[str, dict[str, int]] = {}
    with store._tx() as s:
        for kind, table in KINDS.items():
            query = (
                select(UnitRow.serial, func.count(table.id))
                .outerjoin(table, table.unit_id == UnitRow.id)
                .group_by(UnitRow.serial)
            )
            for serial, n in s.execute(query):
                out.setdefault(serial, {})[kind] = n
    return out


def _print_summary(
    store: Any,
    counts: dict[str, dict[str, int]],
    shore_counts: dict[str, dict[str, int]],
    shore: str,
    admin: str,
    drained: bool,
    seconds: float,
) -> None:
    from service.fleet.overview import overview
    from service.fleet.priors import FleetPriors

    view = overview(store, FleetPriors(store))
    kinds = list(VESSEL_TABLES)
    print(f"{'unit':16s} {'model':9s} {'current':>7s} {'versions':>8s} {'rejected':>8s} "
          f"{'drift':>12s}  rows on vessel = on shore ({', '.join(kinds)})")  # fmt: skip
    for row in sorted(view["units"], key=lambda r: r["unit"]):
        mine, theirs = counts[row["unit"]], shore_counts.get(row["unit"], {})
        same = "yes" if mine == theirs else "NO"
        cur = "-" if row["current_version"] is None else f"v{row['current_version']}"
        print(f"{row['unit']:16s} {row['model']:9s} {cur:>7s} {row['versions']:8d} "
              f"{row['rejected']['count']:8d} {row['drift']['state']:>12s}  {same}: "
              + " ".join(str(mine[k]) for k in kinds))  # fmt: skip
    t = view["totals"]
    synced = sum(sum(c.values()) for c in shore_counts.values())
    print(f"\n{t['units']} units, {t['versions']} versions ({t['rejected']} rejected), "
          f"{synced} rows synced, every outbox {'empty' if drained else 'NOT empty'}; "
          f"{t['attention']} unit(s) need attention; {seconds:.1f} s")  # fmt: skip
    for row in view["units"]:
        if row["attention"]:
            why = row["rejected"]["last_reasons"][:1]
            print(f"  {row['unit']}: {', '.join(row['attention'])}"
                  + (f" ({why[0]})" if why else ""))  # fmt: skip
    print(f"\nfleet dashboard: {shore}/fleet/dashboard  (administrator's token: {admin})")
    print(f"overview:        curl -H 'Authorization: Bearer {admin}' {shore}/fleet/overview")


def _admin_token() -> str:
    """RECAL_API__TOKEN if set, else a fresh random token for this demo."""
    import os

    return os.environ.get("RECAL_API__TOKEN") or secrets.token_urlsafe(24)
