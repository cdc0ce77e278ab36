"""The fleet prior (issue 28): spreads recovered from a simulated ageing fleet, outlier units
flagged at the stated false-alarm rate, the versioned file, and held coefficients aged by it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from recal import (
    CalibrationOptions,
    CoefficientSet,
    FleetPrior,
    VersionTable,
    calibrate,
    fleet_prior,
    outlier_units,
    read_fleet_prior,
    simulate_fleet,
    simulate_positions,
)
from recal.errors import RecalInputError
from recal.fleet.estimate import random_walk_rate
from recal.fleet.history import is_relative

TRUTH = CoefficientSet.seed_truth()


@pytest.fixture(scope="module")
def design() -> tuple[list[str], np.ndarray, np.ndarray]:
    """Names, values and the 1-sigma a real calibration of the 24-position design reports: the
    sigma model of the simulated fleet's versions."""
    result = calibrate(simulate_positions(TRUTH, seed=1))
    return result.layout.names, result.theta, np.sqrt(np.diag(result.covariance))


def _rates(names: list[str], theta: np.ndarray, sigma: np.ndarray, seed: int) -> np.ndarray:
    """True rates per coefficient: 0.3 to 3 times the version's own 1-sigma per sqrt-month
    (relative for scale factors), so some coefficients age below their measurement error."""
    rel = np.array([is_relative(n) for n in names])
    own = np.where(rel, sigma / np.abs(theta), sigma)
    return own * np.random.default_rng(seed).uniform(0.3, 3.0, len(names))


@pytest.mark.parametrize("seed", [1234, 98765])
def test_the_spreads_are_recovered_within_20_percent(design, seed: int) -> None:
    names, theta, sigma = design
    rates = _rates(names, theta, sigma, seed)
    fleet = simulate_fleet(names, theta, rates, sigma, units=200, years=5.0, outliers=4,
                           seed=seed)  # fmt: skip
    prior = fleet_prior(fleet.versions, "KVH-1750")
    got, rel = prior.rates(names)
    ratio = got / rates
    assert np.all(np.abs(ratio - 1.0) < 0.2), dict(zip(names, np.round(ratio, 3), strict=True))
    assert np.array_equal(rel, [is_relative(n) for n in names])
    # each figure says what it stands on, and its own 1-sigma is honest (within 4 of it)
    for name, true in zip(names, rates, strict=True):
        c = prior.coefficients[name]
        assert c.units == 200 - len(prior.outliers) and c.changes > 1000
        assert abs(c.rate - true) < 4.0 * c.rate_sigma, name
    # the units ageing five times faster are flagged, and set aside from the figure
    assert set(fleet.outliers) <= {o.unit for o in prior.outliers}


def test_a_naive_spread_counts_the_measurement_errors_as_ageing(design) -> None:
    """The std of the changes over sqrt(dt) overstates a slow coefficient; the estimate that
    subtracts both versions' sigmas does not."""
    names, theta, sigma = design
    rates = _rates(names, theta, sigma, 5) * 0.2  # ageing well below the measurement error
    changes = simulate_fleet(names, theta, rates, sigma, seed=77).versions.changes()
    naive = np.sqrt(np.nanmean(changes.delta**2 / changes.months[:, None], axis=0))
    est = random_walk_rate(changes.delta, changes.months, changes.variance)
    assert np.all(naive > 1.5 * rates)
    assert np.median(np.abs(est.rate / rates - 1.0)) < 0.2


def test_outliers_are_flagged_at_the_stated_false_alarm_rate(design) -> None:
    names, theta, sigma = design
    rates = _rates(names, theta, sigma, 3)
    flagged = units = 0
    for seed in (11, 12, 13):
        fleet = simulate_fleet(names, theta, rates, sigma, units=300, years=3.0, seed=seed)
        prior = fleet_prior(fleet.versions, "KVH-1750", false_alarm=0.05)
        flagged += len(prior.outliers)
        units += 300
    # 900 units ageing alike at 5 %: 45 expected, binomial 1-sigma 6.5
    assert 25 <= flagged <= 65, flagged
    # the test itself, against the true rates
    fleet = simulate_fleet(names, theta, rates, sigma, units=100, outliers=3, outlier_factor=3.0,
                           seed=21)  # fmt: skip
    found = outlier_units(fleet.versions.changes(), rates, 0.001)
    assert {o.unit for o in found} == set(fleet.outliers)
    assert all(o.p_value < 0.001 and o.statistic > o.dof for o in found)


def test_the_file_round_trips_and_a_newer_format_is_refused(design) -> None:
    names, theta, sigma = design
    fleet = simulate_fleet(names, theta, _rates(names, theta, sigma, 1), sigma, units=30,
                           outliers=1, outlier_factor=10.0, seed=2)  # fmt: skip
    prior = fleet_prior(fleet.versions, "KVH-1750", version=7, created_at="2026-11-27T00:00:00Z")
    text = json.dumps(prior.to_json_dict())
    back = read_fleet_prior(text, source="prior.json")
    assert back == prior
    obj = json.loads(text)
    assert obj["format"] == "recal.fleet_prior/1" and obj["version"] == 7
    assert obj["outliers"][0]["unit"] == fleet.outliers[0]
    with pytest.raises(RecalInputError, match=r"prior.json: format recal.fleet_prior/2 is newer "
                       r"than this recal reads \(up to /1\); upgrade recal"):  # fmt: skip
        read_fleet_prior({**obj, "format": "recal.fleet_prior/2"}, source="prior.json")
    with pytest.raises(RecalInputError, match="is not a fleet prior"):
        read_fleet_prior({**obj, "format": "recal.coefficients/1"})
    with pytest.raises(RecalInputError, match="malformed fleet prior"):
        read_fleet_prior({**obj, "coefficients": {"gyro.bias.bx": {"rate": -1.0}}})
    with pytest.raises(RecalInputError, match="not JSON"):
        read_fleet_prior("{")


def test_the_table_reads_the_shore_documents(design) -> None:
    from datetime import UTC, datetime

    names, theta, sigma = design
    doc = calibrate(simulate_positions(TRUTH, seed=1)).to_json_dict()
    rows = [(datetime(2026, 1, 1, tzinfo=UTC), doc), (datetime(2026, 7, 2, tzinfo=UTC), doc)]
    table = VersionTable.from_documents(names, {"SN1": rows, "SN2": rows[:1]})
    changes = table.changes()
    assert len(changes) == 1 and changes.units == ("SN1", "SN2")
    assert changes.months[0] == pytest.approx(182 / (365.25 / 12))
    assert np.allclose(changes.delta, 0.0)
    assert np.allclose(table.values[0], theta)


# ---- a unit's held coefficients, aged by its model's fleet prior ---------------------------------
def _prior_with(values: dict[str, np.ndarray], sigma: dict[str, np.ndarray] | None):
    p = TRUTH.copy()
    p.values = {k: np.array(v, float) for k, v in values.items()}
    p.uncertainty = {} if sigma is None else {k: np.array(v, float) for k, v in sigma.items()}
    p.metadata = {"source": "accepted version"}
    return p


def _flat_prior(rate: dict[str, float], model: str = "KVH-1750") -> FleetPrior:
    from recal.fleet.prior import CoefficientAgeing

    coefficients = {n: CoefficientAgeing(r, r / 20, is_relative(n), 200, 3000)
                    for n, r in rate.items()}  # fmt: skip
    return FleetPrior(model, 3, "2026-11-27T00:00:00Z", coefficients)


@pytest.mark.parametrize("case", ["fast", "slow"])
def test_held_coefficients_cover_the_truth_with_the_fleet_prior(case: str) -> None:
    """Six random positions hold the accel quadratic at the prior (the accepted version). A
    model whose K2 ages fast (3e-6 per sqrt-month, over 16 months): the version's own 1-sigma
    (no ageing) fails to cover the truth, the fleet's figure covers it. One that ages slowly
    (1e-7): the datasheet's typical change (1e-4, a prior file without uncertainty) covers it
    a hundred times over; the fleet's figure covers it and is as tight as the ageing."""
    months, rate = 16.0, {"fast": 3e-6, "slow": 1e-7}[case]
    names = [f"accel.quadratic.K2{a}" for a in "xyz"]
    before = TRUTH.values["accel.quadratic"]
    after = TRUTH.copy()
    step = np.array([1.8, -2.1, 1.5]) * rate * np.sqrt(months)  # a typical draw of the walk
    after.values["accel.quadratic"] = before + step
    measured_sigma = {k: np.full(np.shape(v), 1e-9) for k, v in TRUTH.values.items()}
    given = measured_sigma if case == "fast" else None  # slow: the datasheet stands in
    prior = _prior_with(TRUTH.values, given)
    positions = simulate_positions(after, design="random", n_positions=6, seed=1)
    fleet = _flat_prior(dict.fromkeys(names, rate))

    def held_sigma(opt: CalibrationOptions) -> tuple[np.ndarray, dict]:
        r = calibrate(positions, opt)
        assert list(r.status["accel.quadratic"]) == ["held"] * 3
        sl = r.layout.term_slices()["accel.quadratic"]
        return r.held_uncertainty.sigma[sl], r.to_json_dict()["held_uncertainty"]

    datasheet, _ = held_sigma(CalibrationOptions(prior=prior))
    opt = CalibrationOptions(prior=prior, fleet_prior=fleet, prior_age_months=months)
    aged, doc = held_sigma(opt)
    z_datasheet, z_fleet = np.abs(step) / datasheet, np.abs(step) / aged
    assert np.all(z_fleet < 3.0), z_fleet
    if case == "fast":
        assert np.all(z_datasheet > 3.0), z_datasheet  # too tight: fails to cover the truth
    else:
        assert np.all(datasheet > 100 * np.abs(step))  # too loose
        assert np.all(aged < 2 * rate * np.sqrt(months))
    assert doc["fleet_prior"] == {"model": "KVH-1750", "version": 3,
                                  "created_at": "2026-11-27T00:00:00Z", "months": 16.0}  # fmt: skip
    assert "fleet prior KVH-1750 v3 over 16 months" in doc["prior_sigma_source"]["accel.quadratic"]
