"""Models, references and coefficient sets."""

import numpy as np
import pytest

from recal.errors import RecalInputError
from recal.model.coefficients import CoefficientSet
from recal.model.error_model import Model, ParameterLayout, inv3
from recal.model.reference import OMEGA_IE_DEG_H, dot_reference, normal_gravity_g
from recal.model.terms import MISALIGNMENT_NAMES, catalogue_terms


def test_reference_values_match_conventions():
    assert OMEGA_IE_DEG_H == pytest.approx(15.04107, abs=5e-6)
    assert normal_gravity_g(0.0) == pytest.approx(0.99732, abs=1e-5)
    assert normal_gravity_g(45.7) == pytest.approx(1.00002, abs=1e-5)
    assert normal_gravity_g(90.0) == pytest.approx(1.00260, abs=1e-5)
    assert normal_gravity_g(45.0, 1000.0) < normal_gravity_g(45.0)  # free-air decrease
    assert dot_reference(30.0) == pytest.approx(OMEGA_IE_DEG_H * normal_gravity_g(30.0) * 0.5)


def test_misalignment_layout_follows_seed_eq11():
    layout = ParameterLayout((Model.seed("gyro"),))
    theta = CoefficientSet.seed_truth().to_vector(layout)
    E = Model.seed("gyro").terms[2].matrix(theta[None, 6:])[0]
    vals = dict(zip(MISALIGNMENT_NAMES, theta[6:], strict=True))
    expected = [
        [0, vals["Exz"], vals["Exy"]],
        [vals["Eyz"], 0, vals["Eyx"]],
        [vals["Ezy"], vals["Ezx"], 0],
    ]
    np.testing.assert_array_equal(E, expected)


@pytest.mark.parametrize("sensor", ["gyro", "accel"])
def test_inverse_undoes_forward_batched(sensor):
    rng = np.random.default_rng(7)
    model = Model.seed(sensor)
    layout = ParameterLayout((model,))
    base = CoefficientSet.seed_truth().to_vector(layout)
    theta = base + layout.typical(base) * rng.normal(size=(5, layout.size))
    x = rng.normal(size=(11, 3)) * (15.0 if sensor == "gyro" else 1.0)
    N = model.forward(theta, x, {})
    for p in range(5):
        back = model.inverse(theta[p : p + 1], N[p], {})[0]
        np.testing.assert_allclose(back, x, rtol=0, atol=1e-12 * np.abs(x).max())


def test_inv3_matches_numpy():
    A = np.eye(3) + 0.1 * np.random.default_rng(0).normal(size=(20, 3, 3))
    np.testing.assert_allclose(inv3(A), np.linalg.inv(A), atol=1e-12)


def test_catalogue_effect_changes_output_as_described():
    term = catalogue_terms(t0_c=20.0)["gyro.bias_temperature"]
    model = Model.seed("gyro", [term])
    layout = ParameterLayout((model,))
    theta = CoefficientSet.seed_truth().to_vector(layout)
    theta[-3:] = [0.01, 0.0, 0.0]
    x = np.zeros((2, 3))
    N = model.forward(theta[None], x, {"temperature_c": np.array([20.0, 30.0])})[0]
    # 10 degC above T0 adds 0.1 deg/h of x bias, times the x scale factor
    assert N[1, 0] - N[0, 0] == pytest.approx(0.1 * theta[0])


def test_coefficients_json_round_trip_and_errors():
    cs = CoefficientSet.seed_truth()
    terms = catalogue_terms()
    cs.values["gyro.bias_drift"] = np.array([1e-3, 2e-3, 3e-3])
    doc = cs.to_json_dict(terms)
    assert set(doc["gyro"]) == {"scale", "bias", "misalignment"}
    assert set(doc["accel"]) == {"scale", "bias", "misalignment", "quadratic"}
    assert doc["effects"]["gyro.bias_drift"] == {"dx": 1e-3, "dy": 2e-3, "dz": 3e-3}
    back = CoefficientSet.from_json_dict(doc, terms)
    for k, v in cs.values.items():
        np.testing.assert_array_equal(back.values[k], v)
    with pytest.raises(RecalInputError, match="scale must have 3 values"):
        CoefficientSet.from_json_dict({"gyro": {"scale": [1, 2]}})
    with pytest.raises(RecalInputError, match="misalignment must have exactly"):
        CoefficientSet.from_json_dict({"gyro": {"misalignment": {"Exz": 0}}})
