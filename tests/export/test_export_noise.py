"""``recal export --to kalibr|ros`` (issue 39, acceptance) on simulated recordings with known
noise: the Kalibr file parses with PyYAML and its four numbers are ``recal noise``'s after the
documented conversion (docs/export.md#noise) and near the simulated truth; the ROS covariances
read back describe the noise of the samples ``recal apply`` calibrates."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import lfilter

from service.cli.main import main

yaml = pytest.importorskip("yaml")

RATE = 100.0
HOLD_S, SWING_S, HOLDS = 40.0, 3.0, 6
#: per-sample white sigma (deg/s for the gyro, m/s^2 for the accel) and a Gauss-Markov wander
WHITE = np.array([0.02, 0.03, 0.025, 0.004, 0.005, 0.006])
GM_SIGMA = np.array([0.05, 0.04, 0.06, 0.01, 0.012, 0.008])
GM_TAU_S = 4.0


def write_recording(path: Path, white: np.ndarray, gm_sigma: np.ndarray, seed: int) -> None:
    """Holds joined by swings, white noise plus a Gauss-Markov process on every axis."""
    rng = np.random.default_rng(seed)
    hold, swing = int(HOLD_S * RATE), int(SWING_S * RATE)
    n = HOLDS * hold + (HOLDS - 1) * swing
    x = white * rng.standard_normal((n, 6))
    phi = math.exp(-1 / (GM_TAU_S * RATE))
    for c in range(6):
        if gm_sigma[c] > 0:
            e = rng.standard_normal(n) * gm_sigma[c] * math.sqrt(1 - phi * phi)
            x[:, c] += lfilter([1.0], [1, -phi], e, zi=[phi * gm_sigma[c] * rng.standard_normal()])[
                0
            ]
    x[:, 5] += 9.8  # gravity on z
    for k in range(HOLDS - 1):
        s = slice(k * (hold + swing) + hold, (k + 1) * (hold + swing))
        x[s] += 5.0 * np.sin(np.linspace(0, 2 * np.pi, swing))[:, None]
    names = ["time_s"] + [f"{s}_{a}" for s in ("gyro", "accel") for a in "xyz"]
    table = np.column_stack([np.arange(n) / RATE, x])
    np.savetxt(path, table, delimiter=",", header=",".join(names), comments="", fmt="%.10g")


def noise_json(tmp: Path, recording: Path, capsys, *flags: str) -> Path:
    assert main(["noise", str(recording), "--format", "csv", "--json", *flags]) == 0
    out = tmp / "noise.json"
    out.write_text(capsys.readouterr().out)
    return out


def coefficients(tmp: Path, gyro_scale: float, accel_scale: float) -> Path:
    """A calibration whose scale factors say what the outputs' units are (per deg/h, per g)."""
    mis = dict.fromkeys(("Exz", "Exy", "Eyz", "Eyx", "Ezy", "Ezx"), 0.0)
    doc = {
        "gyro": {"scale": [gyro_scale] * 3, "bias": [0.0] * 3, "misalignment": mis},
        "accel": {"scale": [accel_scale] * 3, "bias": [0.0] * 3, "misalignment": mis},
    }
    path = tmp / "coeffs.json"
    path.write_text(json.dumps(doc))
    return path


def test_kalibr_noise_is_recal_noise_in_kalibr_units(tmp_path: Path, capsys) -> None:
    rec = tmp_path / "log.csv"
    write_recording(rec, WHITE, GM_SIGMA, seed=3)
    noise = noise_json(tmp_path, rec, capsys, "--units", "gyro=deg/s,accel=m/s^2")
    coeffs = coefficients(tmp_path, 1 / 3600, 9.80665)  # outputs in deg/s and m/s^2
    out = tmp_path / "imu.yaml"
    assert (
        main(["export", str(coeffs), "--to", "kalibr", "--noise", str(noise), "-o", str(out)]) == 0
    )
    imu = yaml.safe_load(out.read_text())
    assert imu["update_rate"] == RATE and imu["rostopic"] == "/imu0"
    axes = json.loads(noise.read_text())["axes"]
    deg = math.radians(1.0)
    # the documented conversion: white N as is; random walk sigma sqrt(2 / tau); x deg -> rad
    white = {a["name"]: a["white"] for a in axes}
    walk = {
        a["name"]: a["gauss_markov_sigma"] * math.sqrt(2 / a["correlation_time_s"]) for a in axes
    }
    want = {
        "gyroscope_noise_density": max(white[f"gyro_{c}"] for c in "xyz") * deg,
        "gyroscope_random_walk": max(walk[f"gyro_{c}"] for c in "xyz") * deg,
        "accelerometer_noise_density": max(white[f"accel_{c}"] for c in "xyz"),
        "accelerometer_random_walk": max(walk[f"accel_{c}"] for c in "xyz"),
    }
    for key, value in want.items():
        assert imu[key] == pytest.approx(value, rel=1e-8), key
    # ... and near the truth that was simulated (the estimates' own scatter allowed)
    truth_white = WHITE / math.sqrt(RATE)
    truth_walk = GM_SIGMA * math.sqrt(2 / GM_TAU_S)
    assert imu["gyroscope_noise_density"] == pytest.approx(truth_white[:3].max() * deg, rel=0.1)
    assert imu["accelerometer_noise_density"] == pytest.approx(truth_white[3:].max(), rel=0.1)
    assert imu["gyroscope_random_walk"] == pytest.approx(truth_walk[:3].max() * deg, rel=0.5)
    assert imu["accelerometer_random_walk"] == pytest.approx(truth_walk[3:].max(), rel=0.5)


def test_kalibr_needs_the_noise(tmp_path: Path, capsys) -> None:
    coeffs = coefficients(tmp_path, 1.0, 1.0)
    assert main(["export", str(coeffs), "--to", "kalibr", "-o", str(tmp_path / "x.yaml")]) == 2
    err = capsys.readouterr().err
    assert "--noise" in err and err.count("\n") == 1
    assert not (tmp_path / "x.yaml").exists()


def test_ros_covariances_are_the_noise_of_the_calibrated_samples(tmp_path: Path, capsys) -> None:
    """Raw counts (no units known to `recal noise`): the calibration's scale turns them into
    rad/s and m/s^2; the covariances read back match the variance of the samples `recal
    apply` calibrates, in the still holds."""
    rec = tmp_path / "log.csv"
    write_recording(rec, WHITE, np.zeros(6), seed=5)  # white only: a covariance says it all
    noise = noise_json(tmp_path, rec, capsys)
    assert all(a["units"] is None for a in json.loads(noise.read_text())["axes"])
    k_g, k_a = 0.5, 2.0  # output units per deg/h and per g
    coeffs = coefficients(tmp_path, k_g, k_a)
    out = tmp_path / "imu_cov.yaml"
    args = ["export", str(coeffs), "--to", "ros", "--noise", str(noise), "-o", str(out)]
    assert main(args) == 0
    cov = yaml.safe_load(out.read_text())
    assert cov["orientation_covariance"][0] == -1
    gyro_cov = np.array(cov["angular_velocity_covariance"]).reshape(3, 3)
    accel_cov = np.array(cov["linear_acceleration_covariance"]).reshape(3, 3)
    assert np.count_nonzero(gyro_cov - np.diag(np.diag(gyro_cov))) == 0
    # apply: the calibrated samples of the first hold, and their variance
    applied = tmp_path / "applied.csv"
    assert main(["apply", str(coeffs), str(rec), "--format", "csv", "--out-units",
                 "gyro=rad/s,accel=m/s^2", "-o", str(applied)]) == 0  # fmt: skip
    t = np.genfromtxt(applied, delimiter=",", names=True)
    hold = slice(int(2 * RATE), int((HOLD_S - 2) * RATE))
    var_g = [np.var(t[f"gyro_{c}_rad_per_s"][hold]) for c in "xyz"]
    var_a = [np.var(t[f"accel_{c}_m_per_s2"][hold]) for c in "xyz"]
    np.testing.assert_allclose(np.diag(gyro_cov), var_g, rtol=0.15)
    np.testing.assert_allclose(np.diag(accel_cov), var_a, rtol=0.15)
    # and the truth: sigma (output units) / K, in rad/s and m/s^2
    truth_g = (WHITE[:3] / k_g * math.radians(1) / 3600) ** 2
    np.testing.assert_allclose(np.diag(gyro_cov), truth_g, rtol=0.15)
    # at another message rate the variance scales with it
    out2 = tmp_path / "imu_cov_10hz.yaml"
    assert main([*args[:-1], str(out2), "--rate", "10"]) == 0
    cov10 = yaml.safe_load(out2.read_text())
    assert cov10["angular_velocity_covariance"][0] == pytest.approx(gyro_cov[0, 0] / 10, rel=1e-6)
