"""Exports to autopilot parameter files: PX4 (QGroundControl ``.params``) and ArduPilot (``.parm``).

Both read raw samples in m/s^2 and rad/s and correct them per axis, with no misalignment:

- PX4: ``a = (raw - thermal - CAL_ACC0_{X,Y,Z}OFF) * CAL_ACC0_{X,Y,Z}SCALE`` (the calibration
  temperature in ``CAL_ACC0_TEMP``) and
  ``w = raw - thermal - CAL_GYRO0_{X,Y,Z}OFF``; ``thermal = sum_i TC_A0_Xi_j (T - TC_A0_TREF)^i``
  (i = 0..3, axis j = 0..2; T held in [TC_A0_TMIN, TC_A0_TMAX]; gyro: TC_G0_*).
- ArduPilot: ``a = (raw - tcal(T) + tcal(INS_ACC1_CALTEMP) - INS_ACCOFFS_{X,Y,Z}) *
  INS_ACCSCAL_{X,Y,Z}`` and ``w = raw - tcal(T) + tcal(INS_GYR1_CALTEMP) - INS_GYROFFS_{X,Y,Z}``;
  ``tcal(T) = (c1 + (c2 + c3 d) d) d / 1e6`` with ``d = T - 35`` and ``c_k = INS_TCAL1_ACCk_X``
  (gyro: ``INS_TCAL1_GYRk_X``), both temperatures held in [INS_TCAL1_TMIN, INS_TCAL1_TMAX].

From ``N = diag(K) [(I + E) x + b + kT (T - T0)]`` without E: the offset is ``K b`` (raw units),
the accelerometer's scale ``9.80665 / K``, the linear temperature coefficient ``K kT`` per degC.
The gyro has no scale factor in either: the raw output is read as rad/s, and what that costs is
stated with what else is not carried (:mod:`recal.export.losses`). The sensor's ID parameters
are left out: loading the file keeps the IDs the vehicle has.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from recal.errors import RecalInputError
from recal.export.losses import Loss, losses
from recal.model.coefficients import CoefficientSet
from recal.model.reference import G0_M_S2

#: MAVLink parameter types in a QGroundControl file: float and 32-bit integer.
REAL32, INT32 = 9, 6
#: ArduPilot's reference temperature of its polynomial and the scale of its coefficients.
ARDUPILOT_TREF_C, ARDUPILOT_TCAL_SCALE = 35.0, 1e6
#: The parameters' temperature limits when the calibration's range is not known, degC.
WIDE_RANGE_C = (-40.0, 85.0)
_NOT_CARRIED = ("gyro.scale", "gyro.misalignment", "accel.misalignment", "accel.quadratic",
                "accel.scale_asymmetry", "accel.scale_temperature", "gyro.scale_temperature",
                "gyro.bias_temperature_rate", "gyro.g_sensitivity", "gyro.bias_drift")  # fmt: skip
AXES = "XYZ"


def _parts(cs: CoefficientSet, sensor: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(K, K b, K kT or None) of a triad, in raw units."""
    K = cs.get(f"{sensor}.scale")
    b = cs.get(f"{sensor}.bias")
    kT = cs.get(f"{sensor}.bias_temperature")
    return K, K * (np.zeros(3) if b is None else b), None if kT is None else K * kT


def temperature_range(cs: CoefficientSet) -> tuple[float, float, float]:
    """(calibration temperature, min, max), degC: the windows' mean and range from the set's
    metadata, else T0 and :data:`WIDE_RANGE_C`."""
    meta = cs.metadata.get("calibration_temperature_c")
    if isinstance(meta, dict) and meta.get("max", 0) > meta.get("min", 0):
        return float(meta["mean"]), float(meta["min"]), float(meta["max"])
    return cs.t0_c, *WIDE_RANGE_C


def _sensors(cs: CoefficientSet, fmt: str) -> tuple[str, ...]:
    sensors = tuple(s for s in ("accel", "gyro") if cs.get(f"{s}.scale") is not None)
    if not sensors:
        raise RecalInputError(f"--to {fmt} needs gyro or accel coefficients")
    return sensors


def _notes(cs: CoefficientSet, dropped: list[Loss], header: str) -> list[str]:
    tcal, tmin, tmax = temperature_range(cs)
    return [
        header,
        "raw units: the outputs recal calibrated, read by the autopilot as m/s^2 and rad/s",
        f"calibration temperature {tcal:.2f} degC (windows {tmin:.2f} to {tmax:.2f} degC), "
        f"T0 {cs.t0_c:g} degC",
        "sensor ID parameters are not in this file: the vehicle keeps its own",
        *(d.line() for d in dropped),
    ]


def px4(cs: CoefficientSet) -> tuple[dict[str, str], list[Loss]]:
    """A QGroundControl parameter file for accelerometer and gyro instance 0."""
    sensors = _sensors(cs, "px4")
    dropped = losses(cs, _NOT_CARRIED, rate_unit="rad/s", force_unit="m/s^2")
    rows: list[tuple[str, float, int]] = []
    tcal, tmin, tmax = temperature_range(cs)
    for sensor in sensors:
        K, offset, kT = _parts(cs, sensor)
        cal, tc = ("ACC0", "A") if sensor == "accel" else ("GYRO0", "G")
        rows += [(f"CAL_{cal}_{a}OFF", offset[i], REAL32) for i, a in enumerate(AXES)]
        if sensor == "accel":
            rows += [(f"CAL_{cal}_{a}SCALE", G0_M_S2 / K[i], REAL32) for i, a in enumerate(AXES)]
            rows.append((f"CAL_{cal}_TEMP", tcal, REAL32))  # the temperature it was made at
        if kT is not None:
            rows += [(f"TC_{tc}_ENABLE", 1, INT32), (f"TC_{tc}0_TREF", cs.t0_c, REAL32),
                     (f"TC_{tc}0_TMIN", tmin, REAL32), (f"TC_{tc}0_TMAX", tmax, REAL32)]  # fmt: skip
            for power in range(4):
                values = kT if power == 1 else np.zeros(3)
                rows += [(f"TC_{tc}0_X{power}_{j}", values[j], REAL32) for j in range(3)]
    notes = _notes(cs, dropped, "recal export --to px4 (docs/export.md)")
    if any(name.endswith("_ENABLE") for name, _, _ in rows):
        notes.append("thermal compensation applies when TC_A0_ID / TC_G0_ID hold the sensor's "
                     "device ID (the vehicle's CAL_ACC0_ID / CAL_GYRO0_ID)")  # fmt: skip
    lines = [f"# {n}" for n in notes] + ["#", "# Vehicle-Id Component-Id Name Value Type"]
    lines += [f"1\t1\t{name}\t{_number(value, kind)}\t{kind}" for name, value, kind in rows]
    return {"": "\n".join(lines) + "\n"}, dropped


def ardupilot(cs: CoefficientSet) -> tuple[dict[str, str], list[Loss]]:
    """A Mission Planner / MAVProxy parameter file (NAME,VALUE) for IMU 1."""
    sensors = _sensors(cs, "ardupilot")
    dropped = losses(cs, _NOT_CARRIED, rate_unit="rad/s", force_unit="m/s^2")
    tcal, tmin, tmax = temperature_range(cs)
    rows: list[tuple[str, float]] = []
    any_temperature = False
    for sensor in sensors:
        K, offset, kT = _parts(cs, sensor)
        if kT is not None:
            # the polynomial is zero at CALTEMP, the model's term at T0: the offset takes the gap
            offset = offset + kT * (tcal - cs.t0_c)
            any_temperature = True
        name: Callable[[str], str] = (
            (lambda a: f"INS_ACCOFFS_{a}") if sensor == "accel" else (lambda a: f"INS_GYROFFS_{a}")
        )
        rows += [(name(a), offset[i]) for i, a in enumerate(AXES)]
        if sensor == "accel":
            rows += [(f"INS_ACCSCAL_{a}", G0_M_S2 / K[i]) for i, a in enumerate(AXES)]
        short = "ACC" if sensor == "accel" else "GYR"
        rows.append((f"INS_{short}1_CALTEMP", tcal))
        coeff = np.zeros(3) if kT is None else kT * ARDUPILOT_TCAL_SCALE
        for order in (1, 2, 3):
            values = coeff if order == 1 else np.zeros(3)
            rows += [(f"INS_TCAL1_{short}{order}_{a}", values[i]) for i, a in enumerate(AXES)]
    if any_temperature:
        rows = [("INS_TCAL1_ENABLE", 1), ("INS_TCAL1_TMIN", tmin), ("INS_TCAL1_TMAX", tmax), *rows]
    else:
        rows = [(n, v) for n, v in rows if not n.startswith("INS_TCAL1_")]
    notes = _notes(cs, dropped, "recal export --to ardupilot (docs/export.md)")
    lines = [f"# {n}" for n in notes]
    lines += [f"{name},{_number(value, INT32 if name.endswith('ENABLE') else REAL32)}"
              for name, value in rows]  # fmt: skip
    return {"": "\n".join(lines) + "\n"}, dropped


def _number(value: float, kind: int) -> str:
    return str(int(value)) if kind == INT32 else f"{float(value):.9g}"
