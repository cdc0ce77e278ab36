"""Closed turns only where Earth rate checks them or the user declares them (issue 26).

A hull-fixed FOG that turns only in heading cannot show its vertical gyro scale from the still
windows or from the slews' gravity directions; a slew that closes whole turns about the vertical
would pin it. Such a slew is taken as closed only when the two windows' headings from the
horizontal Earth rate agree (the closure's 1-sigma is then theirs), or when the user declares the
closure where the heading cannot be seen. A 345-degree turn is not closed (taking it as 360 would
push 15 degrees, 4 %, into the scale), a 360-degree one is, and near the pole, where the
horizontal Earth rate vanishes, nothing is closed unless declared.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import recal.detect.closed_turns as closed_turns_mod
from recal.detect.closed_turns import CHECKED, DECLARED
from recal.model.coefficients import CoefficientSet
from recal.sim.session import session_positions, session_slews
from recal.sim.simulate import NoiseSpec
from recal.sim.vessel import simulate_vessel
from recal.sim.vessel_spec import SeaState, Segment, VesselSpec
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions

LAT = 45.0
KVH_NOISE = NoiseSpec(arw_deg_rt_h=0.012, vrw_ug_rt_hz=20.0)
MIS = ("Exz", "Exy", "Eyz", "Eyx", "Ezy", "Ezx")
#: the prior: a datasheet-level 1-sigma, and the prior's error against the truth (within it)
PRIOR_SIGMA = {"gyro.scale": 1e-3, "gyro.bias": 0.2, "gyro.misalignment": 5e-4,
               "accel.scale": 1e-3, "accel.bias": 1e-3, "accel.misalignment": 5e-4,
               "accel.quadratic": 1e-5}  # fmt: skip
PRIOR_OFF = {"gyro.scale": [7e-4, -5e-4, 6e-4], "gyro.bias": [0.1, -0.1, 0.15],
             "accel.scale": [-4e-4, 5e-4, 3e-4], "accel.bias": [3e-4, -2e-4, 4e-4]}  # fmt: skip


def _truth() -> CoefficientSet:
    """A KVH-like unit (deg/h and g outputs), as tests/recal/test_hull.py."""
    rng = np.random.default_rng(3)
    return CoefficientSet({
        "gyro.scale": 1.0 + rng.uniform(-5e-4, 5e-4, 3), "gyro.bias": rng.uniform(-1, 1, 3),
        "gyro.misalignment": rng.uniform(-3e-4, 3e-4, 6),
        "accel.scale": 1.0 + rng.uniform(-5e-4, 5e-4, 3),
        "accel.bias": rng.uniform(-1e-3, 1e-3, 3),
        "accel.misalignment": rng.uniform(-3e-4, 3e-4, 6), "accel.quadratic": np.zeros(3),
    })  # fmt: skip


def _prior(truth: CoefficientSet) -> CoefficientSet:
    values = {}
    for name, v in truth.values.items():
        v = np.array(v, float)
        off = np.asarray(PRIOR_OFF.get(name, np.zeros_like(v)), float)
        values[name] = v * (1 + off) if name.endswith("scale") else v + off
    prior = CoefficientSet(values)
    prior.uncertainty = {n: np.full(np.shape(v), PRIOR_SIGMA[n]) for n, v in values.items()}
    return prior


def _session(turn_deg: float, latitude_deg: float = LAT):
    """Six 10-minute holds of a level hull in a calm sea, joined by 2-minute heading turns of
    90, 90, 90, ``turn_deg`` and 45 degrees; the true holds' means and the slews between them."""
    segs = [Segment("hold", 600.0)]
    for d in (90.0, 90.0, 90.0, turn_deg, 45.0):
        segs += [Segment("turn", 120.0, heading_change_deg=d), Segment("hold", 600.0)]
    truth = _truth()
    rec = simulate_vessel(truth, VesselSpec(tuple(segs), sea=SeaState.calm()), latitude_deg,
                          rate_hz=50.0, noise=KVH_NOISE, seed=5)  # fmt: skip
    return truth, session_positions(rec.session), session_slews(rec.session)


@pytest.fixture(scope="module")
def turn_345():
    return _session(345.0)


@pytest.fixture(scope="module")
def turn_360():
    return _session(360.0)


def _fit(session, latitude_deg: float = LAT, declared: float = 0.0):
    truth, positions, slews = session
    opt = CalibrationOptions(latitude_deg=latitude_deg, slews=slews, prior=_prior(truth),
                             turn_closure_sigma_deg=declared)  # fmt: skip
    return calibrate(positions, opt)


def _scale_z(result, truth) -> tuple[np.ndarray, np.ndarray]:
    """(scale error, 1-sigma), relative, per gyro axis."""
    k = result.coefficients.values["gyro.scale"]
    ref = truth.values["gyro.scale"]
    return k / ref - 1.0, result.uncertainty["gyro.scale"] / ref


def test_a_345_degree_turn_is_not_taken_as_closed(turn_345, monkeypatch) -> None:
    truth = turn_345[0]
    for declared in (0.0, 0.1):  # Earth rate overrules a declaration it contradicts
        r = _fit(turn_345, declared=declared)
        (c,) = r.problem.turn_candidates
        assert c.slew == 3 and c.turns == -1 and not c.closed, c
        # the body turned 345 deg clockwise seen from above: +15 deg about up beyond -1 turn
        assert abs(c.heading_change_deg - 15.0) < 3 * c.sigma_deg, c
        assert c.sigma_deg < 0.5 and "not a closed turn" in c.reason
        assert r.problem.closed_turns is None
        err, sd = _scale_z(r, truth)
        assert np.all(np.abs(err) <= sd), (err * 1e6, sd * 1e6)  # the prior's, within its sigma
        assert any("not taken as a closed turn" in n for n in r.notes)
        doc = r.to_json_dict()
        assert doc["turn_closure"]["candidates"][0]["closed"] is False
        assert "closure" not in doc["residuals"]
    # the rule this replaces (any slew within 30 deg of a whole turn closed to 0.1 deg): the
    # 15 degrees go into the vertical gyro scale, tens of sigma off the truth
    monkeypatch.setattr(closed_turns_mod, "_heading_unseen", lambda check: "assumed")
    r = _fit(turn_345, declared=0.1)
    assert r.problem.closed_turns is not None
    err, sd = _scale_z(r, truth)
    assert abs(err[2]) > 10 * sd[2] and abs(abs(err[2]) - 15 / 360) < 0.005, (err, sd)


def test_a_360_degree_turn_is_closed_after_the_earth_rate_check(turn_360) -> None:
    truth = turn_360[0]
    for declared in (0.0, 0.1):  # where Earth rate can check, the check decides
        r = _fit(turn_360, declared=declared)
        (c,) = r.problem.turn_candidates
        assert c.closed and c.how == CHECKED and c.turns == -1, c
        assert abs(c.heading_change_deg) < 3 * c.sigma_deg
        # the closure's 1-sigma is the heading check's: the windows' horizontal rate noise over
        # the horizontal Earth rate, about 0.2 deg for 10-minute holds of a KVH-class gyro
        assert 0.1 < c.sigma_deg < 0.4, c
        assert math.isfinite(c.heading_first_deg) and math.isfinite(c.heading_second_deg)
        turns = r.problem.closed_turns
        assert turns is not None and turns.checked.tolist() == [True]
        assert np.degrees(turns.sigma_rad[0]) == pytest.approx(c.sigma_deg)
        err, sd = _scale_z(r, truth)
        assert r.status["gyro.scale"][2] == "estimated"
        assert abs(err[2]) < 3 * sd[2] and sd[2] < PRIOR_SIGMA["gyro.scale"], (err, sd)
        doc = r.to_json_dict()
        assert doc["residuals"]["closure"]["how"] == [CHECKED]
        cand = doc["turn_closure"]["candidates"][0]
        assert cand["how"] == CHECKED and cand["heading_first_deg"] is not None
        note = next(n for n in r.notes if n.startswith("slew 3 "))
        assert "checked by Earth rate: headings" in note


def test_near_the_pole_nothing_is_closed_unless_declared() -> None:
    """At 89 deg the horizontal Earth rate is 0.26 deg/h, about the gyro bias prior: no heading."""
    session = _session(360.0, latitude_deg=89.0)
    r = _fit(session, latitude_deg=89.0)
    (c,) = r.problem.turn_candidates
    assert not c.closed and "not observable" in c.reason and "--turn-closure" in c.reason, c
    assert r.problem.closed_turns is None
    r = _fit(session, latitude_deg=89.0, declared=0.1)
    (c,) = r.problem.turn_candidates
    assert c.closed and c.how == DECLARED and c.sigma_deg == pytest.approx(0.1), c
    assert r.to_json_dict()["turn_closure"]["declared_sigma_deg"] == pytest.approx(0.1)
    err, sd = _scale_z(r, session[0])
    assert abs(err[2]) < 3 * sd[2], (err, sd)
