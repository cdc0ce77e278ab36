"""Issue 36, item 3: heading creep and anchor swing keep their windows and never bias the
vertical gyro bias.

A hull-fixed FOG at anchor: 16 holds of 10 min joined by 30-degree turns, waves at a berth, the
heading creeping at 0.5, 2 and 5 deg/h, or swinging +-30 degrees round the anchor with a tide
(12.42 h). Two modes: the hull alone (the vertical rate is no measurement,
:mod:`recal.detect.creep`) and the ship's heading as a compass sends it (1 Hz, 0.1 degree,
noise 0.05 degree: the creep measured and taken out). Windows are kept, and every scale factor
and bias, estimated or held, lies within 3 sigma of the truth. Without the creep handling (the
vertical rate taken as a measurement) the vertical bias is off by many sigma: the test can fail.
"""

from __future__ import annotations

import numpy as np
import pytest

from recal.detect.hull import detect_hull
from recal.detect.rest import RestReference
from recal.detect.windows import windows_to_columns
from recal.model.coefficients import CoefficientSet
from recal.model.positions import Positions
from recal.sim.simulate import NoiseSpec
from recal.sim.vessel import random_hull_unit, simulate_vessel
from recal.sim.vessel_spec import SeaState, VesselSpec
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions

RATE_HZ = 20.0
HOLDS = 16
#: the prior's 1-sigma: loose enough that the windows, not the prior, decide the horizontal
#: gyro biases
SIGMA = {"gyro.scale": 3e-4, "gyro.bias": 0.1, "accel.scale": 3e-4, "accel.bias": 1e-4,
         "gyro.misalignment": 1e-4, "accel.misalignment": 1e-4, "accel.quadratic": 1e-6}  # fmt: skip


def _truth(rng: np.random.Generator) -> CoefficientSet:
    return random_hull_unit(rng)


def _prior(truth: CoefficientSet, rng: np.random.Generator) -> CoefficientSet:
    prior = truth.copy()
    for name, s in SIGMA.items():
        v = np.asarray(truth.values[name], float)
        sigma = s * np.abs(v) if name.endswith(".scale") else np.full(v.shape, s)
        prior.values[name] = v + sigma * rng.normal(size=v.shape)
        prior.uncertainty[name] = sigma
    prior.metadata["source"] = "previous calibration"
    return prior


def _session(seed: int, creep_dph: float, swing_deg: float, with_heading: bool):
    rng = np.random.default_rng(seed)
    lat = float(rng.uniform(-65, 65))
    truth = _truth(rng)
    sea = SeaState.berth(0.3, yaw_swing_deg=0.1, heave_m=0.2, lever_arm_m=(0.0, 2.0, -4.0),
                         creep_dph=creep_dph, anchor_swing_deg=swing_deg)  # fmt: skip
    spec = VesselSpec.berth(holds=HOLDS, sea=sea, heading0_deg=float(rng.uniform(0, 360)))
    rec = simulate_vessel(truth, spec, lat, rate_hz=RATE_HZ, noise=NoiseSpec(0.012, 20.0),
                          seed=seed)  # fmt: skip
    prior = _prior(truth, rng)
    heading = None
    if with_heading:  # a compass: 1 Hz, held between sentences, 0.1 degree, 0.05 degree noise
        s = rec.session
        k = np.minimum(np.floor(s.time_s).astype(int) * int(RATE_HZ), len(s.time_s) - 1)
        noise = rng.normal(0.0, 0.05, len(s.time_s))
        heading = np.round((rec.rpy_deg[k, 2] + noise[k]) % 360.0, 1)
    return rec, truth, prior, lat, heading


def _windows(rec, prior, lat, heading):
    s = rec.session
    ref = RestReference.from_coefficients(prior, lat)
    wins, report = detect_hull(s.time_s, s.gyro_out, s.accel_out, ref, heading_deg=heading)
    return [w.window for w in wins], report


def _z(result, truth: CoefficientSet) -> dict[str, float]:
    out = {}
    sd = np.sqrt(np.diag(result.covariance))
    for name, sl in result.layout.term_slices().items():
        if name.rsplit(".", 1)[-1] not in ("scale", "bias"):
            continue
        for j, i in enumerate(range(sl.start, sl.stop)):
            out[result.layout.names[i]] = (result.theta[i] - truth.values[name][j]) / sd[i]
    return out


CASES = [(0.5, 0.0), (2.0, 0.0), (5.0, 0.0), (0.0, 30.0)]


@pytest.mark.slow
@pytest.mark.parametrize("with_heading", [False, True], ids=["hull", "nmea-heading"])
@pytest.mark.parametrize(("creep_dph", "swing_deg"), CASES)
def test_creep_and_anchor_swing_keep_windows_and_cover_the_truth(creep_dph, swing_deg,
                                                                 with_heading):  # fmt: skip
    seed = 31 + CASES.index((creep_dph, swing_deg)) + 10 * with_heading
    rec, truth, prior, lat, heading = _session(seed, creep_dph, swing_deg, with_heading)
    windows, report = _windows(rec, prior, lat, heading)
    assert report.kept == rec.session.n_holds == HOLDS, report.summary_lines()
    vertical = np.array([w.gyro_vertical for w in windows])
    assert vertical.all() if with_heading else not vertical.any()
    if with_heading:  # the creep measured from the heading: close to the truth's
        creep = np.array([w.creep_dph for w in windows])
        assert np.median(np.abs(creep - creep_dph)) < 1.0 if not swing_deg else True
    pos = Positions.from_columns(windows_to_columns(windows), source="anchor")
    res = calibrate(pos, CalibrationOptions(latitude_deg=lat, prior=prior, method="lm"))
    z = _z(res, truth)
    bad = {k: round(v, 2) for k, v in z.items() if abs(v) > 3.0}
    assert not bad, (bad, res.chi2_red)


@pytest.mark.slow
def test_the_vertical_rate_taken_as_a_measurement_puts_the_creep_in_the_vertical_bias():
    """What the creep handling prevents: the same hold with the vertical rate used as it stands
    (as before issue 36) moves the vertical gyro bias by the creep, many sigma off."""
    rec, truth, prior, lat, _ = _session(35, 5.0, 0.0, False)
    windows, _ = _windows(rec, prior, lat, None)
    cols = windows_to_columns(windows)
    cols.pop("gyro_vertical")
    res = calibrate(Positions.from_columns(cols, source="as before"),
                    CalibrationOptions(latitude_deg=lat, prior=prior, method="lm"))  # fmt: skip
    z = _z(res, truth)
    assert abs(z["gyro.bias.bz"]) > 10.0, z
