"""A simulated week of a hull-fixed FOG replayed through the daemon (issue 25).

The week (recal.sim.vessel, a KVH-like unit from service.capture_sim.kvh_like_truth, ARW 0.012
deg/sqrt(h), VRW 20 ug/sqrt(Hz)): each day has its own sea state, a peak roll drawn between 0.1
and 1 degree (log-uniform; pitch half of it, yaw swing and heave 0.3 of it in deg and m, the IMU
5 m above the roll axis). The vessel holds its heading at berth for 20-60 min, then turns
steadily by 15-90 degrees in 1-3 min; about once a day it goes out into rough sea for 2-4 h (roll 3 degrees, heave 0.9 m) where it holds for 10-30 min between turns: nothing
there should be usable. The recording is written chunk by chunk as a KVH Format A capture at a
reduced rate (10 Hz by default), then replayed through a real ``replay://`` port into the
daemon (reader, ingest thread, ``[detector] motion = "hull"``, SQLite, scheduler with jobs of
the shipped method, MCS-NAFSA (``--method lm`` for LM), in worker processes, the gate with ``publish_observable_part``, the publisher), which starts
from a prior: the truth plus a Gaussian draw of 100 ppm, 0.01 deg/h, 20 ug and 0.1 mrad,
carrying that uncertainty (service.capture_sim.prior_near; before issue 36 the draw was uniform
within +-1 sigma, which flattered every held coefficient).

Seeds (issue 36, "evidence that can fail"): the hull detector, the drift test and the gate were
developed on seed 0 (the old default), and seeds 1 and 2 were run and quoted while doing so
(:data:`DEV_SEEDS`). The default is seed 10, held out; ``--seeds 10-12`` runs several weeks one
after the other. Each run says which of its seeds are dev and which held-out. The prior comes
from its own random stream, so a seed's schedule is the same whatever the prior's draw.

Printed: windows stored (in calm and rough sea), windows that overlap a turn (must be 0), holds
with a window, drift alarms, jobs and versions (published or not, with the gate's reasons), and
for each published version every coefficient's error against the truth in its reported sigmas:
the largest over the estimated and over the held ones, and every miss (beyond 3 sigma) by name;
the gyrocompass heading error; the daemon's CPU time (all its threads plus the job workers) per
simulated day.

    python benchmarks/bench_vessel.py                 # a week at 10 Hz, about 10 min on 2 cores
    python benchmarks/bench_vessel.py --quick         # one day, replayed as fast as it reads
    python benchmarks/bench_vessel.py --days 3 --rate 20 --seeds 11,12
    python benchmarks/bench_vessel.py --seed 0        # the development seed (not evidence)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers import DecoderConfig  # noqa: E402
from recal.sim.simulate import NoiseSpec  # noqa: E402
from recal.sim.vessel import vessel_chunks  # noqa: E402
from recal.sim.vessel_spec import SeaState, Segment, VesselSpec  # noqa: E402
from service.capture_sim import encode_kvh, kvh_like_truth, prior_near  # noqa: E402
from service.config import (  # noqa: E402
    DetectorSettings,
    DeviceSettings,
    GateSettings,
    SchedulerSettings,
    Settings,
    SiteSettings,
)
from service.daemon import build_service  # noqa: E402

DAY_S = 86400.0
#: The sea at scale 1 (each segment scales it): peak roll 1 deg; rough sea is scale 3.
SEA = SeaState(roll_deg=1.0, roll_period_s=8.0, pitch_deg=0.5, pitch_period_s=6.0,
               yaw_swing_deg=0.3, yaw_period_s=180.0, heave_m=0.3, heave_period_s=8.0,
               lever_arm_m=(0.0, 0.0, -5.0))  # fmt: skip
ROUGH_SCALE = 3.0
#: Odds that the next stretch is rough rather than a berth hold: about one rough stretch a day.
ROUGH_ODDS = 1 / 30
#: The seeds the week's method was developed and tuned on (module docstring): never quoted as
#: held-out evidence.
DEV_SEEDS = (0, 1, 2)
#: The default seed: held out.
DEFAULT_SEED = 10
#: Section 5 parameter names of the vector terms (the misalignment is a name -> value map).
_PARAMS = {"scale": ("Kx", "Ky", "Kz"), "bias": ("bx", "by", "bz"),
           "quadratic": ("K2x", "K2y", "K2z")}  # fmt: skip


@dataclass(frozen=True)
class Week:
    spec: VesselSpec
    start: np.ndarray  # (S,) segment start, s
    end: np.ndarray
    kind: np.ndarray  # (S,) "hold", "turn"
    scale: np.ndarray  # (S,) sea scale
    day_roll_deg: list[float]


def make_week(days: float, rng: np.random.Generator) -> Week:
    """The schedule: berth holds and turns in each day's sea, rough-sea stretches now and then."""
    segs: list[Segment] = []
    total, day_rolls = 0.0, []
    horizon = days * DAY_S
    while total < horizon:
        day = int(total // DAY_S)
        while len(day_rolls) <= day:
            day_rolls.append(float(10 ** rng.uniform(-1.0, 0.0)))  # 0.1-1 deg
        calm = day_rolls[day]
        if rng.uniform() < ROUGH_ODDS:  # rough stretch: short holds and turns in a big sea
            end = total + rng.uniform(2, 4) * 3600.0
            while total < end:
                segs.append(Segment("hold", rng.uniform(600, 1800), sea_scale=ROUGH_SCALE))
                segs.append(_turn(rng, ROUGH_SCALE))
                total += segs[-2].duration_s + segs[-1].duration_s
        else:
            segs.append(Segment("hold", rng.uniform(1200, 3600), sea_scale=calm))
            segs.append(_turn(rng, calm))
            total += segs[-2].duration_s + segs[-1].duration_s
    # cut at the horizon: the last segment shortened (a turn longer than its ramps, or a hold)
    while segs and sum(s.duration_s for s in segs[:-1]) >= horizon:
        segs.pop()
    over = sum(s.duration_s for s in segs) - horizon
    last = segs[-1]
    if last.kind == "turn" or last.duration_s - over < 60:
        segs.pop()
    else:
        segs[-1] = Segment("hold", last.duration_s - over, sea_scale=last.sea_scale)
    spec = VesselSpec(tuple(segs), sea=SEA)
    d = np.array([s.duration_s for s in segs])
    start = np.concatenate(([0.0], np.cumsum(d)[:-1]))
    return Week(spec, start, start + d, np.array([s.kind for s in segs]),
                np.array([s.sea_scale for s in segs]), day_rolls)  # fmt: skip


def _turn(rng: np.random.Generator, scale: float) -> Segment:
    deg = rng.choice([-1.0, 1.0]) * rng.uniform(15.0, 90.0)
    return Segment("turn", rng.uniform(60.0, 180.0), heading_change_deg=float(deg), sea_scale=scale)


def write_capture(truth, week: Week, path: Path, rate: float, lat: float, seed: int) -> int:
    """The recording as KVH Format A frames, chunk by chunk; returns the frame count."""
    config = DecoderConfig(rate_hz=rate)
    noise = NoiseSpec(arw_deg_rt_h=0.012, vrw_ug_rt_hz=20.0)
    n = 0
    with path.open("wb") as fh:
        for c in vessel_chunks(truth, week.spec, lat, rate_hz=rate, noise=noise, seed=seed,
                               chunk_s=3600.0):  # fmt: skip
            fh.write(encode_kvh(c.gyro_out, c.accel_out, c.temperature_c, "kvh-a", config, n))
            n += len(c.time_s)
    return n


def cpu_s() -> tuple[float, float]:
    """CPU seconds of this process (every thread) and of its finished children (job workers)."""
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time(), kids.ru_utime + kids.ru_stime


def run_daemon(capture: Path, prior_path: Path, folder: Path, rate: float, lat: float,
               speed: str, method: str) -> dict:  # fmt: skip
    settings = Settings(
        database_url=f"sqlite:///{folder / 'recal.db'}",
        publish_path=str(folder / "coefficients.json"),
        spool_dir=str(folder / "spool"),
        prior_path=str(prior_path),
        device=DeviceSettings(url=f"replay://{capture}?speed={speed}&rate={rate:g}", rate_hz=rate),
        site=SiteSettings(latitude_deg=lat),
        detector=DetectorSettings(motion="hull"),
        scheduler=SchedulerSettings(method=method),
        gate=GateSettings(publish_observable_part=True),
    )
    c0, t0 = cpu_s(), time.monotonic()
    service = build_service(settings)
    size = capture.stat().st_size
    service.reader.start()
    last = -1.0
    while service.reader.health().counters.bytes_in < size:
        time.sleep(0.5)
        done = service.reader.health().counters.bytes_in / size
        if done - last >= 0.1:
            print(f"  replay {done:4.0%}: {service.ingest.windows} windows, "
                  f"{len(service.store.history(limit=1000))} versions, "
                  f"{time.monotonic() - t0:.0f} s", file=sys.stderr, flush=True)  # fmt: skip
            last = done
    service.reader.stop()
    service.end_of_input(timeout_s=600)
    deadline = time.monotonic() + 1800
    while not service.scheduler.settled() and time.monotonic() < deadline:
        time.sleep(0.5)
    wall = time.monotonic() - t0
    store = service.store
    positions, _ = store.positions()
    out = {
        "frames": service.reader.health().counters.frames,
        "start_s": np.asarray(positions.columns["start_s"]),
        "end_s": np.asarray(positions.columns["end_s"]),
        "gyro_sem": np.column_stack([positions.columns[f"gyro_{a}_sem"] for a in "xyz"]),
        "history": list(reversed(store.history(limit=10000))),
        "events": store.events(limit=1_000_000),
        "detector": service.ingest.detector_health(),
        # the trigger evaluations' CPU grows with the windows, not with the frame rate
        "cpu_evaluations_s": service.scheduler.evaluation_cpu_s,
        "evaluations": service.scheduler.evaluations,
    }
    service.close()
    c1 = cpu_s()
    out["cpu_daemon_s"], out["cpu_jobs_s"] = c1[0] - c0[0], c1[1] - c0[1]
    out["wall_s"] = wall
    return out


def stream_cpu_1khz(truth, lat: float, hours: float, folder: Path) -> dict:
    """The daemon's per-frame work past the reader at 1 kHz, measured directly: a berth in a
    1-degree sea at 1 kHz, encoded as KVH Format A and decoded as the reader does, fed to the
    daemon's ingest (hull detector, rest check, store and spool of the windows) in batches of
    50 frames (a live 1 kHz reader delivers about 20 reads a second). The thread's own CPU time
    per frame; the reader's share is bench_reader_cpu's (docs/drivers.md)."""
    from drivers import decode_bulk

    rate = 1000.0
    holds = max(1, round(hours * 3600.0 / 720.0))
    spec = VesselSpec.berth(holds=holds, hold_s=660.0, turn_s=60.0, sea=SEA)
    settings = Settings(
        database_url=f"sqlite:///{folder / 'stream.db'}",
        publish_path=str(folder / "stream.json"),
        spool_dir=str(folder / "stream-spool"),
        device=DeviceSettings(url="replay:///dev/null", rate_hz=rate),
        site=SiteSettings(latitude_deg=lat),
        detector=DetectorSettings(motion="hull"),
        scheduler=SchedulerSettings(method="lm", trigger=["count"], min_positions=10**6),
    )
    service = build_service(settings)
    config = DecoderConfig(rate_hz=rate)
    noise = NoiseSpec(arw_deg_rt_h=0.012, vrw_ug_rt_hz=20.0)
    cpu, frames, n = 0.0, 0, 0
    for c in vessel_chunks(truth, spec, lat, rate_hz=rate, noise=noise, seed=1, chunk_s=600.0):
        raw = encode_kvh(c.gyro_out, c.accel_out, c.temperature_c, "kvh-a", config, n)
        n += len(c.time_s)
        batch = decode_bulk(raw, "kvh-a", config)[0]
        batch.time_s[:] = c.time_s  # one stream: device time runs on across the chunks
        c0 = time.thread_time()
        for k in range(0, len(batch), 50):
            service.ingest.feed(batch[k : k + 50])
        cpu += time.thread_time() - c0
        frames += len(batch)
    c0 = time.thread_time()
    service.ingest.flush()
    cpu += time.thread_time() - c0
    windows = service.ingest.windows
    service.close()
    return {"frames": frames, "cpu_s": cpu, "windows": windows, "holds": holds}


def flat(layout: dict) -> dict[str, object]:
    """'gyro.scale.Kx' -> value of a section 5 layout (coefficients, status or uncertainty)."""
    out = {}
    for sensor, block in layout.items():
        if not isinstance(block, dict):
            continue
        for key, entry in block.items():
            if not isinstance(entry, dict) and key not in _PARAMS:
                continue  # metadata
            items = entry.items() if isinstance(entry, dict) else zip(_PARAMS[key], entry)
            out.update({f"{sensor}.{key}.{p}": v for p, v in items})
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--days", type=float, default=7.0, help="simulated days (default 7)")
    ap.add_argument("--rate", type=float, default=10.0, help="sample rate, Hz (default 10)")
    ap.add_argument("--speed", default="2000",
                    help="replay speed: N times real time, or max (default 2000)")  # fmt: skip
    ap.add_argument("--seeds", "--seed", dest="seeds", type=parse_seeds, default=[DEFAULT_SEED],
                    help=f"random seed(s): 10, 10-12 or 10,14 (default {DEFAULT_SEED}, held "
                         f"out; {', '.join(map(str, DEV_SEEDS))} are the development seeds)")  # fmt: skip
    ap.add_argument("--latitude", type=float, default=45.0, help="deg (default 45)")
    ap.add_argument("--quick", action="store_true", help="one day, replayed at max speed")
    ap.add_argument("--keep", metavar="DIR", help="keep the capture and database in DIR")
    ap.add_argument(
        "--stream-hours",
        type=float,
        default=2.0,
        help="hours of a 1 kHz berth for the per-frame CPU (default 2; 0: skip)",
    )
    ap.add_argument("--stream-only", action="store_true", help="only the 1 kHz CPU measurement")
    shipped = SchedulerSettings().method
    ap.add_argument("--method", default=shipped,
                    help=f"[scheduler] method of the jobs (default: the shipped one, {shipped})")  # fmt: skip
    args = ap.parse_args()
    if args.quick:
        args.days, args.speed = 1.0, "max"
    dev = [s for s in args.seeds if s in DEV_SEEDS]
    held = [s for s in args.seeds if s not in DEV_SEEDS]
    print(f"seeds: held-out {', '.join(map(str, held)) or 'none'}; development "
          f"{', '.join(map(str, dev)) or 'none'} (developed on {', '.join(map(str, DEV_SEEDS))}: "
          "not evidence)\n")  # fmt: skip
    summary = []
    for k, seed in enumerate(args.seeds):
        folder = Path(args.keep) / f"seed-{seed}" if args.keep and len(args.seeds) > 1 else None
        summary.append(run_week(args, seed, shipped, stream=k == 0, keep=folder))
        if args.stream_only:
            return 0
    if len(summary) > 1:
        print("\n| seed | | windows over a turn | drift alarms | versions published | misses |")
        print("|---|---|---|---|---|---|")
        for r in summary:
            print(f"| {r['seed']} | {'dev' if r['seed'] in DEV_SEEDS else 'held-out'} | "
                  f"{r['overlap']} | {r['alarms']} | {r['published']} | {r['misses']} |")  # fmt: skip
    return 0


def parse_seeds(text: str) -> list[int]:
    """'10', '10-12' or '10,14' (or a mix) as a list of seeds."""
    seeds: list[int] = []
    for part in text.split(","):
        a, _, b = part.strip().partition("-")
        seeds += list(range(int(a), int(b) + 1)) if b else [int(a)]
    return seeds


def run_week(args: argparse.Namespace, seed: int, shipped: str, stream: bool,
             keep: Path | None = None) -> dict:  # fmt: skip
    """One seed's voyage through the daemon, printed; returns its headline counts."""
    rng = np.random.default_rng([seed, 25])
    truth = kvh_like_truth(seed)
    prior = prior_near(truth, [seed, 25, 1])
    week = make_week(args.days, rng)
    holds = week.kind == "hold"
    rough = week.scale >= ROUGH_SCALE
    role = "development seed: not evidence" if seed in DEV_SEEDS else "held-out seed"
    print(f"# A simulated {args.days:g}-day voyage through the daemon, seed {seed} ({role}; "
          f"{os.cpu_count()} cores)\n")  # fmt: skip
    print(f"schedule: {holds.sum()} holds ({(holds & rough).sum()} in rough sea, "
          f"{(week.end - week.start)[holds & rough].sum() / 3600:.1f} h), "
          f"{(~holds).sum()} turns; daily peak roll "
          + ", ".join(f"{r:.2f}" for r in week.day_roll_deg) + " deg (rough: "
          f"{ROUGH_SCALE:g} deg); {args.rate:g} Hz, latitude {args.latitude:g}; jobs: "
          f"[scheduler] method = {args.method!r}"
          + (" (the shipped default)" if args.method == shipped else f" (ships {shipped!r})"))  # fmt: skip

    tmp = tempfile.TemporaryDirectory(prefix="bench_vessel.")
    folder = keep or (Path(args.keep) if args.keep else Path(tmp.name))
    folder.mkdir(parents=True, exist_ok=True)
    for stale in ("recal.db", "recal.db-wal", "recal.db-shm", "coefficients.json"):
        (folder / stale).unlink(missing_ok=True)
    capture, prior_path = folder / "week.bin", folder / "prior.json"
    prior_path.write_text(json.dumps(prior.to_json_dict(), indent=2), encoding="utf-8")
    (folder / "truth.json").write_text(json.dumps(truth.to_json_dict(), indent=2), "utf-8")
    if stream and args.stream_hours > 0:
        st = stream_cpu_1khz(truth, args.latitude, args.stream_hours, folder)
        share = 100.0 * st["cpu_s"] / st["frames"] * 1000.0
        print(f"per-frame work past the reader at 1 kHz (ingest, hull detector, store; 50-frame "
              f"batches, {st['frames']:,} frames, {st['holds']} holds, {st['windows']} windows): "
              f"{1e6 * st['cpu_s'] / st['frames']:.1f} us/frame = {share:.2f} % of a core; with "
              f"the reader's 2.4 % (bench_reader_cpu, docs/drivers.md): {share + 2.4:.1f} % of "
              "the 5 % budget (docs/service.md)")  # fmt: skip
        if args.stream_only:
            return {"seed": seed}
    t0 = time.monotonic()
    frames = write_capture(truth, week, capture, args.rate, args.latitude, seed)
    print(f"simulated {frames:,} frames ({capture.stat().st_size / 1e6:.0f} MB) in "
          f"{time.monotonic() - t0:.0f} s; replaying at speed {args.speed} ...")  # fmt: skip
    r = run_daemon(capture, prior_path, folder, args.rate, args.latitude, args.speed, args.method)

    start, end = r["start_s"], r["end_s"]
    # the segment each window starts in, and whether it reaches into any turn
    seg = np.searchsorted(week.start, start, side="right") - 1
    turns = ~holds
    ts, te = week.start[turns], week.end[turns]
    overlap = np.array([bool(np.any((s < te) & (e > ts))) for s, e in zip(start, end, strict=True)])
    in_rough = rough[seg]
    hold_hit = np.zeros(len(week.kind), bool)
    hold_hit[seg[~overlap]] = True
    det = r["detector"]
    print(f"\nframes through the daemon: {r['frames']:,}; replay and jobs {r['wall_s']:.0f} s")
    sem = r["gyro_sem"]
    print(f"windows stored: {len(start)} ({np.median(end - start) if len(start) else 0:.0f} s "
          f"median length), {int(in_rough.sum())} of them in rough sea; median gyro sem "
          f"{np.median(sem[~in_rough]) if (~in_rough).any() else 0:.3f} deg/h calm, "
          f"{np.median(sem[in_rough]) if in_rough.any() else 0:.3f} deg/h rough")  # fmt: skip
    inside = np.array([max((min(e, b) - max(s, a) for a, b in zip(ts, te, strict=True)
                            if s < b and e > a), default=0.0)
                       for s, e in zip(start, end, strict=True)])  # fmt: skip
    print(f"windows overlapping a turn: {int(overlap.sum())}  (must be 0; calm sea "
          f"{int((overlap & ~in_rough).sum())}, rough {int((overlap & in_rough).sum())}; "
          f"seconds inside the turn: median {np.median(inside[overlap]) if overlap.any() else 0:.1f}, "
          f"max {inside.max(initial=0):.1f})")  # fmt: skip
    for i in np.argsort(-inside)[: min(8, int(overlap.sum()))]:
        print(f"  {'rough' if in_rough[i] else 'calm'} window {start[i]:.1f}-{end[i]:.1f} s: "
              f"{inside[i]:.1f} s inside a turn")  # fmt: skip
    print(f"holds with a window: {int(hold_hit[holds & ~rough].sum())} of "
          f"{int((holds & ~rough).sum())} calm, {int(hold_hit[holds & rough].sum())} of "
          f"{int((holds & rough).sum())} rough")  # fmt: skip
    print(f"hull detector: rejected {det.get('rejected')}, blocks {det.get('blocks')}")
    alarms = [e for e in r["events"] if e["kind"] == "drift" and (e["data"] or {}).get(
        "alarm_window") is not None]  # fmt: skip
    evaluations = sum(1 for e in r["events"] if e["kind"] == "drift")
    history = r["history"]
    by_trigger: dict[str, int] = {}
    for h in history:
        by_trigger[h.trigger] = by_trigger.get(h.trigger, 0) + 1
    published = [h for h in history if h.accepted]
    print(f"drift alarms: {len(alarms)} (of {evaluations} drift evaluations)")
    print(f"versions: {len(history)} ({', '.join(f'{k} {v}' for k, v in by_trigger.items())}); "
          f"published: {len(published)}")  # fmt: skip
    for h in history:
        if not h.accepted:
            print(f"  version {h.version} not published: {'; '.join(h.reasons)[:300]}")

    true = flat(truth.to_json_dict())
    misses_total = 0
    if published:
        print("\n| version | trigger | windows | estimated | max abs(z) estimated | held | max "
              "abs(z) held | heading error after [deg RMS] | misses (> 3 sigma) |")  # fmt: skip
        print("|---|---|---|---|---|---|---|---|---|")
    for h in published:
        doc = h.document
        est, sd, status = (flat(doc[k]) for k in ("coefficients", "uncertainty", "status"))
        z = {n: (float(est[n]) - float(true[n])) / float(sd[n]) for n in est
             if n in true and sd.get(n) not in (None, 0)}  # fmt: skip
        zest = {n: v for n, v in z.items() if status.get(n) == "estimated"}
        zheld = {n: v for n, v in z.items() if status.get(n) == "held"}
        miss = {n: v for n, v in z.items() if abs(v) > 3}
        misses_total += len(miss)
        nav = (doc.get("navigation") or {}).get("after") or {}
        heading = nav.get("heading_error_deg_rms")
        print(f"| {h.version} | {h.trigger} | {len(h.positions_used)} | {len(zest)} | "
              f"{max(map(abs, zest.values()), default=math.nan):.2f} | {len(zheld)} | "
              f"{max(map(abs, zheld.values()), default=math.nan):.2f} | "
              f"{'-' if heading is None else f'{heading:.4f}'} | "
              + (", ".join(f"{n} {v:+.1f}{'' if status.get(n) == 'estimated' else ' (held)'}"
                           for n, v in sorted(miss.items())) or "none")
              + " |")  # fmt: skip
    days = args.days
    print(f"\nmisses over all published versions: {misses_total}")
    cpu = r["cpu_daemon_s"] + r["cpu_jobs_s"]
    stream = r["cpu_daemon_s"] - r["cpu_evaluations_s"]
    print(f"daemon CPU: {cpu:.0f} s for {days:g} days = {cpu / days:.1f} s per simulated day at "
          f"{args.rate:g} Hz (reader, ingest and hull detector, store {stream / days:.1f} s; "
          f"trigger evaluations {r['cpu_evaluations_s'] / days:.1f} s in {r['evaluations']}; "
          f"job workers {r['cpu_jobs_s'] / days:.1f} s): "
          f"{100 * cpu / (days * DAY_S):.3f} % of a core; the stream part "
          f"{1e6 * stream / r['frames']:.0f} us per 10 Hz frame replayed at {args.speed}x (the "
          "replay's pacing and small reads included: not a 1 kHz figure, see the direct "
          "measurement above)")  # fmt: skip
    tmp.cleanup()
    return {"seed": seed, "overlap": int(overlap.sum()), "alarms": len(alarms),
            "published": len(published), "misses": misses_total}  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
