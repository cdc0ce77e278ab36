"""Fixtures shared by the solver tests: a short KVH-like session with slews and its LM fit."""

from __future__ import annotations

import pytest

from recal.sim.session import session_positions, session_slews, simulate_session
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions
from service.capture_sim import kvh_like_truth

#: The slew session's latitude, deg (tests read it from the ``slew_latitude`` fixture).
SLEW_LATITUDE = 40.0


@pytest.fixture(scope="session")
def slew_latitude() -> float:
    return SLEW_LATITUDE


@pytest.fixture(scope="session")
def slew_session():
    """(positions, slews) of 12 random holds joined by slews (KVH-like unit, 100 Hz, 8 s holds,
    3 s slews, seed 7)."""
    s = simulate_session(kvh_like_truth(7), "random", n_positions=12, latitude_deg=SLEW_LATITUDE,
                         seed=7, rate_hz=100.0, window_s=8.0, slew_s=3.0)  # fmt: skip
    return session_positions(s), session_slews(s)


@pytest.fixture(scope="session")
def slew_lm(slew_session):
    """LM on :func:`slew_session` with its slews."""
    pos, slews = slew_session
    return calibrate(pos, CalibrationOptions(latitude_deg=SLEW_LATITUDE, slews=slews))
