"""The ingest's stages one at a time (issue 38): each is driven alone, with real objects (a
simulated KVH session decoded by drivers, a SQLite Store, a Spool), without the others."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from recal.detect.floor import NoiseFloorEstimator
from recal.detect.rest import RestReference
from recal.detect.static_config import DetectorConfig
from recal.detect.static_detector import StaticDetector
from recal.detect.windows import windows_to_columns
from service.events import Events
from service.ingest.floor_keeper import FloorKeeper
from service.ingest.hull import HullStage
from service.ingest.learn import Learner
from service.ingest.rest_check import RestCheck
from service.ingest.still import StillStage
from service.ingest.store import WindowStore
from service.ingest.underway import ShipState
from service.spool import Spool
from service.store.repository import Store

RATE = 100.0
THRESHOLDS = DetectorConfig(accel_threshold=1e-6, gyro_threshold=1e4, sample_rate_hz=RATE)


class Clock:
    """Host time a test sets."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def store(tmp_path: Path):
    s = Store(f"sqlite:///{tmp_path / 'recal.db'}")
    s.create_schema()
    yield s
    s.close()


def seconds(batch, lo: float, hi: float):
    return batch[int(lo * RATE) : int(hi * RATE)]


def detected_windows(frames):
    detector = StaticDetector(THRESHOLDS)
    out = detector.feed(frames.time_s, frames.gyro_dph, frames.accel_g, frames.temperature_c,
                        frames.valid, frames.lost_before)  # fmt: skip
    return out + detector.flush(), detector.report


def test_the_learner_learns_at_learn_s_of_device_time_and_hands_back_the_frames(frames, store):
    clock = Clock()
    learner = Learner(Events(store), NoiseFloorEstimator(None, RATE), learn_s=10.0, clock=clock)
    first, second = seconds(frames, 0, 6), seconds(frames, 6, 12)
    learner.saw_frames(clock(), learning=True)
    assert learner.learn(first, final=False) == (None, [])
    assert learner.health(True, False, None)["state"] == "learning"
    floor, held = learner.learn(second, final=False)
    assert floor is not None and floor.accel > 0 and floor.gyro > 0
    assert [len(b) for b in held] == [len(first), len(second)]
    assert learner.ended_by == "device_time" and learner.learned_s == pytest.approx(12.0, abs=0.02)
    assert learner.health(False, True, None)["state"] == "learned"


def test_the_learner_ends_early_on_a_quiet_stream(frames, store):
    clock = Clock()
    learner = Learner(Events(store), NoiseFloorEstimator(None, RATE), learn_s=120.0,
                      learn_quiet_s=5.0, clock=clock)  # fmt: skip
    learner.saw_frames(clock(), learning=True)
    assert learner.learn(seconds(frames, 0, 12), final=False) == (None, [])
    clock.t = 6.0  # nothing for 6 s
    assert learner.cut(pending=False) == "quiet"
    floor, held = learner.learn(None, final=False)
    assert floor is not None and "the stream has sent no frame" in floor.source
    assert learner.ended_by == "quiet" and len(held) == 1
    kinds = [e["kind"] for e in store.events()]
    assert "noise_floor" in kinds


def test_the_still_stage_finds_windows_and_keeps_the_slews_between_them(frames, store):
    stage = StillStage(THRESHOLDS, Learner(Events(store)))
    assert not stage.needs_floor
    windows = []
    for lo in range(0, len(frames), int(RATE)):
        windows += stage.run([frames[lo : lo + int(RATE)]], flush=False)
    windows += stage.run([], flush=True)
    expected, _ = detected_windows(frames)
    assert [w.start_s for w in windows] == [w.start_s for w in expected]
    slews, period = stage.slews(windows)
    assert period == pytest.approx(1 / RATE)
    assert len(slews) == len(windows) - 1 and slews[0][:2] == (0, 1)


def test_the_still_stage_learns_its_floor_stores_it_and_reuses_it(frames, store):
    events = Events(store)
    keeper = FloorKeeper(store, "unit", events, window_samples=101)
    config = DetectorConfig(window_s=1.0, sample_rate_hz=RATE)
    stage = StillStage(config, Learner(events, learn_s=30.0), keeper)
    assert stage.needs_floor
    stage.run([seconds(frames, 0, 40)], flush=False)
    assert not stage.needs_floor and keeper.floor is not None
    again = StillStage(config, Learner(events), FloorKeeper(store, "unit", events, 101))
    assert not again.needs_floor  # the stored floor, not learning again
    assert again.config.noise_floor.accel == pytest.approx(keeper.floor.accel)


def test_the_rest_check_refuses_what_is_not_at_rest_and_follows_the_latitude(frames, store):
    windows, report = detected_windows(frames)
    events = Events(store)
    nominal = RestReference.nominal(45.0, 0.0)
    check = RestCheck(nominal, events, rest_at=lambda lat: RestReference.nominal(lat, 0.0))
    assert check.check(windows, report) == windows  # a unit at rest at 45 deg
    assert check.seen == len(windows) and check.refused == 0
    check.nav_latitude(45.01)  # within REST_LATITUDE_STEP_DEG of nothing yet: built once
    assert check.follow_latitude() is not None
    check.nav_latitude(45.02)
    assert check.follow_latitude() is None  # moved less than the step
    check.nav_latitude(-60.0)
    ref = check.follow_latitude()
    assert ref is not None and check.reference is ref
    spun = [w.__class__(**{**w.__dict__, "gyro": np.asarray(w.gyro) + 500.0}) for w in windows]
    assert check.check(spun, report) == []  # Earth's rate is not 500 deg/h
    assert check.refused == len(windows)
    assert RestCheck(None, events).check(windows, report) == windows  # no reference: no check


def test_the_hull_stage_needs_a_rest_reference() -> None:
    from recal.detect.hull_config import HullConfig
    from recal.errors import RecalInputError

    with pytest.raises(RecalInputError, match="deg/h and g"):
        HullStage(None, HullConfig(), RATE)
    stage = HullStage(RestReference.nominal(45.0, 0.0), HullConfig(), RATE)
    assert stage.run([], flush=True) == []
    assert stage.health(None, ())["motion"] == "hull"


def test_the_ship_state_keeps_every_window_without_nav(frames):
    windows, report = detected_windows(frames)
    assert ShipState(None).keep(windows, report) == (windows, None)
    assert ShipState(None).reasons == ()


def test_the_store_spools_then_stores_in_order_and_waits_while_the_database_refuses(
    frames, store, tmp_path
):
    windows, _ = detected_windows(frames)
    session = store.add_session("unit")
    stored: list[int] = []
    clock = Clock()
    spool = Spool(tmp_path / "spool")
    ws = WindowStore(store, session, Events(store), spool, stored.extend, clock)
    ws.put(windows_to_columns(windows[:3]), [], None)
    assert ws.detected == 3 and ws.spooled == 3  # durable before the database has it
    ids = ws.drain_if_due()
    assert len(ids) == 3 and stored == ids and ws.windows == 3 and ws.spooled == 0
    assert not list((tmp_path / "spool").glob("*.json*"))  # deleted once committed
    path = tmp_path / "recal.db"
    refusing = Store(f"sqlite:///file:{path}?mode=ro&uri=true")
    ws2 = WindowStore(refusing, session, Events(store), spool, clock=clock)
    ws2.put(windows_to_columns(windows[3:5]), [], None)
    assert ws2.drain_if_due() == [] and ws2.store_error is not None and ws2.spooled == 2
    assert ws2.drain_if_due() == []  # the back-off has not passed: not even tried
    refusing.close()
