"""Fleet sync over a bad link, with kill -9 on either side or a rebuilt vessel database: every
row arrives exactly once, with its content.

Each run registers a new unit on one shore service (``recal fleet serve`` on PostgreSQL at
127.0.0.1:5432, a throwaway database), and starts that unit's vessel daemon (``recal serve`` on
a replayed 24-position capture, its own SQLite database) whose ``[sync]`` points at a fault
proxy (benchmarks/fault_proxy.py) in front of the shore. The proxy cuts requests mid-body and answers
after the shore has committed (the lost acknowledgement), delays every chunk, and takes the
link down for seconds at a time, all from the run's seed. While the vessel replays and syncs,
the run kills (SIGKILL, the whole process group) the vessel, the shore or both at a random
moment, waits, and restarts what it killed. The ``rebuild`` victim is the vessel's disk swap:
the vessel is killed, its database, spool and published file deleted, and it starts afresh (a
new database instance whose row ids start at 1 again, the replay from its start). When the
replay is over it stops the vessel (SIGTERM), drains what the outbox still holds with
``recal sync`` (the shutdown's own events included), and compares, per kind (session, window,
slew, version, event), by (database instance, vessel row id):

* on the vessel: every row of the unit's database, as the wire carries it (its content digest,
  service.fleet.batch.content_digest); for a rebuilt vessel also the rows of the deleted
  database the shore had acknowledged before the kill (those still in its outbox are lost with
  the disk, and not counted);
* on the shore: every row stored for the unit, its content digest, how often each key is
  stored (a row stored twice would count twice), and the unit's conflicts.

missing: a vessel row not on shore; changed: on shore with other content; extra: on shore
only; doubled: a key stored twice; conflicts: rows the shore kept apart (a key received with
other content). A run passes when all are 0 and the outbox is empty. The table at the end gives,
per victim, the runs, rows compared, these counts, the proxy's cuts and outages, and the
failures; the process exits 1 on any failure.

    python benchmarks/fault_sync.py --runs 50
    python benchmarks/fault_sync.py --runs 3 --seed 7        # a quick look
    python benchmarks/fault_sync.py --runs 4 --victims rebuild
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import secrets
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(1, str(Path(__file__).resolve().parent))

from fault_injection import (  # noqa: E402 - the same process handling as the daemon's faults
    PG_ADMIN_URL,
    _free_port,
    _health,
    _kill,
    _pg_admin,
)
from stopping import stop_on_sigterm  # noqa: E402

RATE = 100.0
SPEED = 30.0  # the 6-minute capture in about 12 s: the kill falls while rows are being made
#: vessel table -> (wire kind, shore table)
KINDS = {
    "sessions": ("session", "fleet_sessions"),
    "positions": ("window", "fleet_windows"),
    "slews": ("slew", "fleet_slews"),
    "calibrations": ("version", "fleet_versions"),
    "events": ("event", "fleet_events"),
}
VICTIMS = ("vessel", "shore", "both", "rebuild")
ADMIN_TOKEN = "fault-sync-admin-" + secrets.token_hex(8)


@dataclass
class Tally:
    runs: int = 0
    rows: int = 0
    missing: int = 0
    extra: int = 0
    doubled: int = 0
    changed: int = 0
    conflicts: int = 0
    backlog: int = 0
    #: rows of deleted databases (rebuild) the shore had acknowledged, compared too
    before_rebuild: int = 0
    cuts: Counter = field(default_factory=Counter)
    outages: int = 0
    failures: list[str] = field(default_factory=list)


def _recal(*args: str, **kw: Any) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "service.cli.main", *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True, **kw,
    )  # fmt: skip


class Shore:
    """``recal fleet serve`` on a throwaway PostgreSQL database, restartable on its port."""

    def __init__(self, root: Path) -> None:
        from psycopg import sql
        from sqlalchemy.engine import make_url

        self.db = f"recal_fault_sync_{secrets.token_hex(4)}"
        with _pg_admin() as admin:
            admin.execute(sql.SQL("CREATE DATABASE {}").format(sql.Identifier(self.db)))
        self.url = make_url(PG_ADMIN_URL).set(drivername="postgresql+psycopg", database=self.db)
        self.port = _free_port()
        self.config = root / "shore.toml"
        self.config.write_text(
            f'database_url = "{self.url.render_as_string(hide_password=False)}"\n'
            f'[api]\nhost = "127.0.0.1"\nport = {self.port}\ntoken = "{ADMIN_TOKEN}"\n'
        )
        self.proc: subprocess.Popen | None = None

    def start(self) -> None:
        import httpx

        self.proc = _recal("fleet", "serve", "--config", str(self.config))
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"the shore exited {self.proc.returncode}: "
                                   f"{self.proc.stderr.read()[-400:]}")  # fmt: skip
            with contextlib.suppress(httpx.HTTPError):
                r = httpx.get(f"http://127.0.0.1:{self.port}/fleet/units", timeout=2,
                              headers={"Authorization": f"Bearer {ADMIN_TOKEN}"})  # fmt: skip
                if r.status_code == 200:
                    return
            time.sleep(0.1)
        raise RuntimeError("the shore did not answer within 60 s")

    def kill(self) -> list[str]:
        return _kill(self.proc) if self.proc is not None else []

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)

    def add_unit(self, serial: str) -> str:
        done = subprocess.run(
            [sys.executable, "-m", "service.cli.main", "fleet", "add-unit", serial, "--config",
             str(self.config), "--model", "KVH-1750"],
            capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        if done.returncode != 0:
            raise RuntimeError(f"add-unit {serial}: {done.stderr.strip()}")
        return done.stdout.strip()

    def rows(self, serial: str) -> tuple[dict[str, Counter], dict[str, dict], int]:
        """Per vessel table: how often each (instance, vessel row id) is stored for
        ``serial``, and the content digest of each; the unit's conflicts."""
        import psycopg

        from service.fleet.batch import content_digest

        counts: dict[str, Counter] = {}
        digests: dict[str, dict] = {}
        conninfo = self.url.set(drivername="postgresql").render_as_string(hide_password=False)
        with psycopg.connect(conninfo) as conn:
            for table, (_, shore_table) in KINDS.items():
                got = conn.execute(
                    f"SELECT r.instance, r.vessel_id, r.data FROM {shore_table} r "  # noqa: S608
                    "JOIN fleet_units u ON u.id = r.unit_id WHERE u.serial = %s", (serial,)
                ).fetchall()  # fmt: skip
                counts[table] = Counter((i, v) for i, v, _ in got)
                digests[table] = {(i, v): content_digest(d) for i, v, d in got}
            (conflicts,) = conn.execute(
                "SELECT n_conflicts FROM fleet_units WHERE serial = %s", (serial,)
            ).fetchone()
        return counts, digests, conflicts

    def drop(self) -> None:
        from psycopg import sql

        self.stop()
        with _pg_admin() as admin:
            admin.execute(sql.SQL("DROP DATABASE IF EXISTS {} WITH (FORCE)").format(
                sql.Identifier(self.db)))  # fmt: skip


class Vessel:
    """One unit's ``recal serve`` on a replayed capture, syncing through ``link``."""

    def __init__(
        self, folder: Path, capture: Path, serial: str, token: str, link: str, speed: float
    ) -> None:
        folder.mkdir()
        self.folder = folder
        self.db = folder / "recal.db"
        self.size = capture.stat().st_size
        self.port = _free_port()
        self.config = folder / "recal.toml"
        self.config.write_text(
            f'database_url = "sqlite:///{self.db}"\n'
            f'publish_path = "{folder / "coefficients.json"}"\n'
            f'spool_dir = "{folder / "spool"}"\n'
            f'[device]\nurl = "replay://{capture}?speed={speed:g}&rate={RATE:g}"\n'
            f"rate_hz = {RATE:g}\n"
            "[site]\nlatitude_deg = 45.0\n"
            "[detector]\naccel_threshold = 1e-6\ngyro_threshold = 1e4\n"
            '[scheduler]\nmin_positions = 12\nmin_new_positions = 6\nmethod = "lm"\n'
            "stop_wait_s = 2\n"
            f"[api]\nport = {self.port}\n"
            f'[sync]\nurl = "{link}"\nunit = "{serial}"\ntoken = "{token}"\ninterval_s = 0.5\n'
        )
        self.proc: subprocess.Popen | None = None

    def start(self) -> None:
        self.proc = _recal("serve", "--config", str(self.config), "--log-level", "ERROR")
        deadline = time.monotonic() + 60
        while _health(self.port) is None:
            if self.proc.poll() is not None:
                raise RuntimeError(f"the vessel exited {self.proc.returncode}: "
                                   f"{self.proc.stderr.read()[-400:]}")  # fmt: skip
            if time.monotonic() > deadline:
                raise RuntimeError("the vessel did not answer within 60 s")
            time.sleep(0.1)

    def replayed(self, timeout_s: float) -> bool:
        """Until the replay has been read and no job runs."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            h = _health(self.port)
            if (h is not None and h["service"]["reader"]["counters"]["bytes_in"] >= self.size
                    and not h.get("recalibrating")):  # fmt: skip
                return True
            time.sleep(0.2)
        return False

    def kill(self) -> list[str]:
        return _kill(self.proc) if self.proc is not None else []

    def stop(self) -> int:
        self.proc.send_signal(signal.SIGTERM)
        return self.proc.wait(60)

    def ensure_stopped(self) -> None:
        """Killed (its process group) if it still runs."""
        if self.proc is not None and self.proc.poll() is None:
            _kill(self.proc)

    def drain(self, timeout_s: float) -> tuple[int, str]:
        """``recal sync``: what the outbox holds, to the shore (exit code, stderr)."""
        done = subprocess.run(
            [sys.executable, "-m", "service.cli.main", "sync", "--config", str(self.config),
             "--timeout", f"{timeout_s:g}", "--json"],
            capture_output=True, text=True, timeout=timeout_s + 30,
        )  # fmt: skip
        return done.returncode, done.stderr.strip()

    def rows(self, acknowledged: bool = False) -> tuple[dict[str, dict], int]:
        """Per vessel table its rows, by (instance, row id): the content digest of each as the
        wire carries it (``acknowledged``: only those the shore acknowledged, out of the
        outbox); the outbox rows left."""
        from service.fleet.batch import content_digest
        from service.store.outbox import OutboxEntry
        from service.store.repository import Store
        from service.sync.batch import wire_row

        with contextlib.closing(sqlite3.connect(self.db)) as conn:
            ids = {t: [r for (r,) in conn.execute(f"SELECT id FROM {t}")] for t in KINDS}  # noqa: S608
            waiting = set(conn.execute("SELECT kind, ref_id FROM outbox").fetchall())
        store = Store(f"sqlite:///{self.db}")
        try:
            instance = store.instance()
            entries = [OutboxEntry(0, KINDS[t][0], i) for t, found in ids.items() for i in found
                       if not (acknowledged and (KINDS[t][0], i) in waiting)]  # fmt: skip
            found = store.outbox_rows(entries)
        finally:
            store.close()
        tables = {kind: table for table, (kind, _) in KINDS.items()}
        out: dict[str, dict] = {t: {} for t in KINDS}
        for (kind, ident), stored in found.items():
            digest = content_digest(wire_row(kind, ident, stored)["data"])
            out[tables[kind]][(instance, ident)] = digest
        return out, len(waiting)

    def instance(self) -> str:
        from service.store.repository import Store

        store = Store(f"sqlite:///{self.db}")
        try:
            return store.instance()
        finally:
            store.close()

    def wipe(self) -> None:
        """The disk swap: the database (and its WAL), the spool and the published file gone."""
        import shutil

        for path in self.folder.glob("recal.db*"):
            path.unlink()
        shutil.rmtree(self.folder / "spool", ignore_errors=True)
        (self.folder / "coefficients.json").unlink(missing_ok=True)


def one_run(
    run: int,
    victim: str,
    seed: int,
    root: Path,
    capture: Path,
    shore: Shore,
    tally: Tally,
    speed: float = SPEED,
) -> None:
    from fault_proxy import FaultProxy, outage_schedule

    rng = random.Random(seed)
    serial = f"FAULT-{seed}-{run}"
    token = shore.add_unit(serial)
    faults = {"drop_request": 0.15, "drop_response": 0.15, "delay_s": 0.01}
    with FaultProxy(("127.0.0.1", shore.port), seed=seed, faults=None) as proxy:
        proxy.set(**faults)
        schedule = outage_schedule(seed, duration_s=20.0, mean_up_s=5.0, mean_down_s=1.5)
        tally.outages += sum(1 for _, change in schedule if change.get("down"))
        proxy.play(schedule)
        vessel = Vessel(root / serial, capture, serial, token, proxy.url, speed)
        try:
            vessel.start()
            time.sleep(rng.uniform(1.0, 1.0 + 210.0 / speed))  # mid-replay, mid-sync
            sides = {"both": ("vessel", "shore"), "rebuild": ("vessel",)}.get(victim, (victim,))
            for side in sides:
                part = vessel if side == "vessel" else shore
                tally.failures += [f"run {run}: {side}: {m}" for m in part.kill()]
            before: dict[str, dict] = {t: {} for t in KINDS}
            gone: set[str] = set()  # the deleted database's instance
            if victim == "rebuild":  # what the shore acknowledged of the database about to go
                before, _ = vessel.rows(acknowledged=True)
                gone.add(vessel.instance())
                tally.before_rebuild += sum(len(r) for r in before.values())
                vessel.wipe()
            time.sleep(rng.uniform(0.5, 3.0))
            if victim in ("shore", "both"):
                shore.start()
            if victim in ("vessel", "both", "rebuild"):
                vessel.start()  # the replay starts again: a second session, more rows
            if not vessel.replayed(180):
                tally.failures.append(f"run {run}: the vessel's replay did not finish in 180 s")
            code = vessel.stop()
            if code != 0:
                tally.failures.append(f"run {run}: the vessel exited {code} on SIGTERM")
            # what the outbox still holds (the shutdown's events at least) goes over the same link
            code, err = vessel.drain(120)
            if code != 0:
                tally.failures.append(f"run {run}: recal sync exited {code}: {err[-300:]}")
            tally.cuts.update(proxy.stats.cuts)
        finally:  # an interrupted run (SIGTERM, Ctrl-C) leaves no daemon behind
            vessel.ensure_stopped()
    have, left = vessel.rows()
    counts, digests, conflicts = shore.rows(serial)
    tally.runs += 1
    tally.backlog += left
    tally.conflicts += conflicts
    if conflicts:
        tally.failures.append(f"run {run}: {conflicts} conflict(s) kept on shore")
    for table, mine in have.items():
        mine = {**before[table], **mine}  # a rebuilt vessel: both databases' rows
        got = digests[table]
        missing = set(mine) - set(got)
        # rows of the deleted database still in its outbox are lost with it: not "extra"
        lost = {k for k in set(got) - set(mine) if k[0] in gone}
        extra = set(got) - set(mine) - lost
        changed = [k for k in set(mine) & set(got) if mine[k] != got[k]]
        doubled = sum(n - 1 for n in counts[table].values() if n > 1)
        tally.rows += len(mine)
        tally.missing += len(missing)
        tally.extra += len(extra)
        tally.doubled += doubled
        tally.changed += len(changed)
        kind = KINDS[table][0]
        if missing:
            tally.failures.append(f"run {run}: {len(missing)} {kind} row(s) never arrived")
        if extra:
            tally.failures.append(f"run {run}: {len(extra)} {kind} row(s) on shore only")
        if doubled:
            tally.failures.append(f"run {run}: {doubled} {kind} row(s) stored twice")
        if changed:
            tally.failures.append(f"run {run}: {len(changed)} {kind} row(s) with other content")
    if left:
        tally.failures.append(f"run {run}: {left} outbox row(s) left")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--victims", default=",".join(VICTIMS),
                    help="what is killed, in turn (default vessel,shore,both,rebuild: the "
                    "vessel killed and its database deleted)")  # fmt: skip
    ap.add_argument("--speed", type=float, default=SPEED,
                    help=f"replay speed of the 6-minute capture (default {SPEED:g})")  # fmt: skip
    ap.add_argument("--json", action="store_true", help="also print the totals as one JSON line")
    args = ap.parse_args(argv)
    victims = tuple(args.victims.split(","))
    if not victims or not set(victims) <= set(VICTIMS):
        ap.error(f"--victims: a comma-separated list of {', '.join(VICTIMS)}")
    stop_on_sigterm()  # a timeout's SIGTERM stops the daemons and drops the database
    from recal.sim.session import simulate_session
    from service.capture_sim import kvh_like_truth, session_to_kvh

    root = Path(tempfile.mkdtemp(prefix="recal-fault-sync-"))
    session = simulate_session(kvh_like_truth(1), "24", latitude_deg=45.0, seed=1, rate_hz=RATE,
                               window_s=12.0, slew_s=3.0, first_hold_s=12.0)  # fmt: skip
    capture = root / "capture.bin"
    capture.write_bytes(session_to_kvh(session, rng=1)[0])
    tallies = {v: Tally() for v in victims}
    shore = Shore(root)
    t0 = time.monotonic()
    interrupted = False
    try:
        shore.start()
        for run in range(args.runs):
            victim = victims[run % len(victims)]
            t = time.monotonic()
            try:
                one_run(run, victim, args.seed * 1000 + run, root, capture, shore, tallies[victim],
                        args.speed)  # fmt: skip
            except Exception as exc:  # noqa: BLE001 - one run's failure is reported, not fatal
                tallies[victim].failures.append(f"run {run}: could not run: {exc}")
            left = tallies[victim].failures
            print(f"run {run:3d} kill {victim:6s} {time.monotonic() - t:5.1f} s "
                  f"{'ok' if not left or not left[-1].startswith(f'run {run}:') else 'FAIL'}",
                  flush=True)  # fmt: skip
    except KeyboardInterrupt:  # SIGTERM too (stop_on_sigterm): the runs so far are reported
        interrupted = True
        print("interrupted: the runs so far", flush=True)
    finally:
        shore.drop()
    print(
        f"\n{args.runs} runs in {time.monotonic() - t0:.0f} s; proxy: drop_request 0.15, "
        "drop_response 0.15, delay 0.01 s a chunk, link down about 1.5 s every 5 s"
    )
    print(f"{'kill -9':8s} {'runs':>5s} {'rows':>7s} {'rebuilt':>8s} {'missing':>8s} "
          f"{'changed':>8s} {'extra':>6s} {'doubled':>8s} {'conflict':>8s} {'backlog':>8s} "
          f"{'cut req':>8s} {'cut ans':>8s} {'outages':>8s} {'failures':>9s}")  # fmt: skip
    failures = 0
    for victim, t in tallies.items():
        failures += len(t.failures)
        print(f"{victim:8s} {t.runs:5d} {t.rows:7d} {t.before_rebuild:8d} {t.missing:8d} "
              f"{t.changed:8d} {t.extra:6d} {t.doubled:8d} {t.conflicts:8d} {t.backlog:8d} "
              f"{t.cuts['request']:8d} {t.cuts['response']:8d} {t.outages:8d} "
              f"{len(t.failures):9d}")  # fmt: skip
    print(
        "rows: compared by (database instance, row id) and content; rebuilt: of them, rows "
        "of deleted databases the shore had acknowledged"
    )
    for t in tallies.values():
        for f in t.failures:
            print(f"  FAIL {f}")
    if args.json:
        print(json.dumps({v: {"runs": t.runs, "rows": t.rows, "missing": t.missing,
                              "extra": t.extra, "doubled": t.doubled, "changed": t.changed,
                              "conflicts": t.conflicts, "before_rebuild": t.before_rebuild,
                              "backlog": t.backlog,
                              "cuts": dict(t.cuts), "failures": t.failures}
                          for v, t in tallies.items()}))  # fmt: skip
    with contextlib.suppress(OSError):
        import shutil

        shutil.rmtree(root)
    return 130 if interrupted else 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
