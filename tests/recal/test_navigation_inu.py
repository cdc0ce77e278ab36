"""The mechanization agrees with ``inu.mech``, an independent pure-Python reference."""

from __future__ import annotations

import math

import numpy as np
import pytest

from recal.model.coefficients import CoefficientSet
from recal.model.reference import G0_M_S2
from recal.nav.navigation import DEG_H_TO_RAD_S, attitude_matrix, navigate
from recal.nav.trajectory import Leg, VoyageSpec, simulate_voyage
from recal.sim.simulate import NoiseSpec

inu = pytest.importorskip("inu")


def test_mechanization_agrees_with_inu_on_a_manoeuvring_trajectory():
    """Two minutes at 100 Hz: acceleration to 6 m/s, a 70 deg turn, a slow-down and a second
    turn, with roll and pitch from waves. inu integrates by forward Euler at every sample."""
    spec = VoyageSpec(
        moor_s=5.0, legs=(Leg(60.0, 6.0, 80.0), Leg(60.0, 3.0, 150.0)), heading0_deg=20.0
    )
    v = simulate_voyage(CoefficientSet.seed_truth(), spec, 45.0, 10.0, 0.0, 100.0, NoiseSpec(0, 0))
    w = v.session.gyro_in_dph * DEG_H_TO_RAD_S
    f = v.session.accel_in_g * G0_M_S2
    rpy0 = np.radians(v.rpy_deg[0])
    llh, vne, rpy = inu.mech(
        f, w, np.array([math.radians(45.0), math.radians(10.0), 0.0]), np.zeros(3), rpy0,
        0.01, hae_t=np.zeros(len(f)), show_progress=False,
    )  # fmt: skip
    nav = navigate(w, f, 0.01, 45.0, 10.0, 0.0, attitude_matrix(*rpy0), step_s=0.1)
    idx = np.minimum(np.round(nav.time_s * 100).astype(int), len(f) - 1)
    north, east = nav.north_east_error_m(llh[idx, 0], llh[idx, 1])
    assert np.hypot(north, east).max() < 0.2  # m, over 125 s and 0.6 km
    assert np.abs(nav.v_ned[0, :, :2] - vne[idx, :2]).max() < 0.01  # m/s
    d = np.degrees(nav.rpy_rad[0]) - np.degrees(rpy[idx])
    d[:, 2] = (d[:, 2] + 180.0) % 360.0 - 180.0
    assert np.abs(d).max() < 0.02  # deg: inu's Euler step lags half a sample in the turns
