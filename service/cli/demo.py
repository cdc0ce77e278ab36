"""``recal demo [--serve]``: the whole product on a simulated vessel IMU, on embedded SQLite.

It simulates a KVH-like unit through a 24-position session (static holds joined by slews),
writes the bytes the device would send, replays them through a real pyserial ``replay://`` port
into the service pipeline -- static detector, positions in SQLite, scheduled recalibrations in a
worker process, the gate, versioned storage, the published JSON file -- and compares the
accepted coefficients with the truth. ``--serve`` then keeps the HTTP API up on the demo data.

``--vessel`` runs the same product on what the service is built for: a FOG bolted to a moored
hull (:mod:`recal.sim.vessel`): a few berth holds in a small sea (roll, pitch, yaw swing, heave)
joined by steady heading turns, read with ``[detector] motion = "hull"``, started from a prior
(the truth moved by a Gaussian draw of its 1-sigma, as a previous calibration) and published under ``[gate]
publish_observable_part``: what the turns show is estimated, the rest held at the prior.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

#: The --vessel session: the issue-25 berth (12 holds of 10 min joined by 30-degree turns of
#: 60 s; a window's mean rate carries the net attitude change over its length, so shorter holds
#: blur the gyro) in a small sea, at 20 Hz (the replay takes seconds).
VESSEL_HOLDS = 12
VESSEL_HOLD_S = 600.0
VESSEL_TURN_DEG = 30.0
VESSEL_TURN_S = 60.0
VESSEL_ROLL_DEG = 0.1
VESSEL_YAW_SWING_DEG = 0.02
VESSEL_HEAVE_M = 0.05
VESSEL_RATE_HZ = 20.0
#: The prior's 1-sigma: an older calibration, looser than what the berth shows, so the demo
#: shows what is estimated and what stays held (service.capture_sim.prior_near).
VESSEL_PRIOR_SIGMA = {"scale": 3e-4, "gyro.bias": 0.1, "accel.bias": 100e-6, "misalignment": 3e-4}


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
    p.add_argument("--vessel", action="store_true",
                   help="a hull-fixed FOG at berth instead of the 24-position session: "
                   f"{VESSEL_HOLDS} holds of {VESSEL_HOLD_S:g} s in a {VESSEL_ROLL_DEG:g}-degree "
                   f"sea joined by {VESSEL_TURN_DEG:g}-degree turns, the hull detector "
                   "([detector] motion = \"hull\"), a prior and [gate] publish_observable_part")  # fmt: skip
    p.add_argument("--fleet", action="store_true",
                   help="a shore service and three simulated vessels syncing to it (SQLite): "
                   "every vessel's daemon runs a short session with [sync] pointed at the "
                   "shore, one unit ages and has a version rejected; prints the fleet "
                   "dashboard's URL (docs/fleet.md)")  # fmt: skip
    p.add_argument("--serve", action="store_true", help="then serve the HTTP API until Ctrl-C")
    p.add_argument("--port", type=int, default=None,
                   help="TCP port of the API on 127.0.0.1 with --serve (default 8750; "
                   "with --fleet the shore's, default 8760)")  # fmt: skip
    p.set_defaults(func=run)
    return p


def _say(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    from recal.errors import RecalInputError
    from service.cli.common import atomic_write
    from service.config import (
        DetectorSettings,
        DeviceSettings,
        GateSettings,
        NavSettings,
        SchedulerSettings,
        Settings,
        SiteSettings,
    )
    from service.daemon import build_service

    if args.fleet:
        if args.vessel:
            raise RecalInputError("--fleet and --vessel do not go together")
        from service.cli.demo_fleet import run_fleet

        return run_fleet(args)
    if args.port is None:
        args.port = 8750
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

    capture = folder / "session.bin"
    if args.vessel:
        data, rate, truth, prior, turns, ship = _simulate_vessel(args, capture)
        nav_log = folder / "ship.nmea"  # the ship's GNSS and gyrocompass beside the capture
        atomic_write(nav_log, ship)
        prior_path = folder / "prior.json"
        atomic_write(prior_path, json.dumps(prior.to_json_dict(), indent=2) + "\n")
        detector = DetectorSettings(motion="hull")
        # a hull-fixed unit: LM (seconds), a job every two new windows, the observable part
        scheduler = SchedulerSettings(min_positions=4, min_new_positions=2, method="lm")
        gate = GateSettings(publish_observable_part=True)
    else:
        data, rate, truth = _simulate_lab(args, capture)
        prior_path, turns, nav_log = None, None, None
        detector = DetectorSettings(init_still_s=30.0, min_duration_s=5.0, edge_trim_s=1.0)
        scheduler = SchedulerSettings(min_positions=14, min_new_positions=5, sensor="both")
        gate = GateSettings()
    atomic_write(folder / "truth.json", json.dumps(truth.to_json_dict(), indent=2) + "\n")

    settings = Settings(
        database_url=f"sqlite:///{db}",
        publish_path=str(folder / "coefficients.json"),
        prior_path=None if prior_path is None else str(prior_path),
        device=DeviceSettings(url=f"replay://{capture}?speed=max&rate={rate:g}", rate_hz=rate),
        # the vessel's latitude comes from its own GNSS ([nav]), as on board
        site=SiteSettings(latitude_deg=None if nav_log else args.latitude),
        nav=NavSettings(log=str(nav_log)) if nav_log else NavSettings(),
        detector=detector,
        scheduler=scheduler,
        gate=gate,
        api={"port": args.port, "token": _api_token()},
    )
    service = build_service(settings)
    t0 = time.monotonic()
    if service.nav is not None:
        service.nav.start()
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
    kind = "quasi-static" if args.vessel else "static"
    _say(f"recal demo: replayed through replay:// in {time.monotonic() - t0:.1f} s: "
         f"{h.frames:,} frames, {service.ingest.windows} {kind} windows stored")  # fmt: skip
    latest = service.store.history(limit=1)
    if not latest or len(latest[0].positions_used) < service.store.count_positions():
        job = service.scheduler.trigger("demo")  # the scheduled jobs did not see every window
        outcome = service.scheduler.wait(timeout=300)
        verdict = "accepted" if outcome and outcome.accepted else f"not accepted: {outcome}"
        _say(f"recal demo: final recalibration (job {job}) on all windows: {verdict}")
    if args.vessel:
        _print_vessel_summary(service, truth, turns)
    else:
        _print_summary(service, truth)
    service.reader = None
    if args.serve:
        return _serve(service, settings)
    service.close()
    return 0


def _simulate_lab(args: argparse.Namespace, capture: Path) -> tuple[bytes, float, object]:
    """The 24-position session as a KVH capture: (bytes, rate, truth)."""
    from recal.sim.session import simulate_session
    from recal.sim.simulate import TemperatureSpec
    from service.capture_sim import kvh_like_truth, session_to_kvh
    from service.cli.common import atomic_write

    rate = 200.0
    truth = kvh_like_truth(args.seed)
    session = simulate_session(truth, "24", latitude_deg=args.latitude, seed=args.seed,
                               rate_hz=rate, window_s=30.0, slew_s=5.0, first_hold_s=45.0,
                               temperature=TemperatureSpec(18.0, 3.0))  # fmt: skip
    data, _ = session_to_kvh(session, rng=args.seed)
    atomic_write(capture, data)
    _say(f"recal demo: simulated {len(session.time_s):,} KVH Format-A frames "
         f"({session.time_s[-1]:.0f} s at {rate:g} Hz, 24 positions) -> {capture}")  # fmt: skip
    return data, rate, truth


def _simulate_vessel(
    args: argparse.Namespace, capture: Path
) -> tuple[bytes, float, object, object, list[tuple[float, float]], bytes]:
    """The berth session as a KVH capture: (bytes, rate, truth, prior, turn spans in s, the
    ship's NMEA sentences beside it at 1 Hz)."""
    from recal.sim.vessel import simulate_vessel
    from recal.sim.vessel_spec import SeaState, VesselSpec
    from service.capture_sim import kvh_like_truth, prior_near, session_to_kvh, ship_nmea
    from service.cli.common import atomic_write

    rate = VESSEL_RATE_HZ
    truth = kvh_like_truth(args.seed)
    prior = prior_near(truth, (args.seed, 1), VESSEL_PRIOR_SIGMA)
    sea = SeaState.berth(
        VESSEL_ROLL_DEG, yaw_swing_deg=VESSEL_YAW_SWING_DEG, heave_m=VESSEL_HEAVE_M
    )
    spec = VesselSpec.berth(VESSEL_HOLDS, VESSEL_HOLD_S, VESSEL_TURN_S, VESSEL_TURN_DEG, sea)
    rec = simulate_vessel(truth, spec, args.latitude, rate_hz=rate, seed=args.seed)
    data, _ = session_to_kvh(rec.session, rng=args.seed)
    atomic_write(capture, data)
    turns, t = [], 0.0
    for seg in spec.segments:
        if seg.kind == "turn":
            turns.append((t, t + seg.duration_s))
        t += seg.duration_s
    _say(f"recal demo: simulated a hull-fixed FOG at berth: {VESSEL_HOLDS} holds of "
         f"{VESSEL_HOLD_S:g} s joined by {VESSEL_TURN_DEG:g}-degree turns of {VESSEL_TURN_S:g} s, "
         f"roll {sea.roll_deg:g} deg, pitch {sea.pitch_deg:g} deg, yaw swing "
         f"{sea.yaw_swing_deg:g} deg, heave {sea.heave_m:g} m; {len(rec.session):,} KVH "
         f"Format-A frames ({spec.duration_s:.0f} s at {rate:g} Hz) -> {capture}")  # fmt: skip
    ship = ship_nmea(spec, args.latitude, seed=args.seed)
    _say("recal demo: and the ship's GNSS and gyrocompass beside it (NMEA 0183 GGA, RMC, VTG, "
         "HDT at 1 Hz): the daemon's [nav] log, its latitude and heading")  # fmt: skip
    return data, rate, truth, prior, turns, ship


def _print_summary(service, truth) -> None:

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
    _print_against_truth(doc, truth, mark_held=False)
    print(f"\npublished: {service.publisher.path}\ndatabase:  {service.settings.database_url}")


def _print_vessel_summary(service, truth, turns: list[tuple[float, float]]) -> None:
    """Windows against the turns, the versions, and the accepted one against the truth: each
    coefficient's error over its reported 1-sigma, marked h where it was held at the prior."""
    import numpy as np

    store = service.store
    positions, _ = store.positions()
    start, end = positions.columns["start_s"], positions.columns["end_s"]
    overlap = sum(any(s < b and e > a for a, b in turns) for s, e in zip(start, end, strict=True))
    health = service.ingest.detector_health()
    rejected = ", ".join(f"{k} {v}" for k, v in health.get("rejected", {}).items()) or "none"
    print(f"windows: {len(start)} stored ({np.min(end - start):.0f}-{np.max(end - start):.0f} s "
          f"long), {overlap} overlapping a turn; rejected: {rejected}")  # fmt: skip
    history = list(reversed(store.history(limit=50)))
    print(f"\n{'version':>7s} {'trigger':>11s} {'positions':>9s} {'accepted':>8s} "
          f"{'chi2_red':>8s}  heading error [deg RMS] before -> after")  # fmt: skip
    for r in history:
        nav = r.document.get("navigation") or {}
        before = (nav.get("before") or {}).get("heading_error_deg_rms")
        after = (nav.get("after") or {}).get("heading_error_deg_rms")
        fig = "-" if after is None else f"{before or float('nan'):.4f} -> {after:.4f}"
        print(f"{r.version:7d} {r.trigger:>11s} {len(r.positions_used):9d} "
              f"{'yes' if r.accepted else 'no':>8s} {r.document['chi2_red']:8.2f}  {fig}")  # fmt: skip
    current = store.current()
    if current is None:
        print("no accepted calibration")
        return
    doc = current.document
    print(f"\naccepted version {current.version} against the simulated truth "
          "(error / reported 1-sigma; h: held at the prior):")  # fmt: skip
    _print_against_truth(doc, truth, mark_held=True)
    nav = doc.get("navigation") or {}
    if nav.get("summary"):
        print(f"\nnavigation: {nav['summary']}")
    print(f"\npublished: {service.publisher.path}\ndatabase:  {service.settings.database_url}")


def _print_against_truth(doc: dict, truth, mark_held: bool) -> None:
    """Each scale and bias's error over its reported 1-sigma, marked h where held at the prior."""
    import numpy as np

    for sensor in ("gyro", "accel"):
        for key in ("scale", "bias"):
            est = np.array(doc["coefficients"][sensor][key])
            sd = np.array(doc["uncertainty"][sensor][key], dtype=float)
            z = (est - truth.values[f"{sensor}.{key}"]) / sd
            marks = [
                ("h" if st == "held" else " ") if mark_held else ""
                for st in doc["status"][sensor][key]
            ]
            print(f"  {sensor}.{key:6s} " + "  ".join(
                f"{v:+5.2f}{m}" for v, m in zip(z, marks, strict=True)
            ))  # fmt: skip


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
