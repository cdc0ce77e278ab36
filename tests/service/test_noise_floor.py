"""The daemon's detector noise floor: learned without flags, stored with the device, reused after
a restart that happens while the unit moves, refined only from windows that passed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from drivers import DecoderConfig, decode_bulk
from recal.sim.session import simulate_session
from service.capture_sim import kvh_like_truth, session_to_kvh
from service.config import DetectorSettings, DeviceSettings, SchedulerSettings, Settings
from service.daemon import build_service

RATE = 200.0
FRAME = 36  # bytes of a Format-A frame


@pytest.fixture(scope="module")
def session():
    # long slews: a restart lands in seconds of motion, as on a vessel under way
    return simulate_session(kvh_like_truth(8), "24", latitude_deg=45.0, seed=8, rate_hz=RATE,
                            window_s=15.0, slew_s=20.0, first_hold_s=15.0)  # fmt: skip


def _settings(tmp_path: Path, **detector) -> Settings:
    return Settings(
        database_url=f"sqlite:///{tmp_path / 'recal.db'}",
        publish_path=str(tmp_path / "c.json"),
        device=DeviceSettings(url="replay://unit", rate_hz=RATE),  # one device for all runs
        detector=DetectorSettings(**detector),
        scheduler=SchedulerSettings(min_positions=1000, min_new_positions=1000),
    )


def _run(settings: Settings, data: bytes) -> tuple[list[tuple[float, float]], dict]:
    """Feed decoded frames to a freshly built service (as the reader would, in 1 s batches);
    return the windows stored (start, end frame times of the session) and the detector health."""
    service = build_service(settings, with_reader=False)
    try:
        batch, _ = decode_bulk(data, "kvh-a", DecoderConfig(rate_hz=RATE))
        step = int(RATE)
        for lo in range(0, len(batch), step):
            service.ingest.feed(batch[lo : lo + step])
        service.ingest.flush()
        health = service.ingest.detector_health()
        table, _ = service.store.positions(session_id=service.session_id)
        spans = list(zip(table.columns.get("start_s", []), table.columns.get("end_s", []),
                         strict=True))  # fmt: skip
    finally:
        service.close(wait_s=0)
    return spans, health


def _inside_holds(spans, session, offset_frames: int) -> bool:
    """Every window lies inside one true hold (times are from the first frame fed)."""
    for start, end in spans:
        a = int(round(start * RATE)) + offset_frames
        b = int(round(end * RATE)) + offset_frames
        if not session.static[a : b + 1].all():
            return False
    return True


def test_restart_while_moving_reuses_the_stored_floor(tmp_path: Path, session) -> None:
    data, _ = session_to_kvh(session, rng=8)
    # First start: no flag at all; the floor is learned from the quietest stretches.
    spans, health = _run(_settings(tmp_path), data)
    assert len(spans) == session.n_holds
    assert _inside_holds(spans, session, 0)
    assert "quiet" in health["threshold_source"] or "stretch" in health["threshold_source"]
    # Restart in the middle of a slew: the stored floor is used, motion is not let through.
    cut = int(session.hold_last[2]) + int(1.5 * RATE)  # 1.5 s into the third slew (of 20 s)
    moving = data[cut * FRAME :]
    spans, health = _run(_settings(tmp_path), moving)
    assert "stored for this device" in health["threshold_source"]
    assert _inside_holds(spans, session, cut)
    assert len(spans) == session.n_holds - 3


def test_the_old_way_learned_motion_as_still(tmp_path: Path, session) -> None:
    """What a restart at sea did before: thresholds from an 'initial still period' that moves
    let motion pass the variance test; the rest check in physics now refuses it."""
    data, _ = session_to_kvh(session, rng=8)
    cut = int(session.hold_last[2]) + int(1.5 * RATE)
    spans, health = _run(_settings(tmp_path, init_still_s=10.0), data[cut * FRAME :])
    refused = sum(health["rejected"].get(r, 0) for r in ("turning", "swinging", "accelerating"))
    assert refused > 0  # motion passed the variance test ...
    assert _inside_holds(spans, session, cut)  # ... and none of it was stored


def test_refined_only_from_windows_that_passed(tmp_path: Path, session) -> None:
    from service.store.repository import Store

    data, _ = session_to_kvh(session, rng=8)
    _run(_settings(tmp_path), data)
    store = Store(f"sqlite:///{tmp_path / 'recal.db'}")
    try:
        rows = store.noise_floor("replay://unit kvh-a 200 Hz")
    finally:
        store.close()
    assert rows is not None and rows["windows"] >= 10  # refined after every 10 windows
    assert "refined from" in rows["source"]
    # the refined floor stays at the still-data level (a hold's moving variance), far below
    # what a slew would give
    sigma = np.array([rows["accel"], rows["gyro"]])
    assert np.all(sigma > 0)


def test_accelerometer_only_windows_do_not_refine_the_floor() -> None:
    """A hand-held window's gyro moving variance is tremor, not the gyro's noise floor."""
    from recal.detect.static_detector import detect_static
    from recal.sim.session import simulate_handheld
    from service.ingest.floor_keeper import FloorKeeper

    s = simulate_handheld(seed=0)  # 2 windows with both triads still, 8 for the accel only
    windows = detect_static(s.time_s, s.gyro_out, s.accel_out).windows
    keeper = FloorKeeper(store=None, device="hand", events=None, window_samples=101)
    keeper.refine(windows)  # no floor yet: only collects (and stores nothing)
    assert keeper._windows == sum(w.gyro_still for w in windows) == 2
    assert [g for _, g in keeper._recent] == [w.gyro_mvar for w in windows if w.gyro_still]
