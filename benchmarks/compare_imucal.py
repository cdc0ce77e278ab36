"""This project against imucal's own Ferraris calibrations of two real MEMS sessions
(../shared/data/imucal): scale factors in ppm of imucal's, with this project's 1-sigma, as a user
would run it (flags: --columns and --rate only; the Ferraris session also with its turns declared
closed, --turn-closure 0.1), plus chi2_red, convergence and the fixed point (the calibration's own
output as --prior).

    python benchmarks/compare_imucal.py

imucal's calibration is converted with recal.model.imucal (its K R, its 9.81 m/s^2, its deg/s). Both
fits assume the same latitude (45 deg, calibrate's default), which then cancels.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from recal.model.imucal import coefficients_from_imucal
from recal.model.reference import normal_gravity_g
from service.cli.main import main

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "imucal"
COLUMNS = "gyro_x=gyr_x,gyro_y=gyr_y,gyro_z=gyr_z,accel_x=acc_x,accel_y=acc_y,accel_z=acc_z"


def run(args: list[str]) -> dict:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        rc = main([*args, "--json"] if args[0] != "positions" else args)
    if rc != 0:
        raise SystemExit(f"recal {' '.join(args)}: exit {rc}")
    return json.loads(out.getvalue()) if args[0] != "positions" else {}


def annotated_recording(d: Path) -> Path:
    """The annotated session in time order (rows grouped by part; time = samples / 204.8)."""
    rows = sorted(csv.DictReader(open(SHARED / "annotated_session.csv")),
                  key=lambda r: int(r["samples"]))  # fmt: skip
    path = d / "annotated.csv"
    keys = ("acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z")
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time_s", *keys])
        for r in rows:
            w.writerow([int(r["samples"]) / 204.8, *(r[k] for k in keys)])
    return path


def row(label: str, doc: dict, ref, sensor: str) -> str:
    k = np.array(doc["coefficients"][sensor]["scale"])
    sd = np.array(doc["uncertainty"][sensor]["scale"])
    off = (k / ref.values[f"{sensor}.scale"] - 1) * 1e6
    z = off / (sd / k * 1e6)
    cells = " / ".join(f"{v:+.0f}" for v in off)
    sig = " / ".join(f"{v:.0f}" for v in sd / k * 1e6)
    return f"| {label} | {sensor} | {cells} | {sig} | {np.max(np.abs(z)):.2f} |"


def main_() -> int:
    if not SHARED.is_dir():
        print(f"{SHARED} not found", file=sys.stderr)
        return 2
    g = normal_gravity_g(45.0)
    lines = ["| session | triad | scale off imucal's, x / y / z (ppm) | 1-sigma (ppm) | worst |z| |",
             "|---|---|---|---|---|"]  # fmt: skip
    notes = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        ann_pos = d / "annotated_pos.csv"
        run(["positions", str(annotated_recording(d)), "--format", "csv", "--columns", COLUMNS,
             "-o", str(ann_pos)])  # fmt: skip
        ref = coefficients_from_imucal(json.loads((SHARED / "annotated_session.imucal_cal.json")
                                                  .read_text()), g)  # fmt: skip
        doc = run(["calibrate", str(ann_pos), "--sensor", "accel"])
        lines.append(row("annotated (6 faces)", doc, ref, "accel"))
        notes.append(f"annotated, accelerometer: {doc['positions']} windows, held-coefficient "
                     f"prior class {doc['held_uncertainty']['sensor_class']}")  # fmt: skip
        fer_pos = d / "ferraris_pos.csv"
        run(["positions", str(SHARED / "example_ferraris_session.csv"), "--format", "csv",
             "--rate", "102.4", "--columns", COLUMNS, "-o", str(fer_pos)])  # fmt: skip
        ref = coefficients_from_imucal(json.loads((SHARED / "example_ferraris_session"
                                                   ".imucal_cal.json").read_text()), g)  # fmt: skip
        # the default: a MEMS gyro cannot check its turns' closure by Earth rate, so none is
        # assumed; the Ferraris protocol's three 360-degree turns declared closed to 0.1 deg
        plain = run(["calibrate", str(fer_pos)])
        lines.append(row("Ferraris, turns not declared (default)", plain, ref, "gyro"))
        lines.append(row("Ferraris, turns not declared (default)", plain, ref, "accel"))
        closed = ["--turn-closure", "0.1"]
        first = d / "first.json"
        doc = run(["calibrate", str(fer_pos), *closed, "-o", str(first)])
        lines.append(row("Ferraris, turns declared (--turn-closure 0.1)", doc, ref, "gyro"))
        lines.append(row("Ferraris, turns declared (--turn-closure 0.1)", doc, ref, "accel"))
        for label, x in (("not declared", plain), ("declared", doc)):
            held = [f"{s}.{k}" for s in ("gyro", "accel") for k, v in x["status"][s].items()
                    if "held" in (v.values() if isinstance(v, dict) else v)]  # fmt: skip
            gb = np.array(x["coefficients"]["gyro"]["bias"]) - ref.values["gyro.bias"]
            gs = np.array(x["uncertainty"]["gyro"]["bias"])
            notes.append(f"Ferraris, turns {label}: chi2_red {x['chi2_red']:.2f}; gyro bias off "
                         f"imucal's {' / '.join(f'{v:+.1f}' for v in gb)} deg/h (1-sigma "
                         f"{' / '.join(f'{v:.1f}' for v in gs)}); held: "
                         f"{', '.join(held) or 'none'}")  # fmt: skip
        again = run(["calibrate", str(fer_pos), *closed, "--prior", str(first)])
        moved = max(
            float(np.max(np.abs(np.array(again["coefficients"][s][k])
                                - np.array(doc["coefficients"][s][k]))
                         / np.array(doc["uncertainty"][s][k])))
            for s in ("gyro", "accel") for k in ("scale", "bias")
        )  # fmt: skip
        notes.append(f"Ferraris, turns declared: converged {doc['converged']}; "
                     f"its own output as --prior: chi2_red {again['chi2_red']:.2f}, largest "
                     f"scale/bias change {moved:.3f} sigma")  # fmt: skip
    print("# This project against imucal's Ferraris calibrations (../shared/data/imucal)\n")
    print("\n".join(lines))
    print()
    for n in notes:
        print(f"- {n}")
    print(
        "\ntargets: accelerometer scale within 3 sigma + 50 ppm; gyro scale within 1000 ppm "
        "(with the turns declared closed)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main_())
