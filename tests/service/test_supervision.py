"""What a vessel does to the daemon: a killed worker, a database outage, a restart mid-job, and
``systemctl stop`` signalling the whole control group (issue 8)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from drivers import DecoderConfig, decode_bulk
from recal.sim.session import simulate_session
from service.capture_sim import kvh_like_truth, session_to_kvh
from service.config import DetectorSettings, DeviceSettings, SchedulerSettings, Settings
from service.daemon import build_service
from service.store.errors import StoreError
from service.store.repository import Store

RATE = 100.0


@pytest.fixture(scope="module")
def capture() -> bytes:
    session = simulate_session(kvh_like_truth(4), "24", latitude_deg=45.0, seed=4, rate_hz=RATE,
                               window_s=12.0, slew_s=3.0, first_hold_s=12.0)  # fmt: skip
    return session_to_kvh(session, rng=4)[0]


def _settings(url: str, tmp_path: Path, **scheduler) -> Settings:
    return Settings(
        database_url=url,
        publish_path=str(tmp_path / "c.json"),
        spool_dir=str(tmp_path / "spool"),
        device=DeviceSettings(url="replay://unit", rate_hz=RATE),
        detector=DetectorSettings(accel_threshold=1e-6, gyro_threshold=1e4),
        scheduler=SchedulerSettings(
            **({"min_positions": 1000, "min_new_positions": 1000} | scheduler)
        ),  # fmt: skip
    )


def _feed(service, data: bytes, part: slice = slice(None)) -> None:
    """Decode the capture and feed frames ``part`` in 1 s batches, as the reader would."""
    batch, _ = decode_bulk(data, "kvh-a", DecoderConfig(rate_hz=RATE))
    batch = batch[part]
    for lo in range(0, len(batch), int(RATE)):
        service.ingest.feed(batch[lo : lo + int(RATE)])


def test_a_killed_worker_is_recorded_and_the_next_trigger_works(tmp_path, capture) -> None:
    settings = _settings(f"sqlite:///{tmp_path / 'r.db'}", tmp_path, method="nafsa",
                         mc_runs=3000)  # fmt: skip
    service = build_service(settings, with_reader=False)
    try:
        _feed(service, capture)
        service.ingest.flush()
        assert service.store.count_positions() == 24
        service.scheduler.trigger("manual")
        runner = service.scheduler._runner
        deadline = time.monotonic() + 60
        while runner._running is None:
            assert time.monotonic() < deadline
            time.sleep(0.05)
        os.kill(runner._running.process.pid, signal.SIGKILL)
        service.scheduler.wait(timeout=60)
        health = service.health()
        assert health["scheduler"]["last_job"]["status"] == "died"
        assert "signal 9" in health["scheduler"]["last_job"]["message"]
        assert not health["recalibrating"]
        events = [e["message"] for e in service.store.events(limit=20)]
        assert any("failed (died)" in m for m in events)
        # the next job works: MCS-NAFSA (with the 23 slews) stores a version. Its time is
        # benchmarks/bench_mcs_slews.py's to measure; 10 runs show the worker is sound again
        service.scheduler._settings = settings.model_copy(
            update={"scheduler": settings.scheduler.model_copy(update={"mc_runs": 10})}
        )
        service.scheduler.trigger("manual")
        outcome = service.scheduler.wait(timeout=120)
        assert outcome is not None and outcome.document is not None
        assert service.scheduler.last_end.status == "ok"
        assert outcome.document["method"] == "nafsa" and outcome.document["mc"]["runs"] == 10
        assert "slew" in outcome.document["residuals"]
        assert service.store.current() is not None  # the version is stored
    finally:
        service.close(wait_s=0)


def test_a_trigger_that_cannot_run_says_why(tmp_path) -> None:
    from service.scheduler import SchedulerRefused

    service = build_service(_settings(f"sqlite:///{tmp_path / 'r.db'}", tmp_path),
                            with_reader=False)  # fmt: skip
    try:
        with pytest.raises(SchedulerRefused, match="no positions"):
            service.scheduler.trigger("manual")
        with pytest.raises(SchedulerRefused, match="scheduler.min_positions"):
            service.scheduler.trigger("auto")
        # four stored windows: the engine's own reason, at once (not a 202 and a failed job)
        from recal.sim.simulate import simulate_positions

        four = simulate_positions(kvh_like_truth(4), design="random", n_positions=4)
        service.store.add_positions(service.session_id, four.columns)
        with pytest.raises(SchedulerRefused, match="4 stored positions cannot be used.*rank"):
            service.scheduler.trigger("manual")
        assert not service.scheduler.busy
        # a KVH outputs deg/h and g: windows at a tenth of Earth's rate mean a wrong rate_hz,
        # said before anything is calibrated (and published with a scale factor of 0.1)
        slow = {k: v / 10 if k.startswith("gyro_") else v for k, v in four.columns.items()}
        service.store.add_positions(service.session_id, slow)
        with pytest.raises(SchedulerRefused, match=r"rate_hz 100 \(these windows suggest"):
            service.scheduler.trigger("manual")
        assert "[device] rate_hz" in service.store.last_event("device")["message"]
    finally:
        service.close(wait_s=0)


@pytest.mark.slow
def test_no_window_is_lost_to_a_database_outage(
    tmp_path, capture, pg_database, block_database
) -> None:
    name, url = pg_database
    service = build_service(_settings(url, tmp_path), with_reader=False)
    try:
        half = len(capture) // 36 // 2
        _feed(service, capture, slice(0, half))
        before = service.store.count_positions()
        assert before > 5
        block_database(name, allow=False)
        _feed(service, capture, slice(half, None))
        service.ingest.flush()
        assert service.ingest.spooled > 0  # waiting, not dropped
        health = service.health()
        assert health["status"] == "degraded"
        assert any(p.startswith("database:") for p in health["problems"])
        block_database(name, allow=True)
        deadline = time.monotonic() + 60
        while service.ingest.spooled:
            assert time.monotonic() < deadline, "spooled windows were never stored"
            service.ingest.poll()
            time.sleep(0.2)
        assert service.store.count_positions() == 24
        assert service.ingest.windows_dropped == 0
        assert service.health()["status"] == "ok"
    finally:
        service.close(wait_s=0)


def test_a_restart_resumes_the_interrupted_job(tmp_path, capture) -> None:
    url = f"sqlite:///{tmp_path / 'r.db'}"
    # the estimator does not matter to what is resumed: LM takes seconds where MCS-NAFSA takes tens
    service = build_service(_settings(url, tmp_path, method="lm"), with_reader=False)
    _feed(service, capture)
    service.ingest.flush()
    # a job was running when the power went: its start is recorded, its end never was
    service.events.emit("job", "recalibration 1 started (auto)", {"job": 1, "state": "started"})
    service.close(wait_s=0)
    service = build_service(_settings(url, tmp_path, method="lm"), with_reader=False)
    try:
        assert service.scheduler.resume() is not None
        outcome = service.scheduler.wait(timeout=120)
        assert outcome is not None and outcome.document is not None
        assert service.store.history(limit=1)[0].trigger == "resume"
        # nothing interrupted and no new positions: a second restart starts nothing
        assert service.scheduler.resume() is None
    finally:
        service.close(wait_s=0)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_sigterm_to_the_whole_group_mid_job_exits_0(tmp_path, capture) -> None:
    """What `systemctl stop` does with KillMode=control-group: every process gets SIGTERM."""
    (tmp_path / "capture.bin").write_bytes(capture)
    port = _free_port()
    (tmp_path / "recal.toml").write_text(
        f'database_url = "sqlite:///{tmp_path / "r.db"}"\npublish_path = "{tmp_path / "c.json"}"\n'
        f'[device]\nurl = "replay://{tmp_path / "capture.bin"}?speed=max&rate=100"\n'
        f"rate_hz = 100\n[detector]\naccel_threshold = 1e-6\ngyro_threshold = 1e4\n"
        f'[scheduler]\nmin_positions = 12\nmin_new_positions = 4\nmethod = "nafsa"\n'
        f"mc_runs = 3000\nstop_wait_s = 1\n[api]\nport = {port}\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-m", "service.cli.main", "serve", "--config", str(tmp_path / "recal.toml")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
    )  # fmt: skip
    try:
        store = None
        deadline = time.monotonic() + 90
        while True:  # wait until a (long) swarm job is running
            assert time.monotonic() < deadline, "no job started"
            assert proc.poll() is None, proc.communicate()[1]
            time.sleep(0.5)
            if not (tmp_path / "r.db").exists():
                continue
            store = store or Store(f"sqlite:///{tmp_path / 'r.db'}")
            try:
                if store.last_event("job", state="started") is not None:
                    break
            except StoreError:  # the daemon has not created its tables yet
                continue
        time.sleep(1.0)
        os.killpg(proc.pid, signal.SIGTERM)
        _, err = proc.communicate(timeout=150)
        assert proc.returncode == 0, err
        assert "internal error" not in err
        ended = store.last_event("job", state="ended")
        assert ended is not None and ended["data"]["status"] == "cancelled"
        assert store.last_event("stop") is not None
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        if store is not None:
            store.close()


def test_start_republishes_what_a_crash_left_behind(tmp_path, make_record) -> None:
    """A crash between the commit of an accepted version and the file write: the next start
    writes the file; an unwritable file is 'degraded' with the reason, then written when it can."""
    import json

    url = f"sqlite:///{tmp_path / 'r.db'}"
    store = Store(url)
    store.create_schema()
    version = store.add_calibration(make_record())
    store.close()
    settings = _settings(url, tmp_path)
    service = build_service(settings, with_reader=False)
    try:
        published = json.loads((tmp_path / "c.json").read_text())
        assert published["version"] == version
        (tmp_path / "c.json").unlink()
        (tmp_path / "c.json").mkdir()  # the file cannot be written now
        service.sync_published()
        health = service.health()
        assert health["status"] == "degraded"
        assert any(p.startswith("publisher: cannot write") for p in health["problems"])
        (tmp_path / "c.json").rmdir()
        service.tick()  # housekeeping retries at once after a failure
        assert json.loads((tmp_path / "c.json").read_text())["version"] == version
        assert service.health()["status"] == "ok"
    finally:
        service.close(wait_s=0)


def _catches_sigterm(pid: int) -> bool:
    """Whether the process has installed a SIGTERM handler (SigCgt in /proc/PID/status)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    caught = next(line for line in status.splitlines() if line.startswith("SigCgt:"))
    return bool(int(caught.split()[1], 16) >> (signal.SIGTERM - 1) & 1)


def _api_up(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.2):
            return True
    except OSError:
        return False


def test_sigterm_during_start_exits_0(tmp_path, capture) -> None:
    """SIGTERM while importing (before any handler: systemd counts death by SIGTERM as a clean
    stop), the moment the handler is installed (loading and checking the settings), and once the
    API answers (learning the noise floor). The phases are reached by watching the process, not
    by fixed delays, which a loaded machine stretches past (it took over 2 s to import once)."""
    api_port = _free_port()
    (tmp_path / "capture.bin").write_bytes(capture)
    (tmp_path / "recal.toml").write_text(
        f'database_url = "sqlite:///{tmp_path / "r.db"}"\npublish_path = "{tmp_path / "c.json"}"\n'
        f'[device]\nurl = "replay://{tmp_path / "capture.bin"}?speed=1&rate=100"\n'
        f"rate_hz = 100\n[api]\nport = {api_port}\n"
    )
    for phase in ("importing", "settings", "learning"):
        proc = subprocess.Popen(
            [sys.executable, "-m", "service.cli.main", "serve", "--config",
             str(tmp_path / "recal.toml")],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        deadline = time.monotonic() + 60
        if phase == "importing":
            time.sleep(0.05)
        else:
            pid = proc.pid

            def ready(pid: int = pid, phase: str = phase) -> bool:
                return _catches_sigterm(pid) if phase == "settings" else _api_up(api_port)

            while not ready() and proc.poll() is None and time.monotonic() < deadline:
                time.sleep(0.005)
            assert proc.poll() is None, f"{phase}: the daemon ended before the signal"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 0 or (
            phase == "importing" and proc.returncode == -signal.SIGTERM
        ), (phase, err)
        assert "error" not in err.lower(), err
