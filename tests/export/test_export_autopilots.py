"""``recal export --to px4|ardupilot|imu_tk`` (issue 39, acceptance): each file is read back and
applied with the target's own published equations (written out here, not recal's), on raw
outputs simulated from known coefficients; what the target carries comes back to its own
precision, and what it cannot carry costs no more than the file says."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from recal.model.apply import triad_models
from recal.model.coefficients import CoefficientSet
from recal.model.error_model import ParameterLayout
from service.cli.main import main

G0 = 9.80665
RAD_S_PER_DEG_H = math.radians(1.0) / 3600.0
N = 3000
T0, T_CAL, T_MIN, T_MAX = 25.0, 31.0, 20.0, 45.0


def autopilot_set(misaligned: bool = False) -> CoefficientSet:
    """A MEMS unit whose raw outputs are m/s^2 and rad/s (what an autopilot's driver gives):
    K_a ~ 9.80665 per g, K_g exactly the rad/s per deg/h (an autopilot has no gyro scale),
    biases, linear temperature terms; misalignment only when asked."""
    cs = CoefficientSet(
        {
            "accel.scale": G0 * np.array([1.002, 0.997, 1.001]),
            "accel.bias": np.array([0.012, -0.008, 0.02]),  # g
            "gyro.scale": np.full(3, RAD_S_PER_DEG_H),
            "gyro.bias": np.array([300.0, -150.0, 80.0]),  # deg/h
            "accel.bias_temperature": np.array([2e-4, -1e-4, 3e-4]),  # g/degC
            "gyro.bias_temperature": np.array([5.0, -3.0, 2.0]),  # deg/h/degC
        },
        t0_c=T0,
        metadata={"calibration_temperature_c": {"mean": T_CAL, "min": T_MIN, "max": T_MAX}},
    )
    if misaligned:
        cs.values["accel.misalignment"] = np.array([2e-3, -1e-3, 1.5e-3, 5e-4, -2e-3, 1e-3])
        cs.values["gyro.misalignment"] = np.array([1e-3, 2e-3, -1e-3, 5e-4, 1e-3, -5e-4])
    return cs


def simulate(cs: CoefficientSet, seed: int = 0) -> dict[str, np.ndarray]:
    """True inputs (f in g, w in deg/h), the temperature inside the calibration's range, and
    the raw outputs of the set's model."""
    rng = np.random.default_rng(seed)
    f = rng.standard_normal((N, 3))
    f = f / np.linalg.norm(f, axis=1, keepdims=True) * rng.uniform(0.5, 2.0, (N, 1))
    w = rng.uniform(-2e5, 2e5, (N, 3))  # up to 55 deg/s
    temp = rng.uniform(T_MIN, T_MAX, N)
    ctx = {"temperature_c": temp}
    out = {"f": f, "w": w, "T": temp}
    for sensor, x in (("accel", f), ("gyro", w)):
        model = triad_models(cs)[sensor]
        theta = cs.to_vector(ParameterLayout((model,)))[None]
        out[sensor] = model.forward(theta, x, ctx)[0]
    return out


def export(tmp: Path, cs: CoefficientSet, fmt: str, capsys) -> tuple[Path, dict[str, float]]:
    coeffs = tmp / "coeffs.json"
    coeffs.write_text(json.dumps(cs.to_json_dict()))
    out = tmp / f"out.{fmt}"
    assert main(["export", str(coeffs), "--to", fmt, "-o", str(out)]) == 0
    stated = {}
    for line in capsys.readouterr().err.splitlines():
        if "not carried" in line:
            term = line.split("recal export: ")[1].split(":")[0]
            stated[term] = float(line.split("costs up to ")[1].split()[0])
    return out, stated


def _relative(got: np.ndarray, want: np.ndarray) -> float:
    return float(np.max(np.linalg.norm(got - want, axis=1) / np.linalg.norm(want, axis=1)))


# ---- PX4 -------------------------------------------------------------------------------------
def read_px4(path: Path) -> dict[str, float]:
    """A QGroundControl parameter file: '#' comments, then VEHICLE COMPONENT NAME VALUE TYPE."""
    params = {}
    for line in path.read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        _, _, name, value, kind = line.split("\t")
        params[name] = int(value) if kind == "6" else float(value)
    return params


def px4_apply(p: dict[str, float], raw_a, raw_g, temp) -> tuple[np.ndarray, np.ndarray]:
    """PX4's sensor correction: (raw - thermal - CAL_*OFF) * CAL_*SCALE, thermal the TC_*
    polynomial in (T - TREF), T held in [TMIN, TMAX]."""

    def thermal(prefix: str, enable: str) -> np.ndarray:
        if not p.get(enable):
            return np.zeros((len(temp), 3))
        dt = np.clip(temp, p[f"{prefix}_TMIN"], p[f"{prefix}_TMAX"]) - p[f"{prefix}_TREF"]
        return np.column_stack([sum(p[f"{prefix}_X{i}_{j}"] * dt**i for i in range(4))
                                for j in range(3)])  # fmt: skip

    off_a = np.array([p[f"CAL_ACC0_{a}OFF"] for a in "XYZ"])
    scale_a = np.array([p[f"CAL_ACC0_{a}SCALE"] for a in "XYZ"])
    off_g = np.array([p[f"CAL_GYRO0_{a}OFF"] for a in "XYZ"])
    accel = (raw_a - thermal("TC_A0", "TC_A_ENABLE") - off_a) * scale_a
    gyro = raw_g - thermal("TC_G0", "TC_G_ENABLE") - off_g
    return accel, gyro


def test_px4_parameters_applied_as_px4_does(tmp_path: Path, capsys) -> None:
    cs = autopilot_set()
    path, stated = export(tmp_path, cs, "px4", capsys)
    assert stated == {}  # everything this set has, PX4 carries
    sim = simulate(cs)
    params = read_px4(path)
    assert params["TC_A_ENABLE"] == 1 and params["TC_A0_TREF"] == T0
    assert params["CAL_ACC0_TEMP"] == T_CAL  # the temperature the calibration was made at
    accel, gyro = px4_apply(params, sim["accel"], sim["gyro"], sim["T"])
    assert _relative(accel, sim["f"] * G0) < 1e-7  # 9 digits written: float32 on the vehicle
    assert _relative(gyro, sim["w"] * RAD_S_PER_DEG_H) < 1e-7


def test_px4_states_what_dropping_misalignment_costs(tmp_path: Path, capsys) -> None:
    cs = autopilot_set(misaligned=True)
    path, stated = export(tmp_path, cs, "px4", capsys)
    assert set(stated) == {"accel.misalignment", "gyro.misalignment"}
    sim = simulate(cs, seed=1)
    accel, gyro = px4_apply(read_px4(path), sim["accel"], sim["gyro"], sim["T"])
    # per unit of input: the stated cost is at 1 g and at 1 rad/s
    miss_a = np.linalg.norm(accel - sim["f"] * G0, axis=1) / np.linalg.norm(sim["f"], axis=1)
    w_si = sim["w"] * RAD_S_PER_DEG_H
    miss_g = np.linalg.norm(gyro - w_si, axis=1) / np.linalg.norm(w_si, axis=1)
    assert miss_a.max() <= 1.02 * stated["accel.misalignment"]
    assert miss_a.max() > 0.5 * stated["accel.misalignment"]
    assert miss_g.max() <= 1.02 * stated["gyro.misalignment"]
    assert miss_g.max() > 0.5 * stated["gyro.misalignment"]


# ---- ArduPilot -------------------------------------------------------------------------------
def read_ardupilot(path: Path) -> dict[str, float]:
    """NAME,VALUE lines (Mission Planner's .param), '#' comments."""
    params = {}
    for line in path.read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        name, value = line.split(",")
        params[name] = float(value)
    return params


def ardupilot_apply(p: dict[str, float], raw_a, raw_g, temp) -> tuple[np.ndarray, np.ndarray]:
    """ArduPilot: raw - tcal(T) + tcal(CALTEMP), both held in [TMIN, TMAX], tcal(T) =
    (c1 + (c2 + c3 d) d) d / 1e6 with d = T - 35; then - offsets, * scale (accel only)."""

    def tcal(short: str, t: np.ndarray) -> np.ndarray:
        d = np.clip(t, p["INS_TCAL1_TMIN"], p["INS_TCAL1_TMAX"]) - 35.0
        c = [np.array([p[f"INS_TCAL1_{short}{k}_{a}"] for a in "XYZ"]) for k in (1, 2, 3)]
        d = d[:, None]
        return (c[0] + (c[1] + c[2] * d) * d) * d * 1e-6

    def corrected(raw, short: str, caltemp: str) -> np.ndarray:
        if not p.get("INS_TCAL1_ENABLE"):
            return raw
        cal = np.full(len(temp), p[caltemp])
        return raw - tcal(short, temp) + tcal(short, cal)

    accel = corrected(raw_a, "ACC", "INS_ACC1_CALTEMP")
    accel = (accel - [p[f"INS_ACCOFFS_{a}"] for a in "XYZ"]) * [
        p[f"INS_ACCSCAL_{a}"] for a in "XYZ"
    ]
    gyro = corrected(raw_g, "GYR", "INS_GYR1_CALTEMP") - [p[f"INS_GYROFFS_{a}"] for a in "XYZ"]
    return accel, gyro


def test_ardupilot_parameters_applied_as_ardupilot_does(tmp_path: Path, capsys) -> None:
    cs = autopilot_set()
    path, stated = export(tmp_path, cs, "ardupilot", capsys)
    assert stated == {}
    params = read_ardupilot(path)
    assert params["INS_ACC1_CALTEMP"] == T_CAL and params["INS_GYR1_CALTEMP"] == T_CAL
    assert (params["INS_TCAL1_TMIN"], params["INS_TCAL1_TMAX"]) == (T_MIN, T_MAX)
    sim = simulate(cs)
    accel, gyro = ardupilot_apply(params, sim["accel"], sim["gyro"], sim["T"])
    assert _relative(accel, sim["f"] * G0) < 1e-7
    assert _relative(gyro, sim["w"] * RAD_S_PER_DEG_H) < 1e-7
    # the calibration temperature is not T0: the offsets carry the difference
    assert params["INS_ACCOFFS_X"] != cs.values["accel.scale"][0] * cs.values["accel.bias"][0]


def test_ardupilot_states_the_gyro_scale_it_reads_as_rad_s(tmp_path: Path, capsys) -> None:
    cs = autopilot_set()
    cs.values["gyro.scale"] = cs.values["gyro.scale"] * np.array([1.003, 0.998, 1.0])
    path, stated = export(tmp_path, cs, "ardupilot", capsys)
    assert abs(stated["gyro.scale"] - 0.003) < 1e-6  # the largest |K / (rad/s per deg/h) - 1|
    sim = simulate(cs, seed=2)
    _, gyro = ardupilot_apply(read_ardupilot(path), sim["accel"], sim["gyro"], sim["T"])
    w_si = sim["w"] * RAD_S_PER_DEG_H
    miss = np.abs(gyro - w_si) / np.abs(w_si)
    assert np.max(miss[np.abs(w_si) > 0.1]) <= 1.01 * stated["gyro.scale"]


# ---- imu_tk ----------------------------------------------------------------------------------
def read_imu_tk(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The 21 numbers imu_tk's CalibratedTriad::load reads (T, K row-major, then B); what
    follows them is never read."""
    numbers = []
    for token in path.read_text().split():
        if len(numbers) == 21:
            break
        numbers.append(float(token))
    return (np.array(numbers[:9]).reshape(3, 3), np.array(numbers[9:18]).reshape(3, 3),
            np.array(numbers[18:]))  # fmt: skip


def test_imu_tk_matrices_applied_as_imu_tk_does(tmp_path: Path, capsys) -> None:
    cs = CoefficientSet.seed_truth()
    cs.values["accel.quadratic"] = np.zeros(3)  # imu_tk has no quadratic term
    path, stated = export(tmp_path, cs, "imu_tk", capsys)
    assert stated == {}
    sim = simulate(cs)
    for part, raw, want in (("acc", sim["accel"], sim["f"] * G0),
                            ("gyro", sim["gyro"], sim["w"] * RAD_S_PER_DEG_H)):  # fmt: skip
        T, K, B = read_imu_tk(Path(f"{path}_{part}.calib"))
        assert np.allclose(np.diag(T), 1.0) and np.count_nonzero(K - np.diag(np.diag(K))) == 0
        got = (T @ K @ (raw - B).T).T  # X' = T K (X - B)
        assert _relative(got, want) < 1e-12, part


def test_imu_tk_notes_the_quadratic_term(tmp_path: Path, capsys) -> None:
    cs = CoefficientSet.seed_truth()
    path, stated = export(tmp_path, cs, "imu_tk", capsys)
    k2 = float(np.abs(cs.values["accel.quadratic"]).max())
    assert stated == {"accel.quadratic": float(f"{k2 * G0:.3g}")}
    text = Path(f"{path}_acc.calib").read_text()
    assert "# accel.quadratic: not carried" in text
    assert "quadratic" not in Path(f"{path}_gyro.calib").read_text()
