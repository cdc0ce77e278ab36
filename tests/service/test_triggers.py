"""The scheduler's triggers in the daemon (issue 20): a replayed capture whose truth changes
half-way starts a job because of drift, and its record says so; a steady capture starts none
after the first calibration unless the information gain says so."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import pytest

from drivers import DecoderConfig, decode_bulk
from recal.sim.session import simulate_session
from service.capture_sim import kvh_like_truth, session_to_kvh
from service.config import DetectorSettings, DeviceSettings, SchedulerSettings, Settings
from service.daemon import build_service

RATE = 100.0
LAT = 45.0
GYRO_X_STEP = 2000e-6  # a shock: +2000 ppm on gyro x scale
ACCEL_X_STEP = 100e-6  # and +100 micro-g on accel x bias


def _capture(truth, seed: int) -> bytes:
    session = simulate_session(truth, "24", latitude_deg=LAT, seed=seed, rate_hz=RATE,
                               window_s=12.0, slew_s=3.0, first_hold_s=12.0)  # fmt: skip
    return session_to_kvh(session, rng=seed)[0]


def _stepped(truth):
    out = truth.copy()
    out.values["gyro.scale"][0] *= 1.0 + GYRO_X_STEP
    out.values["accel.bias"][0] += ACCEL_X_STEP
    return out


def _settings(tmp_path: Path, **scheduler) -> Settings:
    return Settings(
        database_url=f"sqlite:///{tmp_path / 'r.db'}",
        publish_path=str(tmp_path / "c.json"),
        device=DeviceSettings(url="replay://unit", rate_hz=RATE),
        site={"latitude_deg": LAT},
        detector=DetectorSettings(accel_threshold=1e-6, gyro_threshold=1e4),
        scheduler=SchedulerSettings(**({"min_positions": 24, "method": "lm"} | scheduler)),
    )


def _feed(service, captures: list[bytes]) -> None:
    """The captures one after the other, as one stream: device time continues, and the frames
    between two captures count as lost (the unit was not seen turning from one to the next).
    Every 15 s of frames (about one window) the scheduler settles, as at sea, where windows
    come minutes apart: the triggers look at each new window."""
    offset = 0.0
    for data in captures:
        batch, _ = decode_bulk(data, "kvh-a", DecoderConfig(rate_hz=RATE))
        lost = batch.lost_before.copy()
        lost[0] = 1000 if offset else lost[0]
        batch = replace(batch, time_s=batch.time_s + offset, lost_before=lost)
        for lo in range(0, len(batch), int(RATE)):
            service.ingest.feed(batch[lo : lo + int(RATE)])
            if (lo // int(RATE)) % 15 == 14:
                _settle(service)
        offset = float(batch.time_s[-1]) + 10.0
    service.ingest.flush()


def _settle(service, timeout_s: float = 600.0) -> None:
    """Until the triggers have looked at every window and no job runs."""
    deadline = time.monotonic() + timeout_s
    while not service.scheduler.settled():
        service.scheduler.wait(timeout=1.0)
        assert time.monotonic() < deadline, "the scheduler never settled"


def _drift_events(store) -> list[dict]:
    return [e for e in reversed(store.events(limit=1000)) if e["kind"] == "drift"]


@pytest.fixture(scope="module")
def truth():
    return kvh_like_truth(4)


@pytest.mark.slow
def test_a_change_half_way_starts_a_job_because_of_drift(tmp_path, truth) -> None:
    service = build_service(_settings(tmp_path, min_information_gain=0.6), with_reader=False)
    try:
        _feed(service, [_capture(truth, 4), _capture(_stepped(truth), 5)])
        _settle(service)
        history = list(reversed(service.store.history()))
        assert history[0].trigger == "count" and history[0].accepted
        assert len(service.store.positions()[1]) == 48
        drift_jobs = [r for r in history if r.trigger == "drift"]
        assert drift_jobs, [(r.trigger, r.document.get("trigger_detail")) for r in history]
        why = drift_jobs[0].document["trigger_detail"]
        assert why["trigger"] == "drift" and why["statistic"] > why["threshold"] > 0
        assert why["alarm_id"] > 24, "an alarm before the change"
        assert "gyro x scale" in why["suspect"] or "accel x bias" in why["suspect"]
        # the job used only windows since the change: the unit as it is now
        assert min(drift_jobs[0].positions_used) > 24
        # every window before the change was steady, the alarm came within 15 windows of it
        # the windows were looked at one by one: steady until the change, an alarm within 15
        # windows of it, and the suspect named
        events = _drift_events(service.store)
        alarms = [e["data"]["last_id"] for e in events if e["data"]["alarm_window"] is not None]
        assert len(events) >= 5 and alarms and 24 < alarms[0] <= 24 + 15
        assert why["alarm_id"] <= 24 + 15
        # the versions after it use only windows since the change and see the step within
        # 4 sigma; the accelerometer's too
        current = service.store.current()
        assert current.accepted and min(current.positions_used) > 24
        assert current.document["trigger_detail"]["since_id"] >= 24
        doc, old = current.document, history[0].document
        got, was = doc["coefficients"]["gyro"]["scale"][0], old["coefficients"]["gyro"]["scale"][0]
        sigma = doc["uncertainty"]["gyro"]["scale"][0]
        assert sigma < 1e-3 and abs((got - was) - GYRO_X_STEP * was) < 4 * sigma
        got, was = doc["coefficients"]["accel"]["bias"][0], old["coefficients"]["accel"]["bias"][0]
        sigma = doc["uncertainty"]["accel"]["bias"][0]
        assert abs((got - was) - ACCEL_X_STEP) < 4 * sigma
        # /health says why the last job ran, as its record does
        health = service.health()
        assert health["scheduler"]["last_reason"] == history[-1].document["trigger_detail"]
        assert health["scheduler"]["last_evaluation"]["drift"]["statistic"] >= 0
    finally:
        service.close(wait_s=0)


@pytest.mark.slow
def test_a_steady_capture_starts_no_job_after_the_first_unless_information_says_so(
    tmp_path, truth
) -> None:
    captures = [_capture(truth, 4), _capture(truth, 6)]
    (tmp_path / "a").mkdir()
    service = build_service(_settings(tmp_path / "a", min_information_gain=0.9),
                            with_reader=False)  # fmt: skip
    try:
        _feed(service, captures)
        _settle(service)
        history = service.store.history()
        assert [r.trigger for r in history] == ["count"], "a job after the first, on no change"
        # the windows were looked at as they came (how many at a time depends on how long the
        # first job ran while the feed went on), every one of the 24 new ones, none raised an alarm
        events = _drift_events(service.store)
        assert len(events) >= 5 and events[-1]["data"]["windows"] == 24, events
        assert all(e["data"]["alarm_window"] is None for e in events)
    finally:
        service.close(wait_s=0)
    # the default gain: the same design once more sharpens the coefficients by about 1 -
    # sqrt(1/2) = 0.29 >= 0.25, so one job runs, and says why
    (tmp_path / "b").mkdir()
    service = build_service(_settings(tmp_path / "b"), with_reader=False)
    try:
        _feed(service, captures)
        _settle(service)
        history = list(reversed(service.store.history()))
        assert history[0].trigger == "count"
        later = [r.trigger for r in history[1:]]
        assert later and set(later) == {"information"}, later
        why = history[1].document["trigger_detail"]
        assert why["gain"] >= why["threshold"] == 0.25 and why["coefficient"]
    finally:
        service.close(wait_s=0)
