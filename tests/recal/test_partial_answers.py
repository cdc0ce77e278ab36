"""Issue 36, item 5: a coefficient the positions cannot show never refuses the part they show.

Two poses, x up then x down (a ring-laser IMU recorded so, public, MIT; ``../shared/data/
two-poses`` reproduces it), show the accelerometer's x scale factor and bias and nothing else.
Without a prior the unseen gyro biases carried a default 1-sigma of 1.8e3 deg/h, more than any
unit can be off, and the whole answer was refused. Now such a held coefficient is held at its
physical bound, and the estimated part is reported and written; a nonsensical estimate is still
refused (tests/recal/test_held_and_believable.py).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from recal.model.reference import OMEGA_IE_DEG_H, normal_gravity_g
from service.cli.main import main

COLUMNS = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")


def _flat(doc: dict, what: str) -> dict[str, float]:
    out = {}
    for sensor in ("gyro", "accel"):
        for term, values in doc[what][sensor].items():
            if isinstance(values, list):
                for axis, v in zip("xyz", values, strict=False):
                    out[f"{sensor}.{term}.{axis}"] = v
    return out


def _calibrate(path, tmp_path, capsys, latitude: float) -> tuple[dict, object]:
    out = tmp_path / "coefficients.json"
    capsys.readouterr()
    rc = main(["calibrate", str(path), "--latitude", f"{latitude:g}", "--json", "-o", str(out)])
    assert rc == 0, capsys.readouterr().err
    doc = json.loads(capsys.readouterr().out)
    assert out.exists() and "accel" in json.loads(out.read_text())
    return doc, out


def _check(doc: dict, truth: dict, g_truth: float, g_assumed: float) -> None:
    status, value, sigma = (
        _flat(doc, "status"),
        _flat(doc, "coefficients"),
        _flat(doc, "uncertainty"),
    )
    estimated = {k for k, s in status.items() if s == "estimated"}
    assert estimated == {"accel.scale.x", "accel.bias.x"}, estimated
    # the truth in the calibration's own terms: a scale read against the gravity it assumes
    kx = truth["accel"]["scale"][0] * g_truth / g_assumed
    bx = truth["accel"]["bias"][0] * g_truth / g_assumed
    for name, t in (("accel.scale.x", kx), ("accel.bias.x", bx)):
        assert abs(value[name] - t) <= 3 * sigma[name], (name, value[name], t, sigma[name])
    # the held ones stand at the prior with a 1-sigma that says something: the gyro biases at
    # most Earth rate (their physical bound), and the note says so
    for axis in "xyz":
        assert 0 < sigma[f"gyro.bias.{axis}"] <= OMEGA_IE_DEG_H * (1 + 1e-9)
    assert any("physical bound" in n for n in doc["notes"])


def test_the_shared_two_pose_case_is_a_partial_answer_and_is_written(shared_data, tmp_path, capsys):
    case = shared_data / "two-poses"
    meta = json.loads((case / "truth.json").read_text())
    doc, _ = _calibrate(case / "positions.csv", tmp_path, capsys, meta["latitude"])
    # the case was made with 1 g of gravity; the calibration assumes the normal gravity at 40 deg
    _check(doc, meta["truth"], 1.0, normal_gravity_g(meta["latitude"]))


def _two_poses(rng: np.random.Generator, lat: float, gyro_noise_dph: float) -> tuple[str, dict]:
    """Window means of x up then x down at a random heading (a ring-laser IMU's noise level):
    seed model with diagonal scale, bias, no misalignment."""
    truth = {
        "gyro": {"scale": list(1 + 3e-4 * rng.normal(size=3)), "bias": list(rng.normal(0, 3, 3))},
        "accel": {"scale": list(1 + 5e-4 * rng.normal(size=3)),
                  "bias": list(rng.normal(0, 2e-3, 3))},
    }  # fmt: skip
    g = normal_gravity_g(lat)
    w_up, w_north = (
        OMEGA_IE_DEG_H * math.sin(math.radians(lat)),
        OMEGA_IE_DEG_H * math.cos(math.radians(lat)),
    )
    h = rng.uniform(0, 2 * math.pi)
    rows = []
    n, accel_std = 19200, 5e-4
    for sign, t0 in ((1.0, 0.0), (-1.0, 420.0)):
        # body x along +-up; body y and z horizontal at heading h (z = x cross y)
        w = np.array([sign * w_up, w_north * math.cos(h), sign * w_north * math.sin(h)])
        f = np.array([sign * g, 0.0, 0.0])
        gyro = np.array(truth["gyro"]["scale"]) * (w + truth["gyro"]["bias"])
        accel = np.array(truth["accel"]["scale"]) * (f + truth["accel"]["bias"])
        gyro = gyro + rng.normal(0, gyro_noise_dph / math.sqrt(n), 3)
        accel = accel + rng.normal(0, accel_std / math.sqrt(n), 3)
        std = [gyro_noise_dph] * 3 + [accel_std] * 3
        rows.append([t0, t0 + 300.0, n, *gyro, *accel, *std])
    head = (
        "start_s,end_s,samples," + ",".join(COLUMNS) + "," + ",".join(f"{c}_std" for c in COLUMNS)
    )
    return head + "\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n", truth


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_simulated_two_pose_recordings_give_the_same_partial_answer(seed, tmp_path, capsys):
    rng = np.random.default_rng(seed)
    lat = float(rng.uniform(-60, 60))
    text, truth = _two_poses(rng, lat, gyro_noise_dph=float(rng.uniform(50, 300)))
    path = tmp_path / "positions.csv"
    path.write_text(text)
    doc, _ = _calibrate(path, tmp_path, capsys, lat)
    g = normal_gravity_g(lat)
    _check(doc, truth, g, g)
