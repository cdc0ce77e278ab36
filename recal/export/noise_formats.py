"""Exports of the noise `recal noise --json` measured: Kalibr's ``imu.yaml`` and the three
covariances of ROS ``sensor_msgs/Imu``.

Units (docs/export.md#noise). ``recal noise`` gives per axis the white level ``N`` (angle or
velocity random walk) in output units x sqrt(s), with AVAR(tau) = N^2 / tau, and the bias
wander as a Gauss-Markov process (``gauss_markov_sigma``, ``correlation_time_s``) or, where none
shows, the bias instability B at its averaging time tau_B. Output units become physical ones by
the axis's ``units`` when ``recal noise`` knew them, else by dividing by the calibration's scale
factor K (output units per deg/h or per g). Then:

- Kalibr's ``*_noise_density`` is N, in rad/s/sqrt(Hz) and m/s^2/sqrt(Hz) (the continuous-time
  density: the same number);
- Kalibr's ``*_random_walk`` (bias diffusion, rad/s^2/sqrt(Hz) and m/s^3/sqrt(Hz)) is the
  Gauss-Markov process's driving density ``sigma sqrt(2 / tau)`` (it grows like that random walk
  for times shorter than tau), else ``B sqrt(3 / tau_B)``, the random walk whose Allan deviation
  at tau_B is B;
- one value per sensor: the largest of the three axes (Kalibr takes a scalar);
- a ROS covariance is the per-sample variance at the message rate f, ``N^2 f``, on the diagonal
  (row-major 3x3); ``orientation_covariance[0] = -1``: no orientation.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from recal.errors import RecalInputError
from recal.export.losses import FORCE_FROM_G, RATE_FROM_DEG_H
from recal.model.coefficients import CoefficientSet

#: Physical units ``recal noise`` names -> (triad, factor to rad/s or m/s^2).
_SI = {
    "deg/h": ("gyro", RATE_FROM_DEG_H["rad/s"]),
    "deg/s": ("gyro", math.radians(1.0)),
    "rad/s": ("gyro", 1.0),
    "g": ("accel", FORCE_FROM_G["m/s^2"]),
    "m/s^2": ("accel", 1.0),
}


def axis_noise_si(
    noise: Mapping[str, Any], coefficients: CoefficientSet | None
) -> dict[str, dict[str, Any]]:
    """Per triad present with its three axes: white density (SI x sqrt(s)), random walk (SI /
    sqrt(s)) per axis, and where each came from."""
    axes = noise.get("axes")
    if not isinstance(axes, list):
        raise RecalInputError("noise file: no 'axes' list (give `recal noise --json` output)")
    out: dict[str, dict[str, Any]] = {}
    for triad in ("gyro", "accel"):
        rows = {a.get("name"): a for a in axes if str(a.get("name", "")).startswith(triad + "_")}
        if set(rows) != {f"{triad}_{c}" for c in "xyz"}:
            continue
        white, walk, how = np.zeros(3), np.zeros(3), []
        for i, c in enumerate("xyz"):
            a = rows[f"{triad}_{c}"]
            factor = _to_si(a, triad, i, coefficients)
            white[i] = float(a["white"]) * factor
            walk[i], source = _random_walk(a)
            walk[i] *= factor
            how.append(source)
        out[triad] = {"white": white, "random_walk": walk, "sources": how}
    if not out:
        raise RecalInputError("noise file: no triad with all three axes")
    return out


def _to_si(axis: Mapping[str, Any], triad: str, i: int, cs: CoefficientSet | None) -> float:
    unit = axis.get("units")
    if unit in _SI and _SI[unit][0] == triad:
        return _SI[unit][1]
    K = None if cs is None else cs.get(f"{triad}.scale")
    if K is None:
        raise RecalInputError(
            f"noise file: {axis.get('name')} is in output units and the coefficients have no "
            f"{triad}.scale to turn them into physical ones (run `recal noise --units ...`)"
        )
    per_unit = RATE_FROM_DEG_H["rad/s"] if triad == "gyro" else FORCE_FROM_G["m/s^2"]
    return per_unit / float(K[i])


def _random_walk(axis: Mapping[str, Any]) -> tuple[float, str]:
    sigma, tau = axis.get("gauss_markov_sigma"), axis.get("correlation_time_s")
    if sigma and tau:
        return float(sigma) * math.sqrt(2.0 / float(tau)), "gauss-markov sigma sqrt(2/tau)"
    b, tau_b = axis.get("bias_instability"), axis.get("bias_instability_tau_s")
    if b and tau_b:
        bound = " (an upper bound)" if axis.get("bias_instability_upper_bound") else ""
        return float(b) * math.sqrt(3.0 / float(tau_b)), "bias instability B sqrt(3/tau_B)" + bound
    raise RecalInputError(f"noise file: {axis.get('name')} has no bias wander to convert")


def kalibr(
    noise: Mapping[str, Any], coefficients: CoefficientSet | None, topic: str = "/imu0"
) -> str:
    """Kalibr's imu.yaml text (both triads needed)."""
    si = axis_noise_si(noise, coefficients)
    if set(si) != {"gyro", "accel"}:
        raise RecalInputError("--to kalibr needs the noise of both gyro and accel axes")
    rate = noise.get("sample_rate_hz")
    if not rate:
        raise RecalInputError("noise file: no sample_rate_hz")
    g, a = si["gyro"], si["accel"]
    lines = [
        "# recal export --to kalibr (docs/export.md#noise): from `recal noise --json`",
        "# noise density = the white level N (AVAR = N^2/tau); random walk = "
        + ", ".join(sorted(set(g["sources"] + a["sources"]))),
        "# the largest of the three axes; per axis (x, y, z):",
        f"#   gyro white {_v(g['white'])} rad/s/sqrt(Hz), random walk {_v(g['random_walk'])} "
        "rad/s^2/sqrt(Hz)",
        f"#   accel white {_v(a['white'])} m/s^2/sqrt(Hz), random walk {_v(a['random_walk'])} "
        "m/s^3/sqrt(Hz)",
        "# not carried: the deterministic calibration (Kalibr's imu.yaml has none): feed Kalibr "
        "data already corrected by `recal apply`",
        f"rostopic: {topic}",
        f"update_rate: {float(rate):.9g}  # Hz",
        f"accelerometer_noise_density: {a['white'].max():.9g}  # m/s^2/sqrt(Hz)",
        f"accelerometer_random_walk: {a['random_walk'].max():.9g}  # m/s^3/sqrt(Hz)",
        f"gyroscope_noise_density: {g['white'].max():.9g}  # rad/s/sqrt(Hz)",
        f"gyroscope_random_walk: {g['random_walk'].max():.9g}  # rad/s^2/sqrt(Hz)",
    ]
    return "\n".join(lines) + "\n"


def _v(values: np.ndarray) -> str:
    return ", ".join(f"{v:.4g}" for v in values)


def ros(
    noise: Mapping[str, Any], coefficients: CoefficientSet | None, rate_hz: float | None = None
) -> str:
    """The three row-major covariances of sensor_msgs/Imu, as YAML, at ``rate_hz`` (default:
    the rate the noise was measured at)."""
    si = axis_noise_si(noise, coefficients)
    rate = rate_hz or noise.get("sample_rate_hz")
    if not rate or not float(rate) > 0:
        raise RecalInputError("no message rate: give --rate HZ (the rate the driver publishes)")
    rate = float(rate)
    lines = [
        "# recal export --to ros (docs/export.md#noise): sensor_msgs/Imu covariances, row-major",
        f"# per-sample variance N^2 f of the white noise at f = {rate:.9g} Hz (the message "
        "rate: averaging or decimating changes it)",
        "# not carried: the bias wander and the calibration's own 1-sigma, which are not white "
        "(model them as bias states in the filter); orientation: none (-1)",
        "orientation_covariance: " + _matrix(None),
    ]
    for triad, key, unit in (("gyro", "angular_velocity_covariance", "(rad/s)^2"),
                             ("accel", "linear_acceleration_covariance", "(m/s^2)^2")):  # fmt: skip
        if triad in si:
            lines.append(f"{key}: {_matrix(si[triad]['white'] ** 2 * rate)}  # {unit}")
        else:
            lines.append(f"{key}: {_matrix(None)}  # no {triad} noise measured")
    return "\n".join(lines) + "\n"


def _matrix(diagonal: np.ndarray | None) -> str:
    values = [-1.0] + [0.0] * 8 if diagonal is None else list(np.diag(diagonal).reshape(9))
    return "[" + ", ".join(f"{v:.9g}" for v in values) + "]"
