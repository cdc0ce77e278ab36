"""The daemon with the ship's sensors (issue 36): ``[nav] url`` over a real UDP socket on
127.0.0.1 and over a pseudo-terminal serial line, windows stored with the stream's latitude,
the hull detector's rest reference rebuilt at it, the underway rule in the pipeline, and a
hull-fixed unit that has neither ``[nav]`` nor ``[site] latitude_deg`` refused at start."""

from __future__ import annotations

import datetime as dt
import os
import socket
import sys
import threading
import time
import tty
from pathlib import Path

import httpx
import numpy as np
import pytest

from drivers import DecoderConfig, decode_bulk
from drivers.nmea import NavFix, epoch_sentences
from recal.model.reference import normal_gravity_g
from recal.sim.session import simulate_session
from recal.sim.simulate import NoiseSpec
from recal.sim.vessel import simulate_vessel
from recal.sim.vessel_spec import SeaState, VesselSpec
from service.capture_sim import kvh_like_truth, session_to_kvh
from service.cli.main import main
from service.config import (
    DetectorSettings,
    DeviceSettings,
    NavSettings,
    SchedulerSettings,
    Settings,
    load_settings,
)
from service.daemon import build_service

RATE = 100.0
#: Where the simulated IMU is, and the ship's sensors say it is (a little off: not the default).
LAT = 57.7
SHIP_LAT = 57.71234
START = dt.datetime(2026, 3, 1, 12, 0, 0, tzinfo=dt.UTC)


def _epoch(k: int, sog_kn: float = 0.1) -> bytes:
    """One second of the ship's talkers: GGA, RMC, VTG, HDT."""
    return epoch_sentences(START + dt.timedelta(seconds=k), SHIP_LAT, 11.9, 5.0, sog_kn, 40.0,
                           123.4)  # fmt: skip


class Talker:
    """The ship's sensors sending an epoch every ``period_s`` to ``send`` until stopped."""

    def __init__(self, send, period_s: float = 0.05) -> None:
        self._send, self.period_s = send, period_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self.sent = 0

    def _run(self) -> None:
        while not self._stop.is_set():
            self._send(_epoch(self.sent))
            self.sent += 1
            self._stop.wait(self.period_s)

    def __enter__(self) -> Talker:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(2)


def _wait_until(pred, timeout: float = 20.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.02)
    return pred()


@pytest.fixture(scope="module")
def still_capture():
    """A still unit at LAT: 6 holds of 12 s (the first 25 s) at 100 Hz, 1.5 min."""
    session = simulate_session(kvh_like_truth(3), "random", n_positions=6, latitude_deg=LAT,
                               seed=3, rate_hz=RATE, window_s=12.0, slew_s=3.0,
                               first_hold_s=25.0)  # fmt: skip
    return session, session_to_kvh(session, rng=3)[0]


def _settings(tmp_path: Path, capture: Path, nav_url: str, **detector) -> Settings:
    return Settings(
        database_url=f"sqlite:///{tmp_path / 'recal.db'}",
        publish_path=str(tmp_path / "c.json"),
        device=DeviceSettings(url=f"replay://{capture}?speed=max&rate={RATE:g}", rate_hz=RATE),
        detector=DetectorSettings(**detector),
        nav=NavSettings(url=nav_url),
        scheduler=SchedulerSettings(min_positions=1000, min_new_positions=1000, method="lm"),
        api={"port": 0},
    )


def _stored_with_ship(service, n_windows: int) -> dict:
    positions, ids = service.store.positions(session_id=service.session_id)
    cols = positions.columns
    assert len(ids) == n_windows
    np.testing.assert_allclose(cols["latitude_deg"], SHIP_LAT, atol=1e-6)
    np.testing.assert_allclose(cols["sog_kn"], 0.1, atol=1e-9)
    np.testing.assert_allclose(cols["heading_deg"], 123.4, atol=1e-9)
    return cols


@pytest.mark.slow
def test_daemon_reads_nav_over_udp_and_stores_the_latitude(
    tmp_path, still_capture, serve, replay
) -> None:
    """The real daemon (HTTP, IMU reader, ingest thread, nav reader) with [nav] on a UDP port
    of 127.0.0.1: every window stored carries the stream's latitude, speed and heading; the
    still unit's rest check uses the stream's latitude; /health shows the link."""
    session, data = still_capture
    capture = tmp_path / "still.bin"
    capture.write_bytes(data)
    settings = _settings(tmp_path, capture, "udp://127.0.0.1:0", init_still_s=20.0,
                         min_duration_s=5.0)  # fmt: skip
    assert settings.site_latitude_deg is None  # a still unit with [nav]: no 45 assumed
    with serve(settings) as (base, service):
        service.nav.start()
        assert _wait_until(lambda: service.nav.reader.port is not None)
        port = service.nav.reader.port.local_port
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            with Talker(lambda b: tx.sendto(b, ("127.0.0.1", port))):
                assert _wait_until(lambda: service.nav.latitude_deg() is not None)
                tx.sendto(b"$GPGGA,not a sentence*00\r\n", ("127.0.0.1", port))
                replay(service, len(data))
            with httpx.Client(base_url=base, timeout=30) as http:
                health = http.get("/health").json()
        cols = _stored_with_ship(service, session.n_holds)
        rest = service.ingest.rest_check.reference
        events = [e["message"] for e in service.store.events(100) if e["kind"] == "nav"]
    nav = health["service"]["nav"]
    assert nav["state"] == "ok" and nav["url"] == "udp://127.0.0.1:0" and nav["fixes"] >= 4
    assert nav["latitude_deg"] == pytest.approx(SHIP_LAT, abs=1e-6)
    assert nav["counters"]["bad_checksum"] == 1
    assert health["service"]["detector"]["rejected"]["underway"] == 0
    assert rest.gravity_g == pytest.approx(normal_gravity_g(SHIP_LAT, 0.0), abs=1e-12)
    assert len(events) == 1 and "57.7123" in events[0]
    # a still ship: the transport rate of its (zero) displacement adds nothing to the sigma
    assert np.all(np.isfinite(cols["gyro_x_sem"]))


class NmeaPty:
    """The ship's talker on a serial line: a pty's device side behind a symlink."""

    def __init__(self, link: Path) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.symlink(os.ttyname(self.slave), link)
        self.link = link

    def send(self, data: bytes) -> None:
        os.write(self.master, data)

    def close(self) -> None:
        os.unlink(self.link)
        os.close(self.master)
        os.close(self.slave)


@pytest.fixture(scope="module")
def berth():
    """A hull-fixed unit at LAT: three 4-minute holds in a 0.3-degree sea joined by 30-degree
    turns, 100 Hz (13.3 min)."""
    noise = NoiseSpec(arw_deg_rt_h=0.012, vrw_ug_rt_hz=20.0)
    rec = simulate_vessel(kvh_like_truth(4), VesselSpec.berth(holds=3, hold_s=240.0,
                          sea=SeaState.berth(0.3)), LAT, rate_hz=RATE, noise=noise, seed=4)  # fmt: skip
    return rec.session, session_to_kvh(rec.session, rng=4)[0]


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux ptys")
def test_hull_daemon_takes_its_latitude_from_a_serial_talker(tmp_path, berth, serve, replay):
    """Hull mode with [nav] on a serial line (a pseudo-terminal) and no [site] latitude_deg:
    the hull detector starts at an unknown latitude, its rest reference is rebuilt at the
    stream's once it arrives, and every hold's window is stored with it."""
    session, data = berth
    capture = tmp_path / "berth.bin"
    capture.write_bytes(data)
    talker = NmeaPty(tmp_path / "gps")
    settings = _settings(tmp_path, capture, str(talker.link), motion="hull",
                         hull_max_window_s=240.0)  # fmt: skip
    try:
        with serve(settings) as (_, service):
            # no latitude assumed: gravity anywhere between the equator's and the pole's
            assert service.ingest.hull.detector.ref.gravity_unknown_g > 0
            service.nav.start()
            with Talker(talker.send):
                assert _wait_until(lambda: service.nav.latitude_deg() is not None)
                replay(service, len(data))
            cols = _stored_with_ship(service, session.n_holds)
            ref = service.ingest.hull.detector.ref
            health = service.health()
    finally:
        talker.close()
    assert ref.gravity_unknown_g == 0
    assert ref.gravity_g == pytest.approx(normal_gravity_g(SHIP_LAT, 0.0), abs=1e-12)
    # the ship's heading reached the hull detector: a window it covers has its creep measured
    # from it (HDT holds at 123.4: none) and its vertical rate stays a measurement; a window
    # the replay outran (faster than real time) has it estimated and its vertical rate free
    measured = np.abs(cols["creep_dph"]) < 1e-6
    assert measured.any()
    vertical = cols.get("gyro_vertical", np.ones(len(measured)))
    assert np.all(vertical[measured] != 0) and np.all(vertical[~measured] == 0)
    assert health["nav"]["state"] in ("ok", "silent") and health["nav"]["connected"]
    assert health["detector"]["rejected"]["underway"] == 0


def test_windows_taken_under_way_are_rejected_and_counted(tmp_path, still_capture) -> None:
    """The pipeline's underway rule on decoded frames with host times: the ship makes 5 kn from
    half-way through the recording, so the windows after that are rejected as underway and
    counted; those before are stored with the ship's state, their gyro sigma grown by the
    transport rate of their (tiny) net displacement only."""
    session, data = still_capture
    settings = _settings(tmp_path, tmp_path / "unused.bin", "udp://127.0.0.1:0",
                         init_still_s=20.0, min_duration_s=5.0)  # fmt: skip
    service = build_service(settings, with_reader=False)
    try:
        batch, _ = decode_bulk(data, "kvh-a", DecoderConfig(rate_hz=RATE))
        h0 = 1000.0  # the host's clock when the first frame came
        batch.host_time_s[:] = h0 + batch.time_s
        half = float(batch.time_s[-1]) / 2
        t = np.arange(0.0, float(batch.time_s[-1]) + 5.0, 0.5)
        speed = np.where(t < half, 0.0, 5.0)  # kn, due north
        north = np.cumsum(speed * 1852.0 / 3600.0 * 0.5)
        lat = SHIP_LAT + np.degrees(north / 6.36e6)
        service.nav.track.add(NavFix(h0 + tk, "GP", "RMC", lat=la, lon=11.9, sog_kn=v,
                                     heading_deg=0.0) for tk, la, v in zip(t, lat, speed))  # fmt: skip
        for lo in range(0, len(batch), int(RATE)):
            service.ingest.feed(batch[lo : lo + int(RATE)])
        service.ingest.flush()
        positions, ids = service.store.positions(session_id=service.session_id)
        health = service.health()["detector"]
    finally:
        service.close(wait_s=0)
    cols = positions.columns
    rejected = health["rejected"]["underway"]
    assert rejected >= 2 and len(ids) + rejected == session.n_holds
    assert np.all(cols["end_s"] < half) and np.all(cols["sog_kn"] == 0.0)
    assert health["windows_kept"] == len(ids)


def test_hull_mode_without_nav_or_latitude_exits_2_naming_both(tmp_path, capsys) -> None:
    config = tmp_path / "recal.toml"
    config.write_text('[device]\nurl = "loop://"\n[detector]\nmotion = "hull"\n')
    assert main(["serve", "--config", str(config)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("recal serve: error: ") and err.count("\n") == 1
    assert "[nav] url" in err and "[site] latitude_deg" in err
    # either one is enough
    for extra in ('[nav]\nurl = "udp://:10110"\n', "[site]\nlatitude_deg = 57.7\n"):
        config.write_text('[detector]\nmotion = "hull"\n' + extra)
        assert load_settings(config).detector.motion == "hull"


def test_a_logged_talker_replays_on_the_captures_clock(tmp_path) -> None:
    """``[nav] log`` (a replayed capture's logged talker): a missing file or both sources are
    refused; windows join the log by their own times (from the first frame), whatever the
    replay's speed, and the frames' heading comes from it too."""
    from pydantic import ValidationError

    from service.config import NavSettings
    from service.nav import ShipSensors

    with pytest.raises(ValidationError, match="is not a file"):
        NavSettings(log=str(tmp_path / "none.nmea"))
    log = tmp_path / "ship.nmea"
    log.write_bytes(b"".join(_epoch(k) for k in range(600)))
    with pytest.raises(ValidationError, match="not both"):
        NavSettings(log=str(log), url="udp://127.0.0.1:0")
    nav = ShipSensors(NavSettings(log=str(log)))
    assert nav.reader is None and nav.on_device_clock
    seen = []
    nav.on_latitude = seen.append
    nav.start()
    assert seen == [pytest.approx(SHIP_LAT)]

    class Batch:  # the frames' device times 1000 s on, read at any host time
        time_s = np.arange(1000.0, 1600.0, 0.5)
        host_time_s = np.full(len(time_s), 5.0)

    nav.observe(Batch)

    class W:
        start_s, end_s = 100.0, 400.0

    (ship,) = nav.over([W])
    assert ship.latitude_deg == pytest.approx(SHIP_LAT) and ship.heading_deg == pytest.approx(123.4)
    psi = nav.heading_of(Batch.time_s)
    assert np.allclose(psi[Batch.time_s < 1599.0], 123.4)
