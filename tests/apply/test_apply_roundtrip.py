"""Round trip (issue 39, acceptance): raw outputs simulated from known coefficients, temperature
and quadratic terms included, come back through ``recal.apply`` and ``recal apply`` as the true
inputs to within 1e-9 relative.

The forward simulation is the error model written out here in numpy (docs/reference.md#models,
docs/reference.md#effects), not recal's own forward map, so a sign or order slip on either side
fails.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

import recal
from recal.errors import RecalInputError
from recal.model.apply import Applier
from recal.model.coefficients import CoefficientSet
from service.cli.main import main

RATE_HZ = 100.0
N = 6000  # one minute at 100 Hz, past the temperature-rate span
T0_C = 25.0
TEMP_SLOPE_C_PER_S = 0.01  # a warm-up: 36 degC/h


def truth() -> CoefficientSet:
    """Seed 000 Table 2 gyro + the project's accel, with every catalogue effect a recording can
    drive: temperature (bias and scale, both triads), temperature rate, g-sensitivity, drift,
    the accel's quadratic term and its scale asymmetry."""
    cs = CoefficientSet.seed_truth()
    cs.t0_c = T0_C
    cs.values.update(
        {
            "accel.quadratic": np.array([4e-4, -3e-4, 5e-4]),  # 20x the stand-in: exercised
            "gyro.bias_temperature": np.array([0.002, -0.003, 0.001]),
            "gyro.scale_temperature": np.array([2e-5, -1e-5, 3e-5]),
            "gyro.bias_temperature_rate": np.array([0.001, 0.002, -0.001]),
            "gyro.g_sensitivity": np.array(
                [0.01, -0.02, 0.005, 0.003, 0.02, -0.01, 0.0, 0.004, 0.01]
            ),
            "gyro.bias_drift": np.array([0.003, -0.002, 0.001]),
            "accel.bias_temperature": np.array([2e-5, -1e-5, 3e-5]),
            "accel.scale_temperature": np.array([-2e-5, 1e-5, 2e-5]),
            "accel.scale_asymmetry": np.array([1e-4, -2e-4, 5e-5]),
        }
    )
    return cs


def _E(six: np.ndarray) -> np.ndarray:
    """E = [[0, Exz, Exy], [Eyz, 0, Eyx], [Ezy, Ezx, 0]] (docs/reference.md#models)."""
    Exz, Exy, Eyz, Eyx, Ezy, Ezx = six
    return np.array([[0.0, Exz, Exy], [Eyz, 0.0, Eyx], [Ezy, Ezx, 0.0]])


def inputs(seed: int = 1) -> dict[str, np.ndarray]:
    """A unit turning and shaken: rates up to ~30 deg/s, specific force up to ~2.5 g, and a
    temperature ramp; every sample well away from zero so relative errors mean something."""
    rng = np.random.default_rng(seed)
    t = np.arange(N) / RATE_HZ
    w = (
        1e5
        * np.column_stack([np.sin(0.3 * t + k) + 1.5 for k in range(3)])
        * rng.choice([-1, 1], 3)
    )
    f = np.column_stack([np.cos(0.2 * t), np.sin(0.2 * t), np.full(N, 1.0)]) * 1.4
    f += 0.3 * rng.standard_normal((N, 3))
    temp = 20.0 + TEMP_SLOPE_C_PER_S * t
    rate = np.full(N, TEMP_SLOPE_C_PER_S * 3600.0)
    rate[0] = 0.0  # the slope over the last minute: none before the first sample (docs/apply.md)
    return {"time_s": t, "w_dph": w, "f_g": f, "temp": temp, "temp_rate": rate}


def forward(cs: CoefficientSet, x: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Raw outputs (N_g, N_a) of the model with every effect, written out per term (an effect
    the set lacks is zero)."""
    v = {k: np.zeros(9 if k == "gyro.g_sensitivity" else 3) for k in truth().values}
    v.update(cs.values)
    dT = (x["temp"] - cs.t0_c)[:, None]
    f = x["f_g"]
    K_a = v["accel.scale"] * (1 + v["accel.scale_temperature"] * dT)
    inner_a = f @ (np.eye(3) + _E(v["accel.misalignment"])).T
    inner_a += v["accel.quadratic"] * f**2 + v["accel.scale_asymmetry"] * np.abs(f)
    inner_a += v["accel.bias"] + v["accel.bias_temperature"] * dT
    N_a = K_a * inner_a
    K_g = v["gyro.scale"] * (1 + v["gyro.scale_temperature"] * dT)
    inner_g = x["w_dph"] @ (np.eye(3) + _E(v["gyro.misalignment"])).T
    inner_g += v["gyro.bias"] + v["gyro.bias_temperature"] * dT
    inner_g += v["gyro.bias_temperature_rate"] * x["temp_rate"][:, None]
    inner_g += f @ v["gyro.g_sensitivity"].reshape(3, 3).T
    inner_g += v["gyro.bias_drift"] * (x["time_s"] / 3600.0)[:, None]
    return K_g * inner_g, N_a


def max_relative(got: np.ndarray, want: np.ndarray) -> float:
    """Largest per-sample |got - want| / |want| (vector norms)."""
    return float(np.max(np.linalg.norm(got - want, axis=1) / np.linalg.norm(want, axis=1)))


def test_apply_returns_the_true_inputs_with_every_term() -> None:
    cs, x = truth(), inputs()
    N_g, N_a = forward(cs, x)
    out = recal.apply(cs, N_g, N_a, x["temp"], time_s=x["time_s"])
    assert out.gyro_unit == "deg/h" and out.accel_unit == "g"
    assert max_relative(out.gyro, x["w_dph"]) < 1e-9
    assert max_relative(out.accel, x["f_g"]) < 1e-9
    # the same in other units, from the parsed JSON of a coefficients file
    doc = json.loads(json.dumps(cs.to_json_dict()))
    out = recal.apply(doc, N_g, N_a, x["temp"], time_s=x["time_s"], gyro_unit="rad/s",
                      accel_unit="m/s^2")  # fmt: skip
    assert max_relative(out.gyro, x["w_dph"] * math.radians(1) / 3600) < 1e-9
    assert max_relative(out.accel, x["f_g"] * 9.80665) < 1e-9


def test_leaving_a_term_out_is_seen() -> None:
    """The check above can fail: without the quadratic term the accel is off by ~K2 f^2."""
    cs, x = truth(), inputs()
    N_g, N_a = forward(cs, x)
    cs.values["accel.quadratic"] = np.zeros(3)
    out = recal.apply(cs, N_g, N_a, x["temp"], time_s=x["time_s"])
    assert max_relative(out.accel, x["f_g"]) > 1e-4


def test_chunks_give_the_same_answer_as_one_call() -> None:
    cs, x = truth(), inputs()
    N_g, N_a = forward(cs, x)
    whole = recal.apply(cs, N_g, N_a, x["temp"], time_s=x["time_s"])
    applier = Applier(cs)
    parts = [applier(x["time_s"][s], N_g[s], N_a[s], x["temp"][s])
             for s in (slice(0, 7), slice(7, 2500), slice(2500, 2500), slice(2500, N))]  # fmt: skip
    assert np.array_equal(np.vstack([p.gyro for p in parts]), whole.gyro)
    assert np.array_equal(np.vstack([p.accel for p in parts]), whole.accel)


def test_missing_context_is_an_input_error() -> None:
    cs, x = truth(), inputs()
    N_g, N_a = forward(cs, x)
    with pytest.raises(RecalInputError, match="need the temperature"):
        recal.apply(cs, N_g, N_a, time_s=x["time_s"])
    with pytest.raises(RecalInputError, match="need time"):
        recal.apply(cs, N_g, N_a, x["temp"])
    with pytest.raises(RecalInputError, match="g_sensitivity needs the accel"):
        recal.apply(cs, N_g, None, x["temp"], time_s=x["time_s"])
    with pytest.raises(RecalInputError, match="gyro unit"):
        recal.apply(cs, N_g, N_a, x["temp"], time_s=x["time_s"], gyro_unit="rpm")


def test_a_triad_alone() -> None:
    """A gyro-only set (``calibrate --sensor gyro``) applies to the gyro alone."""
    cs = CoefficientSet.seed_truth()
    gyro_only = CoefficientSet({k: v for k, v in cs.values.items() if k.startswith("gyro.")})
    x = inputs()
    N_g, _ = forward(cs, x)
    out = recal.apply(gyro_only, N_g, None)
    assert out.accel is None and max_relative(out.gyro, x["w_dph"]) < 1e-9


def _write_recording(path: Path, x: dict[str, np.ndarray], N_g, N_a) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time_s", "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z",
                    "temperature_c"])  # fmt: skip
        for row in np.column_stack([x["time_s"], N_g, N_a, x["temp"]]):
            w.writerow([repr(float(v)) for v in row])


def test_recal_apply_command_round_trip(tmp_path: Path, capsys) -> None:
    cs, x = truth(), inputs()
    N_g, N_a = forward(cs, x)
    coeffs = tmp_path / "coeffs.json"
    coeffs.write_text(json.dumps(cs.to_json_dict()))
    rec = tmp_path / "rec.csv"
    _write_recording(rec, x, N_g, N_a)
    out = tmp_path / "out.csv"
    args = [
        "apply",
        str(coeffs),
        str(rec),
        "--format",
        "csv",
        "--rate",
        str(RATE_HZ),
        "-o",
        str(out),
    ]
    assert main([*args, "--out-units", "gyro=deg/s,accel=m/s^2"]) == 0
    assert "wrote 6000 calibrated samples" in capsys.readouterr().err
    table = np.genfromtxt(out, delimiter=",", names=True)
    names = table.dtype.names
    assert names[:7] == ("time_s", "gyro_x_deg_per_s", "gyro_y_deg_per_s", "gyro_z_deg_per_s",
                         "accel_x_m_per_s2", "accel_y_m_per_s2", "accel_z_m_per_s2")  # fmt: skip
    gyro = np.column_stack([table[n] for n in names[1:4]])
    accel = np.column_stack([table[n] for n in names[4:7]])
    assert np.allclose(table["time_s"], x["time_s"], rtol=0, atol=1e-9)
    assert max_relative(gyro, x["w_dph"] / 3600.0) < 1e-9
    assert max_relative(accel, x["f_g"] * 9.80665) < 1e-9
    assert np.array_equal(table["temperature_c"], np.round(x["temp"], 10))


def test_recal_apply_bad_input_exits_2(tmp_path: Path, capsys) -> None:
    cs, x = truth(), inputs()
    N_g, N_a = forward(cs, x)
    coeffs = tmp_path / "coeffs.json"
    coeffs.write_text(json.dumps(cs.to_json_dict()))
    rec = tmp_path / "rec.csv"
    _write_recording(rec, x, N_g, N_a)
    out = tmp_path / "out.csv"
    base = ["apply", str(coeffs), str(rec), "--format", "csv", "-o", str(out)]
    assert main([*base, "--out-units", "gyro=rpm"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--out-units" in err and "Traceback" not in err
    assert main(["apply", str(tmp_path / "none.json"), *base[2:]]) == 2
    assert "does not exist" in capsys.readouterr().err
    no_temp = tmp_path / "no_temp.csv"
    no_temp.write_text("\n".join(",".join(r.split(",")[:7]) for r in rec.read_text().splitlines()))
    assert main(["apply", str(coeffs), str(no_temp), "--format", "csv", "-o", str(out)]) == 2
    assert "need the temperature" in capsys.readouterr().err
    assert not out.exists()  # nothing half-written under the final name


def test_a_nonlinear_term_too_large_to_invert_is_an_input_error() -> None:
    """2 K2 |f| above 1: the inverse does not converge, and says so instead of returning NaN."""
    cs = CoefficientSet.seed_truth()
    cs.values["accel.quadratic"] = np.array([0.6, 0.6, 0.6])  # 1/g
    f = np.array([[3.0, 0.1, 0.1], [0.5, 0.1, 0.2]])  # g
    N_a = cs.values["accel.scale"] * (f + 0.6 * f**2 + cs.values["accel.bias"])
    with pytest.raises(RecalInputError, match="cannot be inverted"):
        recal.apply(cs, None, N_a)


def test_a_lost_value_stays_lost() -> None:
    cs, x = truth(), inputs()
    N_g, N_a = forward(cs, x)
    N_a[10] = np.nan
    out = recal.apply(cs, N_g, N_a, x["temp"], time_s=x["time_s"])
    assert np.isnan(out.accel[10]).all() and np.isnan(out.gyro[10]).all()  # g-sensitivity needs f
    keep = np.arange(N) != 10
    assert max_relative(out.accel[keep], x["f_g"][keep]) < 1e-9
