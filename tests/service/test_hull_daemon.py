"""The daemon on a hull-fixed unit (issue 25): ``[detector] motion = "hull"`` in a real daemon
on a replayed KVH capture of berth holds joined by steady turns; the rest check on the still
detector's windows; the hull windows' standard errors through the spool."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import httpx
import numpy as np
import pytest

from drivers import DecoderConfig, decode_bulk
from recal.detect.hull import HullDetector
from recal.detect.hull_config import HullConfig
from recal.detect.rest import RestReference
from recal.errors import RecalInputError
from recal.model.positions import ACCEL_SEM_COLUMNS, GYRO_SEM_COLUMNS
from recal.sim.session import simulate_session
from recal.sim.simulate import NoiseSpec
from recal.sim.vessel import simulate_vessel
from recal.sim.vessel_spec import SeaState, VesselSpec
from service.capture_sim import kvh_like_truth, session_to_kvh
from service.config import (
    DetectorSettings,
    DeviceSettings,
    SchedulerSettings,
    Settings,
    SiteSettings,
)
from service.daemon import build_service
from service.ingest.setup import detector_config
from service.pipeline import DETECTOR_BLOCK, Ingest
from service.spool import Spool
from service.store.repository import Store

RATE = 100.0
LAT = 45.0
KVH_NOISE = NoiseSpec(arw_deg_rt_h=0.012, vrw_ug_rt_hz=20.0)  # KVH 1750 class


def _vessel(holds: int, hold_s: float, sea: SeaState, seed: int):
    rec = simulate_vessel(kvh_like_truth(seed), VesselSpec.berth(holds=holds, hold_s=hold_s,
                          sea=sea), LAT, rate_hz=RATE, noise=KVH_NOISE, seed=seed)  # fmt: skip
    return rec.session, session_to_kvh(rec.session, rng=seed)[0]


@pytest.fixture(scope="module")
def berth():
    """Four 5-minute holds in a 0.5-degree sea (roll 0.5, pitch 0.25, yaw swing 0.17 degrees),
    joined by 30-degree turns of 60 s: 23 minutes at 100 Hz."""
    return _vessel(4, 300.0, SeaState.berth(0.5), seed=5)


def _settings(tmp_path: Path, url: str = "replay://unit", rate_hz: float = RATE, **detector):
    return Settings(
        database_url=f"sqlite:///{tmp_path / 'recal.db'}",
        publish_path=str(tmp_path / "c.json"),
        device=DeviceSettings(url=url, rate_hz=rate_hz),
        site=SiteSettings(latitude_deg=LAT),
        detector=DetectorSettings(**detector),
        scheduler=SchedulerSettings(min_positions=1000, min_new_positions=1000, method="lm"),
    )


def _in_one_hold(session, start_s: float, end_s: float) -> bool:
    """The window [start, end] (s from the first frame) lies inside exactly one hold."""
    a, b = round(start_s * RATE), round(end_s * RATE)
    return int(((session.hold_first <= a) & (b <= session.hold_last)).sum()) == 1


def test_hull_keys_default_to_the_hull_detector_defaults() -> None:
    built = DetectorSettings().hull_config()
    assert built == HullConfig()  # every field, block_s (not a key) included
    tuned = DetectorSettings(hull_max_window_s=600.0, hull_max_swing_deg=0.5).hull_config()
    assert (tuned.max_window_s, tuned.max_swing_deg) == (600.0, 0.5)
    assert dataclasses.replace(tuned, max_window_s=900.0, max_swing_deg=1.0) == built


def test_hull_daemon_stores_the_holds_and_counts_the_turns(tmp_path, berth, serve, replay) -> None:
    """The real daemon (HTTP, reader, ingest thread) on the replayed capture: one window or more
    per hold, none overlapping a turn, quasi-static sems stored, the turns counted in /health."""
    session, data = berth
    capture = tmp_path / "berth.bin"
    capture.write_bytes(data)
    # windows of at most 5 min: the detector decides as the stream goes, not only at its end
    settings = _settings(tmp_path, f"replay://{capture}?speed=max&rate={RATE:g}",
                         motion="hull", hull_max_window_s=300.0)  # fmt: skip
    with serve(settings) as (base, service):
        replay(service, len(data))
        with httpx.Client(base_url=base, timeout=30) as http:
            health = http.get("/health").json()
        positions, ids = service.store.positions(session_id=service.session_id)
        slews = service.store.slews(ids)
    det = health["service"]["detector"]
    assert det["motion"] == "hull" and det["rest_check"] == "navigation-class defaults"
    assert "learning_noise_floor" not in det  # nothing to learn
    # the turns: 3 of 60 s, seen over the 60 s average (blocks of 0.5 s)
    assert det["blocks"]["turning"] * det["block_s"] >= 3 * 60.0, det
    assert set(det["rejected"]) >= {"too_short", "turning", "swinging", "accelerating"}, det
    assert health["positions"] == len(ids) == det["windows_kept"] == health["service"]["windows"]
    cols = positions.columns
    starts, ends = cols["start_s"], cols["end_s"]
    assert all(_in_one_hold(session, a, b) for a, b in zip(starts, ends, strict=True))
    hit = {int(np.searchsorted(session.hold_first, round(a * RATE), side="right")) for a in starts}
    assert hit == set(range(1, session.n_holds + 1))  # every hold gave a window
    assert np.all(ends - starts >= settings.detector.hull_min_window_s - 1.0 / RATE)
    # the windows' own standard errors (white noise plus the waves' residual), stored
    for name in (*GYRO_SEM_COLUMNS, *ACCEL_SEM_COLUMNS):
        assert np.all(np.isfinite(cols[name]) & (cols[name] > 0)), name
    # a 0.5-degree sea leaves more than the white noise in the horizontal rates' sigma
    # (ARW 0.012 deg/sqrt(h) = 0.72 deg/h/sqrt(Hz), through the parabolic weights: x 1.1)
    white = 0.72 * 1.1 / np.sqrt(ends - starts)
    assert np.all(cols["gyro_x_sem"] > white) and np.all(cols["gyro_y_sem"] > white)
    assert slews == []  # no slews on a rocking hull


def test_hull_windows_keep_their_sems_through_the_spool(tmp_path, berth) -> None:
    """Windows spooled while the database refuses them are stored on the replay with the hull
    detector's own means and standard errors (not pooled like a still window's)."""
    session, data = berth
    batch, _ = decode_bulk(data, "kvh-a", DecoderConfig(rate_hz=RATE))
    settings = _settings(tmp_path, motion="hull", hull_max_window_s=300.0)
    ref = RestReference.nominal(LAT)
    cfg = settings.detector.hull_config()
    # the database refuses writes for real: the SQLite file opened read-only
    store = Store(f"sqlite:///{tmp_path / 'r.db'}")
    store.create_schema()
    sid = store.add_session("replay://unit")
    refusing = Store(f"sqlite:///file:{tmp_path / 'r.db'}?mode=ro&uri=true")
    first = Ingest(refusing, sid, detector_config(settings), spool=Spool(tmp_path / "spool"),
                   rest=ref, hull=cfg)  # fmt: skip
    alone = HullDetector(ref, cfg, rate_hz=RATE)  # the same chunks: the same windows
    want = []
    for lo in range(0, len(batch), DETECTOR_BLOCK):
        b = batch[lo : lo + DETECTOR_BLOCK]
        first.feed(b)
        want += alone.feed(b.time_s, b.gyro_dph, b.accel_g, b.temperature_c, b.valid)
    first.flush()
    want += alone.flush()
    assert first.windows == 0 and first.detected == len(want) >= session.n_holds
    second = Ingest(store, store.add_session("replay://unit"), detector_config(settings),
                    spool=Spool(tmp_path / "spool"), rest=ref, hull=cfg)  # fmt: skip
    assert len(second.replay()) == len(want)
    cols = store.positions(session_id=sid)[0].columns
    for names, field in ((GYRO_SEM_COLUMNS, "gyro_sem"), (ACCEL_SEM_COLUMNS, "accel_sem"),
                         (("gyro_x", "gyro_y", "gyro_z"), "gyro")):  # fmt: skip
        got = np.column_stack([cols[n] for n in names])
        np.testing.assert_array_equal(got, [getattr(hw.window, field) for hw in want])
    store.close()
    refusing.close()


def _run_still(tmp_path: Path, data: bytes, rate_hz: float) -> tuple[list, dict, list[str]]:
    """The still detector in a service fed the decoded capture in 1 s batches."""
    service = build_service(_settings(tmp_path, rate_hz=rate_hz), with_reader=False)
    try:
        batch, _ = decode_bulk(data, "kvh-a", DecoderConfig(rate_hz=rate_hz))
        step = int(rate_hz)
        for lo in range(0, len(batch), step):
            service.ingest.feed(batch[lo : lo + step])
        service.ingest.flush()
        cols = service.store.positions(session_id=service.session_id)[0].columns
        spans = list(zip(cols.get("start_s", []), cols.get("end_s", []), strict=True))
        health = service.health()["detector"]
        device = [e["message"] for e in service.store.events(100) if e["kind"] == "device"]
    finally:
        service.close(wait_s=0)
    return spans, health, device


def test_still_detector_refuses_steady_turns_in_physics(tmp_path) -> None:
    """A perfectly still hull: the moving variance keeps the steady part of each turn; the rest
    check refuses it as turning (the issue's 2691 deg/h "window")."""
    session, data = _vessel(3, 120.0, SeaState.calm(), seed=6)
    spans, health, device = _run_still(tmp_path, data, RATE)
    assert health["motion"] == "still" and health["rest_check"] == "navigation-class defaults"
    assert health["rejected"].get("turning", 0) >= 2, health  # both turns
    assert len(spans) == session.n_holds == health["windows_kept"]
    assert all(_in_one_hold(session, a, b) for a, b in spans)
    assert device == []  # the turns are not blamed on a setting


def test_a_rate_setting_ten_times_too_high_is_named(tmp_path) -> None:
    """Every window reads ten times Earth's rate and so fails the rest check: the device event
    names [device] rate_hz, as the scheduler would for stored windows."""
    session = simulate_session(kvh_like_truth(8), "24", latitude_deg=LAT, seed=8, rate_hz=RATE,
                               window_s=15.0, slew_s=3.0, first_hold_s=15.0)  # fmt: skip
    data = session_to_kvh(session, rng=8)[0]
    spans, health, device = _run_still(tmp_path, data, 10 * RATE)
    assert spans == [] and sum(health["rejected"].values()) >= session.n_holds
    assert len(device) == 1 and "[device] rate_hz 1000 (these windows suggest 100 Hz)" in device[0]


def test_hull_motion_needs_outputs_in_physical_units(tmp_path) -> None:
    settings = _settings(tmp_path, motion="hull").model_copy(
        update={"device": DeviceSettings(url="replay://unit", format="csv", rate_hz=RATE)}
    )
    with pytest.raises(RecalInputError, match='motion = "hull".*prior_path'):
        build_service(settings, with_reader=False)
