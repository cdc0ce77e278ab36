"""Write the small example files the README's commands read (run from the project folder).

    python docs/examples/make_examples.py

Every file is simulated from a fixed seed, so running this again gives the same bytes:

* ``log.csv``: an accelerometer-only IMU log with its own column names (``t, ax, ay, az``;
  time in s, specific force in g), 12 random poses held 3 s, joined by 1 s slews, 50 Hz.
* ``log_without_time.csv``: a log in the standard column names without a ``time_s`` column
  (gyro in deg/h, accel in g, temperature in degC), 8 poses held 3 s, 1 s slews, 100 Hz:
  ``recal positions --rate 100`` gives it its time base.
* ``magnetic.csv``: the window means (a positions file, docs/reference.md#positions) of a FOG with a
  Faraday bias F B (F = 0.04, -0.03, 0.05 deg/h per gauss), 36 random positions at 45 deg: the
  out-of-catalogue effect ``faraday_plugin.py`` models (the magnetic case of
  benchmarks/bench_diagnose.py, seed 0).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))

F_TRUE_DPH_PER_GAUSS = (0.04, -0.03, 0.05)


def _write(path: Path, header: list[str], columns: list[np.ndarray], fmt: str) -> None:
    table = np.column_stack(columns)
    np.savetxt(path, table, fmt=fmt, delimiter=",", header=",".join(header), comments="")
    print(f"wrote {path.relative_to(HERE.parents[1])} ({path.stat().st_size / 1e3:.0f} kB)")


def accel_log() -> None:
    """12 poses, accelerometer only, the log's own column names."""
    from recal.sim.session import simulate_session
    from service.capture_sim import kvh_like_truth

    s = simulate_session(kvh_like_truth(1), "random", 12, latitude_deg=50.0, seed=1,
                         rate_hz=50.0, window_s=3.0, slew_s=1.0)  # fmt: skip
    _write(HERE / "log.csv", ["t", "ax", "ay", "az"], [s.time_s, s.accel_out], "%.7g")


def log_without_time() -> None:
    """8 poses, both triads and temperature, standard names, no time column (100 Hz)."""
    from recal.sim.session import simulate_session
    from service.capture_sim import kvh_like_truth

    s = simulate_session(kvh_like_truth(2), "random", 8, latitude_deg=50.0, seed=2,
                         rate_hz=100.0, window_s=3.0, slew_s=1.0)  # fmt: skip
    names = ["gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z", "temperature_c"]
    _write(HERE / "log_without_time.csv", names,
           [s.gyro_out, s.accel_out, s.temperature_c], "%.6g")  # fmt: skip


def magnetic_positions() -> None:
    """Window means of a FOG with the Faraday bias that faraday_plugin.py models."""
    from recal.model.coefficients import CoefficientSet
    from recal.model.plugins import hidden_plugin
    from recal.sim.simulate import design_orientations, simulate_positions
    from service.cli.common import load_plugin

    (term,) = load_plugin(str(HERE / "faraday_plugin.py"))
    seed, latitude = 0, 45.0
    C = design_orientations("random", 36, np.random.default_rng(seed))  # the simulator's draw
    truth = CoefficientSet.seed_truth()
    truth.values["gyro.faraday"] = np.array(F_TRUE_DPH_PER_GAUSS)
    pos = simulate_positions(truth, "random", 36, latitude, seed=seed,
                             hidden=[hidden_plugin(term, C, latitude)])  # fmt: skip
    (HERE / "magnetic.csv").write_text(pos.to_csv_text())
    print(f"wrote docs/examples/magnetic.csv ({len(pos)} positions)")


if __name__ == "__main__":
    accel_log()
    log_without_time()
    magnetic_positions()
