"""``recal demo [--serve]``: the whole product on a simulated vessel IMU, on embedded SQLite.

It simulates a KVH-like unit through a 24-position session (static holds joined by slews),
writes the bytes the device would send, replays them through a real pyserial ``replay://`` port
into the service pipeline -- static detector, positions in SQLite, scheduled recalibrations in a
worker process, the gate, versioned storage, the published JSON file -- and compares the
accepted coefficients with the truth. ``--serve`` then keeps the HTTP API up on the demo data.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "demo",
        help="simulate a session and run the whole service pipeline on it (SQLite)",
        description=__doc__.splitlines()[0].replace("``", ""),
    )
    p.add_argument("--dir", default="recal-demo", help="folder for the demo files (default "
                   "./recal-demo: capture, database, published coefficients)")  # fmt: skip
    p.add_argument("--seed", type=int, default=0, metavar="S",
                   help="random seed of the simulated unit, noise and capture (default 0)")  # fmt: skip
    p.add_argument("--latitude", type=float, default=57.7, metavar="DEG",
                   help="latitude of the simulated vessel, in degrees (default 57.7)")  # fmt: skip
    p.add_argument("--serve", action="store_true", help="then serve the HTTP API until Ctrl-C")
    p.add_argument("--port", type=int, default=8750,
                   help="TCP port of the API on 127.0.0.1 with --serve (default 8750)")  # fmt: skip
    p.set_defaults(func=run)
    return p


def _say(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    from recal.errors import RecalInputError
    from recal.sim.session import simulate_session
    from recal.sim.simulate import TemperatureSpec
    from service.capture_sim import kvh_like_truth, session_to_kvh
    from service.cli.common import atomic_write
    from service.config import (
        DetectorSettings,
        DeviceSettings,
        SchedulerSettings,
        Settings,
        SiteSettings,
    )
    from service.daemon import build_service

    folder = Path(args.dir).resolve()
    if args.serve:  # say so now, not after the whole demo has run
        from service.startup import check_api_port

        check_api_port("127.0.0.1", args.port)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RecalInputError(f"cannot create {folder}: {exc.strerror}") from None
    db = folder / "recal.db"
    for stale in (db, folder / "recal.db-wal", folder / "recal.db-shm"):
        stale.unlink(missing_ok=True)  # each demo starts from an empty database

    rate = 200.0
    truth = kvh_like_truth(args.seed)
    session = simulate_session(truth, "24", latitude_deg=args.latitude, seed=args.seed,
                               rate_hz=rate, window_s=30.0, slew_s=5.0, first_hold_s=45.0,
                               temperature=TemperatureSpec(18.0, 3.0))  # fmt: skip
    data, _ = session_to_kvh(session, rng=args.seed)
    capture = folder / "session.bin"
    capture.write_bytes(data)
    atomic_write(folder / "truth.json", json.dumps(truth.to_json_dict(), indent=2) + "\n")
    _say(f"recal demo: simulated {len(session.time_s):,} KVH Format-A frames "
         f"({session.time_s[-1]:.0f} s at {rate:g} Hz, 24 positions) -> {capture}")  # fmt: skip

    settings = Settings(
        database_url=f"sqlite:///{db}",
        publish_path=str(folder / "coefficients.json"),
        device=DeviceSettings(url=f"replay://{capture}?speed=max&rate={rate:g}", rate_hz=rate),
        site=SiteSettings(latitude_deg=args.latitude),
        detector=DetectorSettings(init_still_s=30.0, min_duration_s=5.0, edge_trim_s=1.0),
        scheduler=SchedulerSettings(min_positions=14, min_new_positions=5, sensor="both"),
        api={"port": args.port, "token": _api_token()},
    )
    service = build_service(settings)
    t0 = time.monotonic()
    service.reader.start()
    size = len(data)
    while service.reader.health().counters.bytes_in < size:
        time.sleep(0.05)
        if time.monotonic() - t0 > 120:
            raise RuntimeError("replay did not finish within 120 s")
    service.reader.stop()
    service.end_of_input()
    service.scheduler.wait(timeout=300)
    h = service.reader.health().counters
    _say(f"recal demo: replayed through replay:// in {time.monotonic() - t0:.1f} s: "
         f"{h.frames:,} frames, {service.ingest.windows} static windows stored")  # fmt: skip
    latest = service.store.history(limit=1)
    if not latest or len(latest[0].positions_used) < service.store.count_positions():
        job = service.scheduler.trigger("demo")  # the scheduled jobs did not see every window
        outcome = service.scheduler.wait(timeout=300)
        verdict = "accepted" if outcome and outcome.accepted else f"not accepted: {outcome}"
        _say(f"recal demo: final recalibration (job {job}) on all windows: {verdict}")
    _print_summary(service, truth)
    service.reader = None
    if args.serve:
        return _serve(service, settings)
    service.close()
    return 0


def _print_summary(service, truth) -> None:
    import numpy as np

    store = service.store
    history = list(reversed(store.history(limit=50)))
    print(f"{'version':>7s} {'trigger':>11s} {'positions':>9s} {'accepted':>8s} "
          f"{'chi2_red':>8s}  gyro Kx - 1 [ppm]      accel bz [ug]")  # fmt: skip
    for r in history:
        doc = r.document
        kx = (doc["coefficients"]["gyro"]["scale"][0] - 1) * 1e6
        skx = doc["uncertainty"]["gyro"]["scale"][0] * 1e6
        bz = doc["coefficients"]["accel"]["bias"][2] * 1e6
        sbz = doc["uncertainty"]["accel"]["bias"][2] * 1e6
        print(f"{r.version:7d} {r.trigger:>11s} {len(r.positions_used):9d} "
              f"{'yes' if r.accepted else 'no':>8s} {doc['chi2_red']:8.2f}  "
              f"{kx:8.1f} +- {skx:5.1f}       {bz:8.1f} +- {sbz:5.1f}")  # fmt: skip
    current = store.current()
    if current is None:
        print("no accepted calibration")
        return
    doc = current.document
    print(f"\naccepted version {current.version} against the simulated truth "
          "(error / reported 1-sigma):")  # fmt: skip
    for sensor in ("gyro", "accel"):
        for key in ("scale", "bias"):
            est = np.array(doc["coefficients"][sensor][key])
            sd = np.array(doc["uncertainty"][sensor][key], dtype=float)
            true = truth.values[f"{sensor}.{key}"]
            z = (est - true) / sd
            print(f"  {sensor}.{key:6s} " + "  ".join(f"{v:+5.2f}" for v in z))
    print(f"\npublished: {service.publisher.path}\ndatabase:  {service.settings.database_url}")


def _api_token() -> str:
    """RECAL_API__TOKEN if set, else a fresh random token for this demo."""
    import os
    import secrets

    return os.environ.get("RECAL_API__TOKEN") or secrets.token_urlsafe(24)


def _serve(service, settings) -> int:
    from service.daemon import make_server, run_server

    url = f"http://{settings.api.host}:{settings.api.port}"
    token = settings.api.token.get_secret_value()
    print(f"\nserving the demo at {url}  (the dashboard: {url}/ ; the API: {url}/coefficients, "
          f"{url}/docs; Ctrl-C stops)\n"
          f"API token for write endpoints: {token}\n"
          f"  curl -X POST -H 'Authorization: Bearer {token}' {url}/recalibrate",
          flush=True)  # fmt: skip
    try:
        run_server(make_server(service), settings.api)
    finally:
        service.close()
    return 0
