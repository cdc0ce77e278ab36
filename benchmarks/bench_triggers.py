"""The scheduler's triggers on simulated unit histories: needless jobs and reaction time.

Each history feeds windows of a simulated unit (random orientations, both triads, the window
noise of a KVH-class unit; `recal.sim.simulate.simulate_positions`) one at a time into a real
SQLite store and the daemon's :class:`service.scheduler.Scheduler` (jobs in worker processes
with the shipped ``[scheduler] method``, ``SchedulerSettings().method``, MCS-NAFSA; the gate,
publication), waiting for the scheduler to settle after each window, as at sea where windows
come hours apart:

* **steady**: 96 windows of one truth. Every job after the first is needless for the unit (it
  cannot change) and costs a worker; the information trigger runs one only while the answer
  still sharpens materially.
* **step**: 48 windows, then 48 from the same unit with gyro x scale +600 ppm and accel x bias
  +5 micro-g: windows from the change to the first job because of it (drift), and whether the
  accepted version after it sees the change within 4 sigma.

Policies compared side by side: ``count`` (the old rule, a job every ``min_new_positions = 4``
windows), ``drift+information`` (the default), ``drift`` alone.

    python benchmarks/bench_triggers.py               # 5 seeds, the shipped method
    python benchmarks/bench_triggers.py --seeds 2     # quicker
    python benchmarks/bench_triggers.py --method lm   # LM jobs (about 15 min for 5 seeds)
    python benchmarks/bench_triggers.py --policies drift+information --seeds 1

With MCS-NAFSA a seed takes about 30 min on 2 cores (2026, one seed, loaded machine: 1753 s, of
which 1278 s for ``count``'s 38 jobs, 427 s for ``drift+information``, 48 s for ``drift``), so
the default 5 seeds take about 2.5 h; LM about 3 min a seed.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from recal.model.coefficients import CoefficientSet  # noqa: E402
from recal.sim.simulate import simulate_positions  # noqa: E402
from service.capture_sim import kvh_like_truth  # noqa: E402
from service.config import SchedulerSettings, Settings, SiteSettings  # noqa: E402
from service.events import Events  # noqa: E402
from service.publish import Publisher  # noqa: E402
from service.scheduler import Scheduler  # noqa: E402
from service.store.repository import Store  # noqa: E402

LAT = 45.0
GYRO_STEP, ACCEL_STEP = 600e-6, 5e-6
POLICIES = {"count": ["count"], "drift+information": ["drift", "information"], "drift": ["drift"]}


def stepped(truth: CoefficientSet) -> CoefficientSet:
    out = truth.copy()
    out.values["gyro.scale"][0] *= 1.0 + GYRO_STEP
    out.values["accel.bias"][0] += ACCEL_STEP
    return out


def windows(truth: CoefficientSet, n: int, seed: int, t0: float) -> dict[str, np.ndarray]:
    cols = dict(simulate_positions(truth, "random", n, latitude_deg=LAT, seed=seed).columns)
    cols["start_s"] = cols["start_s"] + t0
    cols["end_s"] = cols["end_s"] + t0
    return cols


def run(history: list[dict[str, np.ndarray]], policy: list[str], folder: Path, method: str) -> dict:
    settings = Settings(
        database_url=f"sqlite:///{folder / 'r.db'}",
        publish_path=str(folder / "c.json"),
        site=SiteSettings(latitude_deg=LAT),
        scheduler=SchedulerSettings(
            trigger=policy, min_positions=24, method=method, use_slews=False
        ),  # fmt: skip
    )
    store = Store(settings.database_url)
    store.create_schema()
    session = store.add_session("bench_triggers")
    sched = Scheduler(store, settings, Publisher(settings.publish_path), Events(store))
    try:
        for cols in history:
            for k in range(len(cols["start_s"])):
                one = {name: v[k : k + 1] for name, v in cols.items()}
                sched.notify(store.add_positions(session, one))
                deadline = time.monotonic() + 600
                while not sched.settled():
                    sched.wait(timeout=1.0)
                    if time.monotonic() > deadline:
                        raise RuntimeError("the scheduler never settled")
        return {"versions": list(reversed(store.history(limit=1000))), "store": store}
    finally:
        sched.stop_starting()
        sched.shutdown(0)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first-seed", type=int, default=0)
    shipped = SchedulerSettings().method
    ap.add_argument("--method", default=shipped, help="[scheduler] method of the jobs "
                    f"(default: the shipped one, {shipped})")  # fmt: skip
    ap.add_argument("--policies", default=",".join(POLICIES),
                    help="comma-separated, from: " + ", ".join(POLICIES))  # fmt: skip
    args = ap.parse_args()
    policies = {name: POLICIES[name] for name in args.policies.split(",")}
    print(f"jobs: [scheduler] method = {args.method!r}"
          + (" (the shipped default)" if args.method == shipped else
             f" (the daemon ships {shipped!r})"), flush=True)  # fmt: skip
    t_start = time.monotonic()
    rows = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        truth = kvh_like_truth(100 + seed)
        steady = [windows(truth, 96, 1000 + seed, 0.0)]
        step = [windows(truth, 48, 1000 + seed, 0.0),
                windows(stepped(truth), 48, 3000 + seed, 1e6)]  # fmt: skip
        for name, policy in policies.items():
            t0 = time.monotonic()
            with tempfile.TemporaryDirectory() as tmp:
                versions = run(steady, policy, Path(tmp), args.method)["versions"]
            jobs = len(versions)
            with tempfile.TemporaryDirectory() as tmp:
                out = run(step, policy, Path(tmp), args.method)
                vs = out["versions"]
                after = [
                    v for v in vs if v.prior_version is not None and max(v.positions_used) > 48
                ]
                first = after[0] if after else None
                react = None if first is None else max(first.positions_used) - 48
                why = None if first is None else first.trigger
                drift_jobs = [v for v in vs if v.trigger == "drift"]
                declared = None if not drift_jobs else max(drift_jobs[0].positions_used) - 48
                current = out["store"].current()
                seen = None
                if current is not None and min(current.positions_used) > 48:
                    doc = current.document
                    g = doc["coefficients"]["gyro"]["scale"][0]
                    g0 = vs[0].document["coefficients"]["gyro"]["scale"][0]
                    sg = doc["uncertainty"]["gyro"]["scale"][0]
                    seen = abs((g - g0) - GYRO_STEP * g0) < 4 * sg
                out["store"].close()
            rows.append((seed, name, jobs, react, why, seen, declared))
            print(f"seed {seed} {name:18s} steady: {jobs:2d} jobs ({jobs - 1} after the first); "
                  f"step: first job on the new unit after {react} windows ({why}), drift job after "
                  f"{declared}, "
                  f"accepted version since the change sees the step: {seen} "
                  f"({time.monotonic() - t0:.0f} s)", flush=True)  # fmt: skip
    print(f"\njobs: method {args.method}; {time.monotonic() - t_start:.0f} s in all")
    print(
        "| policy | steady: jobs after the first (mean, 96 windows) | step: windows to the first "
        "job on the changed unit (median, max) | its trigger | windows to a job because of "
        "drift (median, max) | accepted version sees the step |"
    )
    print("|---|---|---|---|---|---|")
    for name in policies:
        mine = [r for r in rows if r[1] == name]
        extra = np.mean([r[2] - 1 for r in mine])
        reacts = [r[3] for r in mine if r[3] is not None]
        whys = sorted({r[4] for r in mine if r[4]})
        seen = sum(bool(r[5]) for r in mine)
        react = f"{np.median(reacts):.0f}, {max(reacts)}" if reacts else "never"
        decl = [r[6] for r in mine if r[6] is not None]
        drift = f"{np.median(decl):.0f}, {max(decl)} ({len(decl)}/{len(mine)})" if decl else "none"
        print(
            f"| {name} | {extra:.1f} | {react} ({len(reacts)}/{len(mine)} reacted) | "
            f"{', '.join(whys)} | {drift} | {seen}/{len(mine)} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
