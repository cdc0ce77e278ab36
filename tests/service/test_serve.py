"""`recal serve` as a real process: systemd readiness, HTTP, clean stop on SIGTERM."""

import os
import signal
import socket
import subprocess
import sys
import time

import httpx
import pytest

from recal.sim.session import simulate_session
from service.capture_sim import kvh_like_truth, session_to_kvh
from service.store.repository import Store


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_serve_process_notifies_systemd_serves_and_stops_on_sigterm(tmp_path, systemd):
    session = simulate_session(kvh_like_truth(2), "24", latitude_deg=50.0, seed=2, rate_hz=100.0,
                               window_s=15.0, slew_s=3.0, first_hold_s=30.0)  # fmt: skip
    capture = tmp_path / "capture.bin"
    capture.write_bytes(session_to_kvh(session, rng=2)[0])
    port = _free_port()
    db = tmp_path / "recal.db"
    (tmp_path / "recal.toml").write_text(
        f'database_url = "sqlite:///{db}"\npublish_path = "{tmp_path / "c.json"}"\n'
        f'[device]\nurl = "replay://{capture}?speed=max&rate=100"\nrate_hz = 100\n'
        f"[site]\nlatitude_deg = 50.0\n[detector]\ninit_still_s = 20\nmin_duration_s = 5\n"
        # MCS-NAFSA (the default method) on 20 Monte Carlo runs: this test checks systemd's
        # protocol around a real job, not the engine (bench_mcs_slews times the default 100)
        f"[scheduler]\nmc_runs = 20\n[api]\nport = {port}\n"
    )
    # NOTIFY_SOCKET names the ``systemd`` fixture's socket; WatchdogSec=2: petted every 1 s
    env = {**os.environ, "WATCHDOG_USEC": "2000000"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "service.cli.main", "serve", "--config",
         str(tmp_path / "recal.toml"), "--log-level", "WARNING"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert systemd.wait_for(b"READY=1") == [b"READY=1"]
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=10) as http:
            deadline = time.monotonic() + 60
            # 23 windows close as the capture plays; the last one when it ends
            while http.get("/health").json()["positions"] < 23:
                assert time.monotonic() < deadline, http.get("/health").json()
                time.sleep(0.2)
            # the scheduler has run its first MCS-NAFSA job (generous: 2 busy cores make it
            # several times slower than the ~2 s it takes on a quiet machine)
            deadline = time.monotonic() + 300
            while http.get("/coefficients").status_code != 200:
                assert time.monotonic() < deadline, http.get("/coefficients/history").json()
                time.sleep(0.2)
        systemd.wait_for(b"WATCHDOG=1")  # every part lives: the watchdog is petted
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0, proc.stderr.read()
        # and nothing said that a part had died
        assert set(systemd.wait_for(b"STOPPING=1")) == {b"READY=1", b"WATCHDOG=1", b"STOPPING=1"}
    finally:
        if proc.poll() is None:
            proc.kill()
    store = Store(f"sqlite:///{db}")
    events = [e["kind"] for e in store.events(limit=100)]
    assert "start" in events and "stop" in events and "calibration" in events
    assert store.count_positions() == 24  # the last window was closed at the end of input
