"""The incremental hull detector (recal.detect.hull.HullDetector, the daemon's form) keeps what
the whole-recording detector keeps, also when a hold is about as long as ``max_window_s``: a
window still waiting when the buffer is cut is kept whole, with the context its first blocks
are judged with."""

from __future__ import annotations

import numpy as np
import pytest

from recal.detect.hull import HullDetector, detect_hull
from recal.detect.hull_config import HullConfig
from recal.detect.rest import RestReference
from recal.model.coefficients import CoefficientSet
from recal.sim.simulate import NoiseSpec
from recal.sim.vessel import simulate_vessel
from recal.sim.vessel_spec import SeaState, VesselSpec

LAT = 45.0
RATE = 20.0


def _windows(holds: int, hold_s: float, cfg: HullConfig, chunk: int):
    truth = CoefficientSet({  # a KVH-like unit: deg/h and g outputs
        "gyro.scale": np.array([1.0002, 0.9998, 1.0001]), "gyro.bias": np.array([0.2, -0.1, 0.3]),
        "gyro.misalignment": np.full(6, 1e-4), "accel.scale": np.array([1.0001, 0.9999, 1.0]),
        "accel.bias": np.array([3e-4, -2e-4, 5e-4]), "accel.misalignment": np.full(6, -1e-4),
        "accel.quadratic": np.zeros(3)})  # fmt: skip
    rec = simulate_vessel(truth, VesselSpec.berth(holds=holds, hold_s=hold_s,
                          sea=SeaState.berth(0.5)), LAT, rate_hz=RATE,
                          noise=NoiseSpec(arw_deg_rt_h=0.012, vrw_ug_rt_hz=20.0), seed=3)  # fmt: skip
    s = rec.session
    ref = RestReference.nominal(LAT)
    bulk, _ = detect_hull(s.time_s, s.gyro_out, s.accel_out, ref, cfg)
    det = HullDetector(ref, cfg, rate_hz=RATE)
    inc = []
    for i in range(0, len(s), chunk):
        inc += det.feed(s.time_s[i : i + chunk], s.gyro_out[i : i + chunk],
                        s.accel_out[i : i + chunk])  # fmt: skip
    inc += det.flush()
    span = [(hw.window.start_index, hw.window.end_index) for hw in bulk]
    return s, span, [(hw.window.start_index, hw.window.end_index) for hw in inc], det.report


@pytest.mark.parametrize("chunk", [409, 4096])
def test_holds_as_long_as_the_longest_window_lose_nothing(chunk: int) -> None:
    # 300 s holds, windows of at most 300 s: the buffer was cut into the second hold's window
    s, bulk, inc, report = _windows(4, 300.0, HullConfig(max_window_s=300.0), chunk)
    assert inc == bulk and len(bulk) == s.n_holds
    assert report.rejected.get("too_short", 0) == 0


def test_long_holds_split_into_windows_keep_every_hold() -> None:
    s, bulk, inc, _ = _windows(3, 1000.0, HullConfig(max_window_s=600.0), 409)
    kept = sum(b - a for a, b in inc)
    # every hold gives windows; where a long hold is split, up to half a turn window and the trim
    # are lost at the split (the next piece's first blocks need the average before them)
    assert {int(np.searchsorted(s.hold_first, a, side="right")) for a, _ in inc} == {1, 2, 3}
    assert kept >= sum(b - a for a, b in bulk) - (len(inc) - s.n_holds) * 63 * RATE
    for a, b in inc:
        assert ((s.hold_first <= a) & (b <= s.hold_last)).sum() == 1
