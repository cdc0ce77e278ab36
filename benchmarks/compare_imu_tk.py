"""The Xsens recording calibrated by this project and by imu_tk's published method, side by side.

Run:  python benchmarks/compare_imu_tk.py [--data ../shared/data]

imu_tk (Tedaldi, Pretto, Menegatti, ICRA 2014) ships this very recording as its test data. Its
method, as published (paper and library documentation), re-implemented here from that
description for the comparison (imu_tk itself, C++ with Ceres, is not built here):

* accelerometer: 9 parameters (scale 3, bias 3, misalignment 3 with the lower triangle fixed to
  zero, which fixes the body frame to the accelerometer frame), fitted so that every static
  sample's norm equals a fixed g (unweighted least squares);
* gyro bias: the mean output over the initial still period (the first 3000 samples, 30 s) and
  never re-estimated;
* gyro scale (3) and misalignment (6): for each pair of consecutive static intervals, the gyro
  samples between them are integrated as rotations and the gravity direction of the first
  interval, carried through that rotation, must equal the second one's: residual
  ``R^T u0 - u1`` (3 components per slew), unweighted, Earth's rotation ignored.

This project (``recal positions`` then ``recal calibrate``, no flag): window means with their
noise, the norm and dot-product invariants plus the slew invariant whitened by its own noise
(angle random walk over the slew and the windows' accelerometer noise), the gyro bias from all
the windows, increments integrated relative to the mean output of the slew's two windows (the
bias of a MEMS gyro wanders between windows), a 1-sigma for every coefficient.

Both use the same static windows (this project's detector), so only the estimators differ. The
two fix the common frame differently (imu_tk: triangular accelerometer misalignment; here: the
accelerometer's antisymmetric part), so the table compares what does not depend on it: each gyro
axis's scale (the norm of its column of the calibration matrix, deg/s per count) and the angles
between the gyro axes. Both solutions are then judged on the same slews by the same per-sample
integrator: the angle between the predicted and the measured gravity direction after each slew.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from recal.detect.quaternions import quat_from_rotvec, quat_multiply, rotate_back
from recal.detect.slew_data import Slews
from recal.model.positions import Positions
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions

DEG_S = math.pi / 180.0


def load(data: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    acc = np.loadtxt(data / "xsens_static_poses_acc.txt")
    gyro = np.loadtxt(data / "xsens_static_poses_gyro.txt")
    return acc[:, 0], acc[:, 1:], gyro[:, 1:]


def windows(tmp: Path, data: Path) -> tuple[Positions, Slews]:
    from service.cli.main import main

    out = tmp / "xsens.csv"
    args = [str(data / "xsens_static_poses_acc.txt"), str(data / "xsens_static_poses_gyro.txt")]
    if main(["positions", *args, "--format", "xsens-text", "-o", str(out)]) != 0:
        sys.exit("recal positions failed")
    pos = Positions.from_csv_text(out.read_text())
    slews = Slews.from_npz_bytes((tmp / "xsens.slews.npz").read_bytes())
    return pos, slews


def integrate(gyro_rad_s: list[np.ndarray], dt: float) -> np.ndarray:
    """Quaternions (S, 4) of each slew's rotation, sample by sample (each sample's rate held over
    its period), vectorised over the slews; C(q) maps end-frame to start-frame coordinates."""
    n = max(g.shape[0] for g in gyro_rad_s)
    rates = np.zeros((len(gyro_rad_s), n, 3))
    for k, g in enumerate(gyro_rad_s):
        rates[k, : g.shape[0]] = g
    q = np.tile([1.0, 0.0, 0.0, 0.0], (len(gyro_rad_s), 1))
    for i in range(
        n
    ):  # a loop over samples, vectorised over the slews (a benchmark, not a hot path)
        q = quat_multiply(q, quat_from_rotvec(rates[:, i] * dt))
    return q


def slew_samples(raw: np.ndarray, pos: Positions, t: np.ndarray) -> list[slice]:
    """Sample ranges of each slew: from the end of a window to the start of the next."""
    start, end = pos.columns["start_s"], pos.columns["end_s"]
    lo = np.searchsorted(t - t[0], end[:-1], side="right")
    hi = np.searchsorted(t - t[0], start[1:], side="left")
    return [slice(int(a), int(b)) for a, b in zip(lo, hi, strict=True)]


def imu_tk_accel(acc_means: list[np.ndarray], g: float = 9.81) -> np.ndarray:
    """imu_tk's accelerometer model fitted to the static samples: returns the 9 parameters."""
    samples = np.concatenate(acc_means)

    def model(p: np.ndarray, raw: np.ndarray) -> np.ndarray:
        T = np.array([[1, -p[0], p[1]], [0, 1, -p[2]], [0, 0, 1]])
        return (T @ (p[3:6, None] * (raw - p[6:9]).T)).T

    def res(p: np.ndarray) -> np.ndarray:
        return np.linalg.norm(model(p, samples), axis=1) - g

    # start: a per-axis range fit (the sample extremes give scale and offset)
    lo, hi = samples.min(axis=0), samples.max(axis=0)
    p0 = np.concatenate([[0, 0, 0], 2 * g / (hi - lo), (hi + lo) / 2])
    p = least_squares(res, p0, method="lm").x
    return p


def accel_apply(p: np.ndarray, raw: np.ndarray) -> np.ndarray:
    T = np.array([[1, -p[0], p[1]], [0, 1, -p[2]], [0, 0, 1]])
    return (T @ (p[3:6, None] * (raw - p[6:9]).T)).T


def gyro_matrix(p: np.ndarray) -> np.ndarray:
    """imu_tk's gyro calibration matrix T K (rad/s per count) from its 9 parameters."""
    T = np.array([[1, -p[0], p[1]], [p[3], 1, -p[2]], [-p[4], p[5], 1]])
    return T @ np.diag(p[6:9])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--data", default=str(Path(__file__).resolve().parents[1] / ".." / "shared" / "data")
    )
    args = ap.parse_args()
    data = Path(args.data)
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        pos, slews = windows(Path(tmp), data)
    t, acc_raw, gyro_raw = load(data)
    dt = float(np.median(np.diff(t)))
    ranges = slew_samples(gyro_raw, pos, t)
    start, end = pos.columns["start_s"], pos.columns["end_s"]
    idx = [
        np.flatnonzero((t - t[0] >= a) & (t - t[0] <= b)) for a, b in zip(start, end, strict=True)
    ]

    # ---- this project ------------------------------------------------------------------------
    ours = calibrate(pos, CalibrationOptions(latitude_deg=57.834, slews=slews))
    c = ours.coefficients.values
    from recal.model.terms import MISALIGNMENT_INDEX

    E = np.zeros((3, 3))
    E[tuple(zip(*MISALIGNMENT_INDEX, strict=True))] = c["gyro.misalignment"]
    M_ours = np.linalg.inv(np.eye(3) + E) @ np.diag(1.0 / c["gyro.scale"]) * (DEG_S / 3600.0)
    b_ours = c["gyro.bias"] * c["gyro.scale"]  # counts
    ea = np.zeros((3, 3))
    ea[tuple(zip(*MISALIGNMENT_INDEX, strict=True))] = c["accel.misalignment"]
    Ka, ba = c["accel.scale"], c["accel.bias"]

    def accel_ours(raw: np.ndarray) -> np.ndarray:  # K2 is small; one fixed-point step is enough
        return (np.linalg.inv(np.eye(3) + ea) @ (raw / Ka - ba).T).T

    # ---- imu_tk's method ---------------------------------------------------------------------
    p_acc = imu_tk_accel([acc_raw[i] for i in idx])
    u_tk = np.array([accel_apply(p_acc, acc_raw[i]).mean(axis=0) for i in idx])
    u_tk /= np.linalg.norm(u_tk, axis=1, keepdims=True)
    b_tk = gyro_raw[:3000].mean(axis=0)

    def tk_residuals(p: np.ndarray) -> np.ndarray:
        M = gyro_matrix(p)
        rates = [(gyro_raw[r] - b_tk) @ M.T for r in ranges]
        q = integrate(rates, dt)
        pred = rotate_back(q, u_tk[:-1])
        return (pred - u_tk[1:]).ravel()

    # imu_tk starts from a user-given nominal scale; without one, a coarse log grid over a common
    # scale (1e-4 to 1 deg/s per count) finds the basin the local solver needs
    grid = np.logspace(-4, 0, 41) * DEG_S
    costs = [np.sum(tk_residuals(np.concatenate([np.zeros(6), np.full(3, g)])) ** 2) for g in grid]
    p0 = np.concatenate([np.zeros(6), np.full(3, grid[int(np.argmin(costs))])])
    p_tk = least_squares(tk_residuals, p0, method="lm").x
    M_tk = gyro_matrix(p_tk)

    # ---- the same judge for both -------------------------------------------------------------
    def judge(M: np.ndarray, bias: np.ndarray | None, u: np.ndarray) -> np.ndarray:
        """Angle (deg) between predicted and measured gravity after each slew. bias None: the
        mean output of the slew's two windows is taken as zero rate (this project's choice)."""
        rates = []
        for k, r in enumerate(ranges):
            zero = (
                bias
                if bias is not None
                else 0.5 * (gyro_raw[idx[k]].mean(0) + gyro_raw[idx[k + 1]].mean(0))
            )
            rates.append((gyro_raw[r] - zero) @ M.T)
        pred = rotate_back(integrate(rates, dt), u[:-1])
        return np.degrees(np.arccos(np.clip(np.sum(pred * u[1:], axis=1), -1, 1)))

    u_ours = np.array([accel_ours(acc_raw[i]).mean(axis=0) for i in idx])
    u_ours /= np.linalg.norm(u_ours, axis=1, keepdims=True)
    sd = ours.uncertainty

    def axes(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        scale = np.linalg.norm(M, axis=0) / DEG_S  # deg/s per count, per gyro axis
        n = M / np.linalg.norm(M, axis=0)
        ang = np.degrees(np.arccos([n[:, 0] @ n[:, 1], n[:, 0] @ n[:, 2], n[:, 1] @ n[:, 2]]))
        return scale, ang

    s_o, a_o = axes(M_ours)
    s_t, a_t = axes(M_tk)
    rel_sd = sd["gyro.scale"] / c["gyro.scale"]
    print(f"# Xsens recording: this project against imu_tk's method ({os.cpu_count()} cores)\n")
    print(f"{len(pos)} windows, {len(ranges)} slews (the same for both)\n")
    print("| quantity | this project (1-sigma) | imu_tk's method | difference / sigma |")
    print("|---|---|---|---|")
    for i, ax in enumerate("xyz"):
        d = (s_t[i] - s_o[i]) / (s_o[i] * rel_sd[i])
        print(f"| gyro {ax} scale, mdeg/s per count | {1e3 * s_o[i]:.4f} ({1e3 * s_o[i] * rel_sd[i]:.4f}) "
              f"| {1e3 * s_t[i]:.4f} | {d:+.1f} |")  # fmt: skip
    for k, pair in enumerate(("x-y", "x-z", "y-z")):
        print(f"| angle between gyro axes {pair}, deg | {a_o[k]:.3f} | {a_t[k]:.3f} | - |")
    bias_sd = sd["gyro.bias"] * c["gyro.scale"]
    for i, ax in enumerate("xyz"):
        print(f"| gyro {ax} bias, counts | {b_ours[i]:.1f} ({bias_sd[i]:.1f}) | {b_tk[i]:.1f} "
              f"(first 30 s) | {(b_tk[i] - b_ours[i]) / bias_sd[i]:+.1f} |")  # fmt: skip
    j_o = judge(M_ours, None, u_ours)
    j_t = judge(M_tk, b_tk, u_tk)
    j_t2 = judge(M_tk, None, u_tk)
    print(
        "\n| gravity direction after each slew, predicted vs measured | RMS (deg) | worst (deg) |"
    )
    print("|---|---|---|")
    print(f"| this project | {np.sqrt(np.mean(j_o**2)):.3f} | {j_o.max():.3f} |")
    print(
        f"| imu_tk's method (its bias from the first 30 s) | {np.sqrt(np.mean(j_t**2)):.3f} | {j_t.max():.3f} |"
    )
    print(
        f"| imu_tk's scale and misalignment, windows' mean as zero rate | {np.sqrt(np.mean(j_t2**2)):.3f} | {j_t2.max():.3f} |"
    )
    slew = ours.to_json_dict()["residuals"]["slew"]
    window = slew.get("window_noise_floor", slew["noise_floor"])
    print(f"\nThis project's slew residual: RMS {slew['rms_after']:.2e} rad against the windows' "
          f"noise floor of {window:.2e} rad ({slew['rms_after'] / window:.1f}x); with the "
          f"unmodelled {slew['unmodelled_excess_rad'] * 1e3:.2g} mrad per slew the engine "
          f"estimates from that misfit, {slew['noise_floor']:.2e} rad (slew chi2_red "
          f"{slew.get('chi2_red', float('nan')):.1f}); imu_tk reports no uncertainty and no "
          "residual-to-noise ratio.")  # fmt: skip
    own_fits(pos, slews, ours.chi2_red, rel_sd)


def own_fits(pos: Positions, slews: Slews, chi2_both: float, gyro_scale_rel_sd: np.ndarray) -> None:
    """The README's other figures on this recording: chi2_red of the accelerometer fit with the
    window-mean noise taken as std/sqrt(n) and as the *_sem columns, of the default fit (both
    triads and the slews), and why the gyro alone is not calibrated from Earth rate."""
    from recal.errors import RecalInputError
    from recal.model.positions import ACCEL_SEM_COLUMNS, GYRO_SEM_COLUMNS

    sem = set(ACCEL_SEM_COLUMNS + GYRO_SEM_COLUMNS)
    plain = Positions.from_columns({k: v for k, v in pos.columns.items() if k not in sem})
    opts = {"latitude_deg": 57.834}
    rows = [
        ("accelerometer alone, window noise std/sqrt(n)",
         calibrate(plain, CalibrationOptions(sensor="accel", **opts)).chi2_red),
        ("accelerometer alone, the `*_sem` columns",
         calibrate(pos, CalibrationOptions(sensor="accel", **opts)).chi2_red),
        ("both triads and the slews (the default)", chi2_both),
    ]  # fmt: skip
    print("\n| this project's fit of the recording (--latitude 57.834) | chi2_red |\n|---|---|")
    for label, chi2 in rows:
        print(f"| {label} | {chi2:.1f} |")
    pct = 100 * gyro_scale_rel_sd
    print(f"\nGyro scale 1-sigma with the slews: {pct.min():.2f}-{pct.max():.2f} %.")
    try:
        calibrate(pos, CalibrationOptions(sensor="gyro", **opts))
        print("The gyro alone, without slews: calibrated from Earth rate.")
    except RecalInputError as exc:
        print(f"The gyro alone, without slews: refused: {exc}")


if __name__ == "__main__":
    main()
