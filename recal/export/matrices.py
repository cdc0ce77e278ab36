"""Exports to the tools that apply full matrices: imucal's JSON and imu_tk's text matrices.

Both carry scale, bias and the whole misalignment (docs/export.md); imucal also the gyro's
g-sensitivity. What they cannot carry (the accelerometer's quadratic term, temperature terms,
drift) is listed with its cost (:mod:`recal.export.losses`).

- **imucal** (mad-lab-fau/imucal, Ferraris): ``acc_raw = K_a R_a a + b_a`` and
  ``gyr_raw = K_g R_g w + K_ga a + b_g`` with ``a`` in m/s^2 and ``w`` in deg/s. From
  ``N = diag(K) [(I + E) x + b]``: ``K_a = diag(K / 9.80665)``, ``R = I + E``, ``b_raw = K b``,
  ``K_g = diag(3600 K)``, ``K_ga = diag(K) G / 9.80665``: imucal's own inverse is then this
  project's, exactly.
- **imu_tk** (A. Pretto): ``X' = T K (X - B)``, ``T`` with a unit diagonal, ``K`` diagonal; a file
  per triad holding ``T`` and ``K`` (3x3, row-major) and ``B`` (3 values). With
  ``M = c (I + E)^-1 diag(1 / K)`` (``c`` to m/s^2 or rad/s): ``K_j = M_jj``, ``T = M diag(1 / K)``,
  ``B = K b``.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from recal.errors import RecalInputError
from recal.export.losses import FORCE_FROM_G, RATE_FROM_DEG_H, Loss, losses, one_plus_e
from recal.model.coefficients import CoefficientSet
from recal.model.reference import G0_M_S2

#: The units imucal's calibrated output is in, and the string its raw units are named by
#: (imucal compares the unit a user passes to ``calibrate`` with it).
IMUCAL_ACC_UNIT, IMUCAL_GYR_UNIT, IMUCAL_RAW_UNIT = "m/s^2", "deg/s", "a.u."
#: imu_tk's calibrated output units (the accelerometer's is its gravity magnitude's).
IMU_TK_UNITS = {"accel": "m/s^2", "gyro": "rad/s"}
_NOT_CARRIED = ("accel.quadratic", "accel.scale_asymmetry", "accel.bias_temperature",
                "accel.scale_temperature", "gyro.bias_temperature", "gyro.scale_temperature",
                "gyro.bias_temperature_rate", "gyro.bias_drift")  # fmt: skip


def _need(coefficients: CoefficientSet, sensors: tuple[str, ...], fmt: str) -> None:
    missing = [s for s in sensors if coefficients.get(f"{s}.scale") is None]
    if missing:
        raise RecalInputError(f"--to {fmt} needs {' and '.join(missing)} coefficients too")


def _bias(coefficients: CoefficientSet, sensor: str) -> np.ndarray:
    b = coefficients.get(f"{sensor}.bias")
    return np.zeros(3) if b is None else b


def imucal(coefficients: CoefficientSet) -> tuple[dict[str, str], list[Loss]]:
    """imucal's FerrarisCalibrationInfo JSON (format 2.0.0): {"": text}, and the losses."""
    _need(coefficients, ("gyro", "accel"), "imucal")
    K_a, K_g = coefficients.get("accel.scale"), coefficients.get("gyro.scale")
    G = coefficients.get("gyro.g_sensitivity")
    G = np.zeros((3, 3)) if G is None else G.reshape(3, 3)
    dropped = losses(coefficients, _NOT_CARRIED, rate_unit="deg/s", force_unit="m/s^2")
    doc: dict[str, Any] = {
        "acc_unit": IMUCAL_ACC_UNIT,
        "gyr_unit": IMUCAL_GYR_UNIT,
        "from_acc_unit": IMUCAL_RAW_UNIT,
        "from_gyr_unit": IMUCAL_RAW_UNIT,
        "comment": _comment(dropped),
        "K_a": np.diag(K_a / G0_M_S2).tolist(),
        "R_a": one_plus_e(coefficients, "accel").tolist(),
        "b_a": (K_a * _bias(coefficients, "accel")).tolist(),
        "K_g": np.diag(K_g * 3600.0).tolist(),
        "R_g": one_plus_e(coefficients, "gyro").tolist(),
        "K_ga": (K_g[:, None] * G / G0_M_S2).tolist(),
        "b_g": (K_g * _bias(coefficients, "gyro")).tolist(),
        "cal_type": "Ferraris",
        "_format_version": "2.0.0",
    }
    return {"": json.dumps(doc, indent=4) + "\n"}, dropped


def _comment(dropped: list[Loss]) -> str:
    head = "recal export (docs/export.md): raw units are the outputs recal calibrated"
    return "; ".join([head, *(d.line() for d in dropped)]) if dropped else head


def imu_tk(coefficients: CoefficientSet) -> tuple[dict[str, str], list[Loss]]:
    """imu_tk's CalibratedTriad files: {"acc": text, "gyro": text} for the triads the set has
    (each: T, K, B, then '#' notes that imu_tk's loader never reaches), and the losses."""
    sensors = tuple(s for s in ("accel", "gyro") if coefficients.get(f"{s}.scale") is not None)
    if not sensors:
        raise RecalInputError("--to imu_tk needs gyro or accel coefficients")
    dropped = losses(coefficients, (*_NOT_CARRIED, "gyro.g_sensitivity"), rate_unit="rad/s")
    files = {}
    for sensor in sensors:
        K = coefficients.get(f"{sensor}.scale")
        c = FORCE_FROM_G["m/s^2"] if sensor == "accel" else RATE_FROM_DEG_H["rad/s"]
        M = c * np.linalg.inv(one_plus_e(coefficients, sensor)) / K[None, :]
        k = np.diag(M).copy()
        T = M / k[None, :]
        B = K * _bias(coefficients, sensor)
        lines = [_row(r) for r in T] + [""] + [_row(r) for r in np.diag(k)] + [""]
        lines += [f"{v:.17g}" for v in B] + ["", ""]
        lines.append(f"# recal export --to imu_tk: {sensor}, X' = T K (X - B) gives "
                     f"{IMU_TK_UNITS[sensor]} from the raw outputs recal calibrated")  # fmt: skip
        lines += [f"# {d.line()}" for d in dropped if d.term.startswith(sensor)]
        files["acc" if sensor == "accel" else "gyro"] = "\n".join(lines) + "\n"
    return files, dropped


def _row(values: np.ndarray) -> str:
    return " ".join(f"{v:.17g}" for v in values)
