"""The published file is self-describing (issue 39, item 3): a file written by the daemon's
publisher is applied with docs/apply.md's reference implementation alone, in a Python process
where importing recal (or drivers, or service) raises, and the true inputs come back to within
1e-9 relative. The raw outputs are simulated here from the model's equations in numpy.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from service.publish import Publisher
from service.store.records import CalibrationRecord

ROOT = Path(__file__).resolve().parents[2]
N = 3000
RATE_HZ = 50.0

#: A calibration with every term docs/apply.md lists, as the daemon stores it.
COEFFICIENTS = {
    "gyro": {
        "scale": [643.5, 645.6, 645.2],
        "bias": [0.0156, 0.0321, 0.0279],
        "misalignment": {"Exz": 9.9e-4, "Exy": 1.1e-4, "Eyz": -3.7e-4, "Eyx": 1.4e-4,
                         "Ezy": 1.05e-4, "Ezx": -4.2e-4},
    },
    "accel": {
        "scale": [1.00021, 0.99987, 1.00012],
        "bias": [2.1e-4, -1.4e-4, 3.2e-4],
        "misalignment": {"Exz": 4e-4, "Exy": -2.5e-4, "Eyz": 1.2e-4, "Eyx": 3.1e-4,
                         "Ezy": -1.8e-4, "Ezx": 2.2e-4},
        "quadratic": [3e-4, -2e-4, 4e-4],
    },
    "effects": {
        "gyro.bias_temperature": {"kTx": 0.002, "kTy": -0.003, "kTz": 0.001},
        "gyro.scale_temperature": {"sTx": 2e-5, "sTy": -1e-5, "sTz": 3e-5},
        "gyro.bias_temperature_rate": {"kdTx": 0.001, "kdTy": 0.002, "kdTz": -0.001},
        "gyro.g_sensitivity": {"Gxx": 0.01, "Gxy": -0.02, "Gxz": 0.005, "Gyx": 0.003,
                               "Gyy": 0.02, "Gyz": -0.01, "Gzx": 0.0, "Gzy": 0.004, "Gzz": 0.01},
        "gyro.bias_drift": {"dx": 0.003, "dy": -0.002, "dz": 0.001},
        "accel.bias_temperature": {"kTx": 2e-5, "kTy": -1e-5, "kTz": 3e-5},
        "accel.scale_temperature": {"sTx": -2e-5, "sTy": 1e-5, "sTz": 2e-5},
        "accel.scale_asymmetry": {"ax": 1e-4, "ay": -2e-4, "az": 5e-5},
    },
    "t0_c": 30.0,
    "schema": "recal.coefficients/1",
    "metadata": {"calibration_temperature_c": {"mean": 31.2, "min": 28.0, "max": 34.5}},
}  # fmt: skip

#: Imports refused in the process that applies the file.
BLOCKER = """
import sys
class _NoProject:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("recal", "drivers", "service"):
            raise ImportError(f"{name}: the published file must be usable without recal")
sys.meta_path.insert(0, _NoProject())
"""


def _vec(block: dict, key: str) -> np.ndarray:
    return np.array(block[key], float)


def _effect(name: str) -> np.ndarray:
    return np.array(list(COEFFICIENTS["effects"][name].values()), float)


def _one_plus_e(mis: dict) -> np.ndarray:
    return np.array(
        [
            [1.0, mis["Exz"], mis["Exy"]],
            [mis["Eyz"], 1.0, mis["Eyx"]],
            [mis["Ezy"], mis["Ezx"], 1.0],
        ]
    )


def simulate() -> dict[str, np.ndarray]:
    """True inputs and the raw outputs the model gives for them."""
    rng = np.random.default_rng(7)
    t = np.arange(N) / RATE_HZ
    w = 2e4 * (np.column_stack([np.sin(0.5 * t + k) for k in range(3)]) + 1.6)
    f = np.column_stack([np.sin(0.1 * t), np.cos(0.1 * t), np.ones(N)]) * 1.2
    f += 0.2 * rng.standard_normal((N, 3))
    temp = 28.0 + 0.05 * t  # 180 degC/h: a fast warm-up
    rate = np.full(N, 0.05 * 3600.0)
    rate[0] = 0.0  # the slope over the last 60 s (docs/apply.md): none at the first sample
    c = COEFFICIENTS
    dT = (temp - c["t0_c"])[:, None]
    a, g = c["accel"], c["gyro"]
    N_a = (_vec(a, "scale") * (1 + _effect("accel.scale_temperature") * dT)) * (
        f @ _one_plus_e(a["misalignment"]).T
        + _vec(a, "quadratic") * f**2
        + _effect("accel.scale_asymmetry") * np.abs(f)
        + _vec(a, "bias")
        + _effect("accel.bias_temperature") * dT
    )
    N_g = (_vec(g, "scale") * (1 + _effect("gyro.scale_temperature") * dT)) * (
        w @ _one_plus_e(g["misalignment"]).T
        + _vec(g, "bias")
        + _effect("gyro.bias_temperature") * dT
        + _effect("gyro.bias_temperature_rate") * rate[:, None]
        + f @ _effect("gyro.g_sensitivity").reshape(3, 3).T
        + _effect("gyro.bias_drift") * (t / 3600.0)[:, None]
    )
    return {"w": w, "f": f, "N_g": N_g, "N_a": N_a, "T": temp, "dTdt": rate, "t_h": t / 3600}


def reference_implementation() -> str:
    """The Python block under docs/apply.md's 'Reference implementation' heading."""
    text = (ROOT / "docs" / "apply.md").read_text(encoding="utf-8")
    match = re.search(r"^## Reference implementation\n.*?```python\n(.*?)```", text, re.S | re.M)
    assert match, "docs/apply.md has no reference implementation block"
    return match.group(1)


def published(tmp_path: Path) -> Path:
    """The file the daemon's publisher writes for a stored version with these coefficients."""
    record = CalibrationRecord(
        version=3,
        created_at=datetime(2026, 11, 28, tzinfo=UTC),
        trigger="auto",
        method="lm",
        accepted=True,
        document={"coefficients": COEFFICIENTS, "status": None, "uncertainty": None, "held": {}},
    )
    path = tmp_path / "coefficients.json"
    Publisher(path).publish(record)
    return path


def test_the_published_file_describes_itself(tmp_path: Path) -> None:
    doc = json.loads(published(tmp_path).read_text())
    assert doc["schema"] == "recal.published/1"
    model = doc["model"]
    assert model["reference_temperature_c"] == 30.0 and model["vector_order"] == "x, y, z"
    assert "K2_a * f**2" in model["equations"]["accel"]
    assert model["equations"]["misalignment"] == "E = [[0, Exz, Exy], [Eyz, 0, Eyx], [Ezy, Ezx, 0]]"
    assert "deg/h" in model["inputs"]["w"] and "9.80665" in model["inputs"]["f"]
    units = model["units"]
    assert units["accel.quadratic"] == {"symbol": "K2_a", "unit": "1/g"}
    assert units["gyro.bias_temperature"]["unit"] == "deg/h/degC"
    assert set(units) == {f"{s}.{k}" for s in ("gyro", "accel") for k in COEFFICIENTS[s]} | set(
        COEFFICIENTS["effects"]
    )
    assert doc["calibration_temperature_c"] == {"mean": 31.2, "min": 28.0, "max": 34.5}


def _apply_standalone(tmp_path: Path, doc_path: Path, sim: dict[str, np.ndarray]) -> dict:
    inputs = tmp_path / "raw.json"
    inputs.write_text(json.dumps({k: sim[k].tolist() for k in ("N_g", "N_a", "T", "dTdt", "t_h")}))
    script = (
        BLOCKER
        + reference_implementation()
        + f"""
import json
try:
    import recal
except ImportError:
    pass
else:
    raise SystemExit("recal was importable")
doc = json.load(open({str(doc_path)!r}))
raw = json.load(open({str(inputs)!r}))
w, f = calibrate(doc, np.array(raw["N_g"]), np.array(raw["N_a"]), np.array(raw["T"]),
                 np.array(raw["dTdt"]), np.array(raw["t_h"]))
print(json.dumps({{"w": w.tolist(), "f": f.tolist(), "modules": sorted(sys.modules)}}))
"""
    )
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, cwd=tmp_path
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def _relative(got: np.ndarray, want: np.ndarray) -> float:
    return float(np.max(np.linalg.norm(got - want, axis=1) / np.linalg.norm(want, axis=1)))


def test_a_published_file_applied_with_the_page_alone(tmp_path: Path) -> None:
    sim = simulate()
    out = _apply_standalone(tmp_path, published(tmp_path), sim)
    assert not [m for m in out["modules"] if m.split(".")[0] in ("recal", "drivers", "service")]
    assert _relative(np.array(out["w"]), sim["w"]) < 1e-9
    assert _relative(np.array(out["f"]), sim["f"]) < 1e-9


def test_the_standalone_check_can_fail(tmp_path: Path) -> None:
    """A file whose T0 is misread by 1 degC: the check above sees it."""
    sim = simulate()
    path = published(tmp_path)
    doc = json.loads(path.read_text())
    doc["model"]["reference_temperature_c"] += 1.0
    path.write_text(json.dumps(doc))
    out = _apply_standalone(tmp_path, path, sim)
    assert _relative(np.array(out["w"]), sim["w"]) > 1e-7


def test_the_daemons_calibration_records_its_temperature(tmp_path: Path) -> None:
    """A calibration job stores the windows' temperature range with the coefficients, and the
    published file carries it."""
    from recal.model.coefficients import CoefficientSet
    from recal.sim.simulate import simulate_positions
    from recal.solve.options import CalibrationOptions
    from service.gate import GateConfig
    from service.recalibration import calibration_job

    positions = simulate_positions(CoefficientSet.seed_truth(), design="24", seed=4)
    temp = positions.columns["temperature_c"]
    outcome = calibration_job(positions.columns, CalibrationOptions(), None,
                              GateConfig().__dict__)  # fmt: skip
    stored = outcome.document["coefficients"]["metadata"]["calibration_temperature_c"]
    assert stored == {"mean": temp.mean(), "min": temp.min(), "max": temp.max()}
    assert temp.max() > temp.min()  # a range, not one number repeated
    record = CalibrationRecord(version=1, trigger="auto", method="lm", accepted=True,
                               document=outcome.document)  # fmt: skip
    doc = Publisher(tmp_path / "c.json").publish(record)
    assert doc["calibration_temperature_c"] == stored


def test_recal_reads_the_published_file_too(tmp_path: Path) -> None:
    """recal.apply and `recal export` take the published file as any coefficients file."""
    import recal
    from service.cli.main import main

    path = published(tmp_path)
    sim = simulate()
    t = sim["t_h"] * 3600.0
    out = recal.apply(json.loads(path.read_text()), sim["N_g"], sim["N_a"], sim["T"], time_s=t)
    assert _relative(out.accel, sim["f"]) < 1e-9
    assert _relative(out.gyro, sim["w"]) < 1e-9
    assert main(["export", str(path), "--to", "imucal", "-o", str(tmp_path / "i.json")]) == 0
