"""Static alignment: attitude to within the sensor noise; non-static input refused."""

from __future__ import annotations

import math

import numpy as np
import pytest

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.nav.alignment import align_static, parse_attitude
from recal.nav.navigation import correct_outputs, decimate
from recal.nav.trajectory import Leg, VoyageSpec, simulate_voyage
from recal.sim.simulate import NoiseSpec

LAT = 45.0


def _corrected(spec, rate=100.0, noise=None, seed=0):
    truth = CoefficientSet.seed_truth()
    v = simulate_voyage(truth, spec, LAT, 0.0, 0.0, rate, noise or NoiseSpec(), seed=seed)
    s = v.session
    d = decimate(s.time_s, s.gyro_out, s.accel_out, None, rate, 10.0)
    w, f = correct_outputs([truth], d)
    return v, w[0], f[0]


@pytest.mark.parametrize("rpy", [(1.5, -2.0, 120.0), (-30.0, 10.0, -75.0)])
def test_alignment_recovers_attitude_within_the_noise(rpy):
    """Seed 000 Table 4 gyro noise (ARW 0.0005 deg/rt h), 20 ug/rt Hz accel noise, 300 s."""
    v, w, f = _corrected(VoyageSpec.static(300.0, rpy), seed=3)
    al = align_static(f, w, LAT)
    err = np.degrees(al.rpy_rad[0]) - np.array(rpy)
    err[2] = (err[2] + 180.0) % 360.0 - 180.0
    # 1-sigma of the mean east rate over the horizontal Earth rate, rad
    heading_sigma = 0.0005 / math.sqrt(300 / 3600) / (15.04107 * math.cos(math.radians(LAT)))
    tilt_sigma = 20e-6 / math.sqrt(300.0)  # rad: accel noise of the mean, in g
    assert abs(math.radians(err[2])) < 4 * heading_sigma
    assert np.abs(np.radians(err[:2])).max() < 4 * tilt_sigma
    # the reported sigmas (from the samples' scatter) agree with the physics
    assert al.heading_sigma_rad[0] == pytest.approx(heading_sigma, rel=0.3)


def test_moving_start_is_refused():
    spec = VoyageSpec(moor_s=10.0, legs=(Leg(300.0, 5.0, 90.0),), heading0_deg=0.0)
    _, w, f = _corrected(spec, rate=20.0)
    with pytest.raises(RecalInputError, match="not static"):
        align_static(f[:3000], w[:3000], LAT)


def test_polar_latitude_needs_an_attitude():
    with pytest.raises(RecalInputError, match="--attitude"):
        align_static(np.zeros((100, 3)), np.zeros((100, 3)), 88.0)


@pytest.mark.parametrize("text", ["1,2", "a,b,c", "1,2,nan", "0,95,0", "1,2,3,4"])
def test_bad_attitude_text(text):
    with pytest.raises(RecalInputError, match="--attitude"):
        parse_attitude(text)


def test_attitude_text():
    assert parse_attitude(" 1.5, -2,350 ") == (1.5, -2.0, 350.0)
