"""Effect or noise (recal.diagnose.hypotheses, recal.diagnose.noise_test): the floor on tau, the
hypotheses' figures in the JSON, an excess called model error, and the test of an effect against
a noise null past the bootstrap's size."""

from __future__ import annotations

import json

import numpy as np
import pytest

import recal.diagnose.candidates as candidates_module
from recal.diagnose.effects import diagnose
from recal.model.coefficients import read_coefficients
from recal.model.positions import Positions
from recal.solve.options import CalibrationOptions
from recal.solve.wander_estimate import correlation_times, tau_floor_s


def test_the_floor_on_tau_is_the_median_spacing_of_one_session():
    t = np.array([0.0, 540.0, 1080.0, 1620.0, 5000.0, 5540.0])
    assert tau_floor_s(t) == 540.0
    # a gap across sessions is not a spacing: the two sessions' own gaps only
    sessions = np.array([0, 0, 0, 1, 1, 1])
    t2 = np.array([0.0, 600.0, 1200.0, 0.0, 600.0, 1200.0])
    assert tau_floor_s(t2, sessions) == 600.0
    taus = correlation_times(t, None, float(np.ptp(t)))
    assert taus[:2] == [0.0, 540.0] and all(540.0 < x <= 2 * np.ptp(t) for x in taus[2:])
    assert correlation_times(None, None, 0.0) == [0.0]


def _shared(shared_data, name: str):
    folder = shared_data / "diagnose-hours"
    truth = json.loads((folder / f"{name}.truth.json").read_text())
    pos = Positions.from_csv_text((folder / f"{name}.csv").read_text(), name)
    prior = read_coefficients((folder / f"{name}.prior.json").read_text())
    return pos, CalibrationOptions(latitude_deg=truth["latitude"], prior=prior, wander="auto")


def test_the_json_carries_each_hypothesis_and_an_orientation_effect_beats_the_excess(shared_data):
    """gyro.g_sensitivity hidden: the baseline's misfit is an excess independent on each window
    (tau 0, not a wander), which the effect explains far better; the verdict says so and the
    JSON has every figure."""
    pos, opt = _shared(shared_data, "gyro_g_sensitivity")
    d = diagnose(pos, opt)
    doc = d.to_json_dict()
    top = doc["candidates"][0]
    assert top["effect"] == "gyro.g_sensitivity" and top["significant"]
    h = top["hypotheses"]
    assert set(h) >= {"nothing", "noise", "effect", "effect+noise", "best", "null", "test"}
    assert h["best"] == "effect" and h["null"] == "noise"
    assert h["effect"] < h["noise"] < h["nothing"]
    gyro = next(t for t in h["noise_null"]["triads"] if t["sensor"] == "gyro")
    assert gyro["kind"] == "excess" and gyro["admitted"] and gyro["tau_s"] == 0.0
    assert h["test"]["draws"] > 0 and h["test"]["likelihood_ratio"] > 50
    assert doc["explanation"] == "effect"
    # the heading-dependent look-alike (recal.diagnose.lookalikes) cannot fit a g-sensitivity
    # with cross-axis terms, so it does not make the diagnosis NOT CONFIRMED
    look = doc["lookalike"]
    assert look["replaces"] == ["gyro.g_sensitivity"] and look["p_suggested_better"] < 1e-6
    assert "heading-dependent gyro bias" not in d.verdict
    assert "excess" in d.verdict and "alone explains it worse" in d.verdict
    assert "wander" not in d.verdict.split("NOT CONFIRMED")[0]  # an excess is never wander


def test_past_the_bootstraps_size_the_test_is_asymptotic_and_says_so(shared_data, monkeypatch):
    monkeypatch.setattr(candidates_module, "NOISE_NULL_MAX_RESIDUALS", 10)
    pos, opt = _shared(shared_data, "accel_bias_temperature")
    d = diagnose(pos, opt)
    top = d.candidates[0]
    assert top.effect == "accel.bias_temperature" and top.significant
    assert "Bonferroni" in top.hypotheses["test"]["null"]
    assert d.suggested_effects == ["accel.bias_temperature"] and not d.model_fails


@pytest.mark.parametrize("name", ["none"])
def test_a_clean_session_of_hours_has_no_noise_and_no_effect(shared_data, name):
    pos, opt = _shared(shared_data, name)
    d = diagnose(pos, opt)
    assert d.explanation == "nothing" and not d.suggested_effects
    assert d.noise is not None and not d.noise.admitted
