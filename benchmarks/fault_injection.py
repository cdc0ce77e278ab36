"""Fault injection: kill the daemon in every phase, refuse its database, fill its disk; restart
and check that no detected window was lost or doubled and that versions go on.

Cases (each its own folder, database, spool and clean reference run; ``--runs`` runs each):

* ``learning``     kill -9 while the detector learns its noise floor (frames held);
* ``detecting``    kill -9 while windows are being detected and stored, no job running;
* ``storing``      kill -9 the moment a window batch is in the spool (written, not yet deleted);
* ``job``          kill -9 while a recalibration job runs (its worker must die with it);
* ``publication``  kill -9 the moment a new version is committed (before or while it is
                   published): the restart must publish it;
* ``outage``       the database (PostgreSQL at 127.0.0.1:5432, closed to connections with
                   ``ALLOW_CONNECTIONS false``) refuses, windows wait in the spool, kill -9;
                   the restart (database back) must store every one of them;
* ``disk-full``    the spool folder is a full tmpfs (ENOSPC): /health must name it and the
                   cause, windows go straight to the database; kill -9.

Each run starts ``recal serve`` (its own process session) on a replayed capture, its jobs with
the shipped ``[scheduler] method`` (``SchedulerSettings().method``, MCS-NAFSA; ``--method lm``
for the faster stand-in). Just before the kill it reads ``/health`` (``windows_detected``:
windows made durable, in the spool or the database). Right after the kill it counts what is
durable: the killed session's windows in the database plus those in spool files the database
has not committed (a batch the kill caught in the spool is in this count, which /health read
just before could not include). After the kill, and again after the next start (the restart),
it checks:

1. no process of the killed run is left (job workers included);
2. ``PRAGMA integrity_check`` is ``ok`` (SQLite); every version is complete;
3. the published file equals the current accepted version once the restarted daemon is up;
4. detected: the durable count (never below /health's ``windows_detected``, else a failure: a
   window counted as durable is in neither the database nor the spool); lost: detected windows
   the restart does not store; doubled: a window stored twice in a session; every session's
   windows are a prefix of the clean run's (same order, same means);
5. after the last run, a clean SIGTERM exits 0.

    python benchmarks/fault_injection.py --runs 50            # every case
    python benchmarks/fault_injection.py --runs 5 --cases outage,disk-full
    python benchmarks/fault_injection.py --runs 3 --cases storing --method lm
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from stopping import stop_on_sigterm

RATE = 100.0
SPEED = 40.0
CASES = ("learning", "detecting", "storing", "job", "publication", "outage", "disk-full")
PG_ADMIN_URL = os.environ.get("RECAL_TEST_POSTGRES", "postgresql://postgres@127.0.0.1:5432/test")


# ---- the database, SQLite or PostgreSQL ------------------------------------------------------


def _query(url: str, sql: str) -> list[tuple]:
    from sqlalchemy import create_engine, text

    engine = create_engine(url)
    try:
        with engine.connect() as conn:
            return [tuple(r) for r in conn.execute(text(sql))]
    finally:
        engine.dispose()


def _windows(url: str) -> dict[int, np.ndarray]:
    """Per session, rows of (start_s, end_s, samples, accel_x, accel_y, accel_z) in id order."""
    rows = _query(url, "SELECT session_id, start_s, end_s, samples, accel_x, accel_y, accel_z "
                  "FROM positions ORDER BY id")  # fmt: skip
    out: dict[int, list] = {}
    for sid, *acc in rows:
        out.setdefault(sid, []).append(acc)
    return {k: np.array(v, dtype=float) for k, v in out.items()}


def _check_db(url: str) -> list[str]:
    failures = []
    if url.startswith("sqlite") and _query(url, "PRAGMA integrity_check")[0][0] != "ok":
        failures.append("integrity_check failed")
    for version, doc in _query(url, "SELECT id, document FROM calibrations ORDER BY id"):
        d = doc if isinstance(doc, dict) else json.loads(doc)
        if not all(k in d for k in ("coefficients", "status", "uncertainty")):
            failures.append(f"version {version} incomplete")
    return failures


def _spooled(folder: Path, url: str) -> tuple[dict[int, int], list[str]]:
    """Per session, the windows in the spool's batch files whose batch the database has not
    committed (a file that outlived its commit is not counted twice); and the files that
    cannot be read (the restart would set them aside: their windows would be lost)."""
    from service.spool import SUFFIX, read_entry

    committed = {k for (k,) in _query(url, "SELECT key FROM spool_batches")}
    out: dict[int, int] = {}
    bad = []
    for path in sorted(folder.glob(f"*{SUFFIX}")) if folder.is_dir() else []:
        if not path.name.split(".", 1)[0].isdigit():
            continue
        try:
            entry = read_entry(path)
        except (OSError, ValueError, KeyError) as exc:
            bad.append(f"{path.name}: {exc}")
            continue
        if entry.key not in committed:
            out[entry.session_id] = out.get(entry.session_id, 0) + entry.size
    return out, bad


def _current(url: str) -> int | None:
    return _query(url, "SELECT max(id) FROM calibrations WHERE accepted")[0][0]


def _versions(url: str) -> int:
    return _query(url, "SELECT count(*) FROM calibrations WHERE accepted")[0][0]


def shipped_method() -> str:
    """The daemon's default ``[scheduler] method``."""
    from service.config import SchedulerSettings

    return SchedulerSettings().method


def _pg_admin() -> Any:
    import psycopg

    return psycopg.connect(PG_ADMIN_URL, autocommit=True, connect_timeout=3)


def _pg_allow(name: str, allow: bool) -> None:
    """Open or close a PostgreSQL database to connections (closing also ends the open ones)."""
    from psycopg import sql

    with _pg_admin() as admin:
        admin.execute(sql.SQL("ALTER DATABASE {} ALLOW_CONNECTIONS {}").format(
            sql.Identifier(name), sql.SQL("true" if allow else "false")))  # fmt: skip
        if not allow:
            admin.execute("SELECT pg_terminate_backend(pid) FROM pg_stat_activity "
                          "WHERE datname = %s", (name,))  # fmt: skip


# ---- processes ----------------------------------------------------------------------------


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _session_processes(sid: int) -> list[int]:
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if os.getsid(int(entry.name)) == sid:
                stat = (entry / "stat").read_text().rsplit(")", 1)[1].split()
                if stat[0] != "Z":
                    out.append(int(entry.name))
        except (ProcessLookupError, FileNotFoundError, PermissionError):
            continue
    return out


def _start(config: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "service.cli.main", "serve", "--config", str(config),
         "--log-level", "ERROR"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True,
    )  # fmt: skip


def _health(port: int) -> dict[str, Any] | None:
    import httpx

    try:
        r = httpx.get(f"http://127.0.0.1:{port}/health", timeout=3)
        return r.json() if r.status_code == 200 else None
    except (httpx.HTTPError, ValueError):
        return None


def _wait_ready(port: int, proc: subprocess.Popen, timeout: float = 90.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"daemon exited {proc.returncode}: {proc.stderr.read()[-400:]}")
        h = _health(port)
        if h is not None:
            return h
        time.sleep(0.1)
    raise RuntimeError("daemon not ready")


def _wait(port: int, until: Any, timeout: float) -> dict[str, Any] | None:
    """Poll /health until ``until(health)``; the last answer (None: timed out)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        h = _health(port)
        if h is not None and until(h):
            return h
        time.sleep(0.05)
    return None


def _kill(proc: subprocess.Popen) -> list[str]:
    """kill -9 the daemon; its job worker must follow within 5 s."""
    sid = proc.pid
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(10)
    deadline = time.monotonic() + 5.0
    while (left := _session_processes(sid)) and time.monotonic() < deadline:
        time.sleep(0.1)
    for p in left:
        with contextlib.suppress(ProcessLookupError):
            os.kill(p, signal.SIGKILL)
    return [f"{len(left)} process(es) left after kill -9: {left}"] if left else []


# ---- one case -------------------------------------------------------------------------------


@dataclass
class Case:
    name: str
    folder: Path
    capture: Path
    size: int
    method: str = field(default_factory=lambda: shipped_method())  # the daemon's jobs'
    port: int = field(default_factory=_free_port)
    url: str = ""
    pg_name: str | None = None
    reference: np.ndarray | None = None
    runs: int = 0
    detected: int = 0  # windows durable at the kills (database + spool, counted after each)
    spooled: int = 0  # of those, in the spool (batches the database had not committed)
    lost: int = 0
    doubled: int = 0
    hit: int = 0  # runs whose kill landed in the phase it aims at
    clear_error: int = 0  # disk-full: /health named the spool folder and ENOSPC
    time_shifted: int = 0  # sessions whose window times moved (see _compare)
    stall_cut: int = 0  # sessions with a window cut short by a reader stall (see _compare)
    failures: list[str] = field(default_factory=list)
    versions: int = 0
    last_version: int | None = None

    @property
    def spool(self) -> Path:
        return self.folder / "spool"

    def config(self, run: int = 0) -> Path:
        from service.config import SchedulerSettings

        learn = self.name == "learning"
        # a new device name each run (the replay's seed option does not change the data): no
        # stored noise floor, so every start learns it again
        device = f"replay://{self.capture}?speed={SPEED:g}&rate={RATE:g}" + (
            f"&seed={run}" if learn else "")  # fmt: skip
        detector = "learn_s = 120\n" if learn else "accel_threshold = 1e-6\ngyro_threshold = 1e4\n"
        trigger = 'trigger = "count"\n' if "trigger" in SchedulerSettings.model_fields else ""
        path = self.folder / "recal.toml"
        path.write_text(
            f'database_url = "{self.url}"\n'
            f'publish_path = "{self.folder / "coefficients.json"}"\n'
            f'spool_dir = "{self.spool}"\n'
            f'[device]\nurl = "{device}"\nrate_hz = {RATE:g}\n'
            "[site]\nlatitude_deg = 45.0\n"
            f"[detector]\n{detector}"
            f'[scheduler]\nmin_positions = 12\nmin_new_positions = 4\nmethod = "{self.method}"\n'
            f"{trigger}"
            "use_last_positions = 30\n"  # sessions pile up: a job stays a few seconds long
            "stop_wait_s = 2\n"
            f"[api]\nport = {self.port}\n"
        )
        return path

    def reference_run(self) -> None:
        """A clean run over the whole capture: the windows every session must be a prefix of."""
        proc = _start(self.config())
        try:
            self._reference(proc)
        finally:
            if proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
        self.reference = _windows(self.url)[1]

    def _reference(self, proc: subprocess.Popen) -> None:
        try:
            _wait_ready(self.port, proc)
            done = _wait(self.port, lambda h: h["service"]["reader"]["counters"]["bytes_in"]
                         >= self.size, timeout=120)  # fmt: skip
            if done is None:
                self.failures.append("reference run: the replay did not finish")
            time.sleep(1.5)  # the detector's last call
            deadline = time.monotonic() + 120  # every case starts from an accepted version
            while _current(self.url) is None and time.monotonic() < deadline:
                time.sleep(0.2)
        finally:
            proc.send_signal(signal.SIGTERM)
            code = proc.wait(60)
        if code != 0:
            self.failures.append(f"reference run exited {code}")

    def check_session(self, run: int, sid: int, detected: int) -> None:
        """After the restart: the killed session's windows, against what it had detected."""
        got = _windows(self.url).get(sid, np.empty((0, 6)))
        self.lost += max(0, detected - len(got))
        doubled = len(got) - len(np.unique(got[:, 3:], axis=0))
        self.doubled += doubled
        if doubled:
            self.failures.append(f"run {run}: {doubled} window(s) stored twice")
        if len(got) < detected:
            self.failures.append(f"run {run}: {detected - len(got)} detected window(s) lost")
        cut = _compare(got, self.reference)
        if cut is None:
            self.failures.append(f"run {run}: session {sid} windows are not a prefix of the clean "
                                 f"run's (starts {np.round(got[:, 0], 2).tolist()})")  # fmt: skip
        elif cut:
            self.stall_cut += 1
        n = min(len(got), len(self.reference))
        if np.any(np.abs(got[:n, 0] - self.reference[:n, 0]) > 1e-6):
            self.time_shifted += 1

    def check_restart(self, run: int, health: dict[str, Any]) -> None:
        """The restarted daemon is up: the published file follows the database; the spool of
        the killed run has been replayed."""
        current = _current(self.url)
        if current is not None:
            time.sleep(0.3)
            published = json.loads((self.folder / "coefficients.json").read_text())["version"]
            if published != current:
                self.failures.append(f"run {run}: file has version {published}, database "
                                     f"{current}")  # fmt: skip
        left = health["service"]["windows_spooled"]
        if left and self.name != "disk-full":
            self.failures.append(f"run {run}: {left} window(s) still spooled after the restart")


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.allclose(a[3:], b[3:], rtol=0, atol=1e-9) and a[2] == b[2])


def _piece(a: np.ndarray, b: np.ndarray) -> bool:
    """``a`` is part of window ``b``: fewer samples of the same position (its mean within
    1e-4 g; the 24 positions differ by about 1 g)."""
    return bool(a[2] < b[2] and np.all(np.abs(a[3:] - b[3:]) < 1e-4))


def _compare(got: np.ndarray, reference: np.ndarray) -> int | None:
    """Whether a session's windows are the clean run's first ones, in order (same samples,
    same mean accelerations): None if not; else how many are only a part of the clean run's
    window (the last one at a clean stop, the window still open; or, at 40x replay on a loaded
    machine, a window cut by a reader stall, after which the frame times are rebuilt whole
    sequence-counter wraps late: the detector saw other windows, nothing was lost). Start
    times are not compared (:attr:`Case.time_shifted` counts sessions whose times moved)."""
    i = j = cut = 0
    while i < len(got):
        if j >= len(reference):
            return None
        if _same(got[i], reference[j]):
            i, j = i + 1, j + 1
            continue
        if not _piece(got[i], reference[j]):
            return None
        while i < len(got) and _piece(got[i], reference[j]):  # one or two parts of it
            i, cut = i + 1, cut + 1
        j += 1
    return cut


def _spool_files(folder: Path) -> bool:
    """Whether a batch is durable in the spool: a ``<seq>.<key>.npz`` file (renamed into place
    after its fsync), not the ``.tmp-`` file still being written (never counted as detected)."""
    try:
        return any(e.name.endswith(".npz") and e.name.split(".", 1)[0].isdigit()
                   for e in os.scandir(folder))  # fmt: skip
    except OSError:
        return False


def aim(case: Case, rng: random.Random, first: dict[str, Any]) -> tuple[dict | None, bool]:
    """Wait for the case's phase; returns the last /health before the kill and whether the
    kill lands in the phase aimed at. The caller kills right after."""
    port = case.port
    if case.name == "learning":
        time.sleep(rng.uniform(0.0, 2.5))  # learn_s = 120 s of device time: 3 s at speed 40
        h = _health(port)
        return h, h is not None and h["service"]["detector"].get("learning_noise_floor", False)
    if case.name == "detecting":  # (a job may run meanwhile: stored windows start them)
        target = rng.randrange(1, 12)
        h = _wait(port, lambda h: h["service"]["windows"] >= target, timeout=15)
        return h, h is not None and h["service"]["windows"] >= target
    if case.name == "storing":
        h = _health(port)
        deadline = time.monotonic() + 12
        while time.monotonic() < deadline:  # a batch between its fsync and its delete
            if _spool_files(case.spool):
                return h, True
            time.sleep(0.0005)
        return h, False
    if case.name == "job":
        h = _wait(port, lambda h: h["service"]["recalibrating"], timeout=15)
        if h is None:
            return _health(port), False
        time.sleep(rng.uniform(0.0, 0.8))
        after = _health(port)
        return after or h, bool(after and after["service"]["recalibrating"])
    if case.name == "publication":
        before = _query(case.url, "SELECT coalesce(max(id), 0) FROM calibrations")[0][0]
        h = _health(port)
        # an MCS-NAFSA job on up to 30 positions with slews takes 10-30 s on 2 cores (LM ~1 s)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:  # the moment a new version is committed
            if _query(case.url, "SELECT coalesce(max(id), 0) FROM calibrations")[0][0] > before:
                return h, True
            time.sleep(0.002)
        return h, False
    if case.name == "outage":
        h = _wait(port, lambda h: h["service"]["windows"] >= 2, timeout=15)
        _pg_allow(case.pg_name, allow=False)
        time.sleep(rng.uniform(0.5, 3.0))
        h = _health(port)
        return h, h is not None and h["service"]["windows_spooled"] > 0
    if case.name == "disk-full":
        time.sleep(rng.uniform(1.0, 6.0))
        h = _health(port)
        said = h is not None and any(
            p.startswith("spool:") and str(case.spool) in p and "ENOSPC" in p
            for p in h["problems"]
        )  # fmt: skip
        case.clear_error += said
        return h, said
    raise ValueError(case.name)


@contextlib.contextmanager
def setup(name: str, root: Path, capture: Path, size: int, method: str) -> Iterator[Case]:
    """The case's folder, database and spool (a PostgreSQL database, a full tmpfs)."""
    folder = root / name
    folder.mkdir()
    case = Case(name, folder, capture, size, method, url=f"sqlite:///{folder / 'recal.db'}")
    mounted = False
    try:
        if name == "outage":
            from psycopg import sql
            from sqlalchemy.engine import make_url

            case.pg_name = f"recal_faults_{secrets.token_hex(4)}"
            with _pg_admin() as admin:
                admin.execute(sql.SQL("CREATE DATABASE {}").format(sql.Identifier(case.pg_name)))
            case.url = (make_url(PG_ADMIN_URL).set(drivername="postgresql+psycopg",
                        database=case.pg_name).render_as_string(hide_password=False))  # fmt: skip
        if name == "disk-full":
            case.spool.mkdir()
            done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=16k", "tmpfs",
                                   str(case.spool)], capture_output=True, text=True)  # fmt: skip
            if done.returncode != 0:
                raise RuntimeError(f"cannot mount a tmpfs: {done.stderr.strip()}")
            mounted = True
            fd = os.open(case.spool / "filler", os.O_WRONLY | os.O_CREAT)
            try:
                while True:
                    os.write(fd, b"\0" * 1024)
            except OSError:
                pass  # ENOSPC: full
            finally:
                os.close(fd)
        yield case
    finally:
        if mounted:
            subprocess.run(["umount", str(case.spool)], check=False)
        if case.pg_name is not None:
            from psycopg import sql

            with _pg_admin() as admin:
                admin.execute(sql.SQL("ALTER DATABASE {} ALLOW_CONNECTIONS true").format(
                    sql.Identifier(case.pg_name)))  # fmt: skip
                admin.execute(sql.SQL("DROP DATABASE {} WITH (FORCE)").format(
                    sql.Identifier(case.pg_name)))  # fmt: skip


def run_case(case: Case, runs: int, rng: random.Random) -> None:
    procs: list[subprocess.Popen] = []
    try:
        _run_case(case, runs, rng, procs)
    finally:  # an error or ^C: no daemon of this case is left running
        for proc in procs:
            if proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(10)


def _run_case(case: Case, runs: int, rng: random.Random, procs: list) -> None:
    case.reference_run()
    print(f"[{case.name}] reference run: {len(case.reference)} windows", flush=True)
    killed: tuple[int, int, int] | None = None  # (run, session, windows detected)
    for run in range(1, runs + 2):  # the last start only checks the run before it
        if case.name == "outage":
            _pg_allow(case.pg_name, allow=True)  # the database is back for the restart
        proc = _start(case.config(run))
        procs.append(proc)
        try:
            first = _wait_ready(case.port, proc)
        except RuntimeError as exc:
            case.failures.append(f"run {run}: (re)start failed: {exc}")
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            break
        if killed is not None:
            case.check_session(*killed)
            case.check_restart(killed[0], first)
        if run > runs:  # the last start: a clean stop must exit 0
            proc.send_signal(signal.SIGTERM)
            if proc.wait(60) != 0:
                case.failures.append(f"final SIGTERM exited {proc.returncode}")
            break
        health, hit = aim(case, rng, first)
        failures = _kill(proc)
        case.runs += 1
        case.hit += hit
        if case.name == "outage":
            _pg_allow(case.pg_name, allow=True)
        # what the kill left durable: the session's rows in the database and in the spool
        sid = first["service"]["session"]
        stored = len(_windows(case.url).get(sid, ()))
        spooled, bad = _spooled(case.spool, case.url)
        durable = stored + spooled.get(sid, 0)
        said = 0 if health is None else health["service"]["windows_detected"]
        if durable < said:
            failures.append(f"/health counted {said} window(s) durable before the kill; the "
                            f"database and the spool hold {durable}")  # fmt: skip
        failures += [f"unreadable spool file {b}" for b in bad]
        detected = max(durable, said)
        case.detected += detected
        case.spooled += spooled.get(sid, 0)
        killed = (run, sid, detected)
        case.failures += [f"run {run}: {f}" for f in failures + _check_db(case.url)]
        print(f"[{case.name}] run {run:3d}: detected {detected:3d} (stored {stored}, spooled "
              f"{spooled.get(sid, 0)}, /health said {said})  phase hit {hit!s:5}  "
              f"versions {_current(case.url)}  failures {len(case.failures)}",
              flush=True)  # fmt: skip
    case.versions = _versions(case.url)
    case.last_version = _current(case.url)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=50, help="runs per case")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cases", default=",".join(CASES), help="comma-separated, from: "
                    + ", ".join(CASES))  # fmt: skip
    ap.add_argument("--method", default=shipped_method(), help="[scheduler] method of the "
                    f"daemon's jobs (default: the shipped one, {shipped_method()})")  # fmt: skip
    args = ap.parse_args()
    print(f"jobs: [scheduler] method = {args.method!r}"
          + (" (the shipped default)" if args.method == shipped_method() else
             f" (the daemon ships {shipped_method()!r})"), flush=True)  # fmt: skip
    stop_on_sigterm()  # cleaned up as after ^C (daemons, mounts, DBs)
    from recal.sim.session import simulate_session
    from service.capture_sim import kvh_like_truth, session_to_kvh

    rng = random.Random(args.seed)
    root = Path(tempfile.mkdtemp(prefix="recal-faults-"))
    session = simulate_session(kvh_like_truth(1), "24", latitude_deg=45.0, seed=1, rate_hz=RATE,
                               window_s=12.0, slew_s=3.0, first_hold_s=12.0)  # fmt: skip
    capture = root / "capture.bin"
    data = session_to_kvh(session, rng=1)[0]
    capture.write_bytes(data)
    results: list[Case] = []
    for name in args.cases.split(","):
        t0 = time.monotonic()
        try:
            with setup(name, root, capture, len(data), args.method) as case:
                results.append(case)
                run_case(case, args.runs, rng)
        except KeyboardInterrupt:
            print(f"[{name}] interrupted", flush=True)
            break
        except Exception as exc:  # noqa: BLE001 - one case's set-up failing is reported
            print(f"[{name}] could not run: {exc}", flush=True)
            continue
        print(f"[{name}] {time.monotonic() - t0:.0f} s", flush=True)
        for f in case.failures:
            print(f"  FAIL {f}", flush=True)
    print(f"\njobs: method {args.method}")
    print(f"{'case':12s} {'runs':>5s} {'detected':>9s} {'in spool':>9s} {'lost':>5s} "
          f"{'doubled':>8s} {'versions':>9s} {'in phase':>9s} {'failures':>9s}")  # fmt: skip
    total = 0
    for c in results:
        total += len(c.failures)
        extra = f"  (clear ENOSPC error in {c.clear_error})" if c.name == "disk-full" else ""
        if c.time_shifted or c.stall_cut:
            extra += (f"  [reader stalls: {c.stall_cut} session(s) with a window cut, "
                      f"{c.time_shifted} time-shifted]")  # fmt: skip
        print(f"{c.name:12s} {c.runs:5d} {c.detected:9d} {c.spooled:9d} {c.lost:5d} {c.doubled:8d} "
              f"{c.versions:9d} {c.hit:5d}/{c.runs:<3d} {len(c.failures):9d}{extra}")  # fmt: skip
    shutil.rmtree(root, ignore_errors=True)
    return 1 if total else 0


if __name__ == "__main__":
    sys.exit(main())
