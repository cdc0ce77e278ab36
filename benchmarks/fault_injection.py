"""Fault injection: kill the daemon or its worker at random moments, restart, check everything.

Each run starts ``recal serve`` (its own process session) on a replayed KVH capture, waits a
random time, and does one of:

* ``kill -9`` of the daemon (a power cut, the OOM killer): its worker must die with it;
* ``kill -9`` of the job's worker (only when a job runs), then SIGTERM to the daemon;
* SIGTERM to the whole process group (``systemctl stop`` with KillMode=control-group).

After each run, and again after the next start (restart), it checks:

1. no process of the killed run is left (workers and swarm children included);
2. ``PRAGMA integrity_check`` is ``ok``;
3. every stored version is complete (coefficients, status, uncertainty) and versions increase;
4. the published file equals the current accepted version once the restarted daemon is up;
5. no window lost or doubled: the windows of every session are a prefix of the windows a clean
   run finds (same order, same means), except at most the one open at the kill;
6. a clean SIGTERM exits 0.

    python benchmarks/fault_injection.py --runs 50        # about 15 s a run
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import socket
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RATE = 100.0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _config(folder: Path, capture: Path, port: int) -> Path:
    path = folder / "recal.toml"
    path.write_text(
        f'database_url = "sqlite:///{folder / "recal.db"}"\n'
        f'publish_path = "{folder / "coefficients.json"}"\n'
        f'[device]\nurl = "replay://{capture}?speed=40&rate={RATE:g}"\nrate_hz = {RATE:g}\n'
        "[site]\nlatitude_deg = 45.0\n"
        "[detector]\naccel_threshold = 1e-6\ngyro_threshold = 1e4\n"
        '[scheduler]\nmin_positions = 12\nmin_new_positions = 4\nmethod = "nafsa"\n'
        "mc_runs = 60\nstop_wait_s = 2\n"
        f"[api]\nport = {port}\n"
    )
    return path


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


def _workers(sid: int, daemon: int) -> list[int]:
    return [p for p in _session_processes(sid) if p != daemon and _is_job_worker(p)]


def _is_job_worker(pid: int) -> bool:
    try:
        return os.getpgid(pid) == pid  # a job's worker leads its own process group
    except ProcessLookupError:
        return False


def _windows(db: Path) -> dict[int, np.ndarray]:
    """Per session, rows of (start_s, accel_x, accel_y, accel_z)."""
    con = sqlite3.connect(db)
    try:
        rows = con.execute(
            "SELECT session_id, start_s, accel_x, accel_y, accel_z FROM positions ORDER BY id"
        ).fetchall()
    finally:
        con.close()
    out: dict[int, list] = {}
    for sid, *acc in rows:
        out.setdefault(sid, []).append(acc)
    return {k: np.array(v) for k, v in out.items()}


def _is_prefix(got: np.ndarray, reference: np.ndarray) -> bool:
    """The windows equal the clean run's first ones; the last may be the window that was open
    at a clean stop (same start, fewer samples, so a slightly different mean)."""
    n = len(got)
    if n > len(reference):
        return False
    whole = np.allclose(got[: n - 1], reference[: n - 1], rtol=0, atol=1e-9)
    return whole and (n == 0 or abs(got[-1, 0] - reference[n - 1, 0]) < 1e-6)


def _check_db(db: Path) -> list[str]:
    failures = []
    con = sqlite3.connect(db)
    try:
        if con.execute("PRAGMA integrity_check").fetchone()[0] != "ok":
            failures.append("integrity_check failed")
        versions = con.execute("SELECT id, document FROM calibrations ORDER BY id").fetchall()
    finally:
        con.close()
    for version, doc in versions:
        d = json.loads(doc)
        if not all(k in d for k in ("coefficients", "status", "uncertainty")):
            failures.append(f"version {version} incomplete")
    return failures


def _current(db: Path) -> int | None:
    con = sqlite3.connect(db)
    try:
        row = con.execute("SELECT max(id) FROM calibrations WHERE accepted").fetchone()
    finally:
        con.close()
    return row[0]


def _start(config: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "service.cli.main", "serve", "--config", str(config),
         "--log-level", "WARNING"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True,
    )  # fmt: skip


def _wait_ready(port: int, proc: subprocess.Popen, timeout: float = 60.0) -> None:
    import httpx

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"daemon exited {proc.returncode}: {proc.stderr.read()[-300:]}")
        try:
            if httpx.get(f"http://127.0.0.1:{port}/health", timeout=2).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    raise RuntimeError("daemon not ready")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    from recal.session import simulate_session
    from service.capture_sim import kvh_like_truth, session_to_kvh

    rng = random.Random(args.seed)
    folder = Path(tempfile.mkdtemp(prefix="recal-faults-"))
    session = simulate_session(kvh_like_truth(1), "24", latitude_deg=45.0, seed=1, rate_hz=RATE,
                               window_s=12.0, slew_s=3.0, first_hold_s=12.0)  # fmt: skip
    capture = folder / "capture.bin"
    capture.write_bytes(session_to_kvh(session, rng=1)[0])
    port = _free_port()
    config = _config(folder, capture, port)
    db = folder / "recal.db"

    # the reference: a clean run's windows
    proc = _start(config)
    _wait_ready(port, proc)
    time.sleep(14)
    proc.send_signal(signal.SIGTERM)
    clean_exit = proc.wait(60) == 0
    reference = _windows(db)[1]
    print(f"reference run: {len(reference)} windows, clean exit {clean_exit}")

    failures: list[str] = [] if clean_exit else ["reference run did not exit 0"]
    kinds = {"daemon -9": 0, "worker -9": 0, "group TERM": 0}
    reported = len(failures)
    for run in range(1, args.runs + 1):
        proc = _start(config)
        try:
            _wait_ready(port, proc)
        except RuntimeError as exc:
            failures.append(f"run {run}: restart failed: {exc}")
            break
        # 4. the published file follows the database from the start
        current = _current(db)
        if current is not None:
            time.sleep(0.5)
            published = json.loads((folder / "coefficients.json").read_text())["version"]
            if published != current:
                failures.append(f"run {run}: file has version {published}, database {current}")
        time.sleep(rng.uniform(0.2, 10.0))
        sid = proc.pid
        workers = _workers(sid, proc.pid)
        kind = rng.choice(["daemon -9", "worker -9", "group TERM"])
        if kind == "worker -9" and not workers:
            kind = "group TERM"
        kinds[kind] += 1
        if kind == "daemon -9":
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait(10)
        elif kind == "worker -9":
            for w in workers:
                os.kill(w, signal.SIGKILL)
            time.sleep(1.0)
            proc.send_signal(signal.SIGTERM)
            if proc.wait(60) != 0:
                failures.append(
                    f"run {run}: SIGTERM after a killed worker exited {proc.returncode}"
                )
        else:
            os.killpg(proc.pid, signal.SIGTERM)
            if proc.wait(60) != 0:
                failures.append(f"run {run}: group SIGTERM exited {proc.returncode}")
        deadline = time.monotonic() + 5.0  # a worker's parent watch reacts within 0.25 s
        while (left := _session_processes(sid)) and time.monotonic() < deadline:
            time.sleep(0.1)
        if left:
            failures.append(f"run {run} ({kind}): {len(left)} process(es) left: {left}")
            for p in left:
                os.kill(p, signal.SIGKILL)
        failures += [f"run {run}: {f}" for f in _check_db(db)]
        for s_id, got in _windows(db).items():
            if not _is_prefix(got, reference):
                failures.append(
                    f"run {run}: session {s_id} windows are not a prefix of the clean run's "
                    f"(starts {np.round(got[:, 0], 2).tolist()})"
                )
        for f in failures[reported:]:
            print("  FAIL", f, flush=True)
        reported = len(failures)
        print(f"run {run:3d}: {kind:10s} windows so far {sum(map(len, _windows(db).values())):5d}"
              f"  versions {_current(db)}  failures {len(failures)}", flush=True)  # fmt: skip
    print(
        f"\n{args.runs} runs ({', '.join(f'{k}: {v}' for k, v in kinds.items())}): "
        f"{len(failures)} failures"
    )
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
