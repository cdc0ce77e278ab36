"""HTML reports: self-contained pages with labelled matplotlib charts, for calibrate, diagnose and
positions; each command prints the report's path on stderr (stdout stays clean for --json)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from recal.detect.floor import estimate_noise_floor
from recal.detect.static_config import DetectorConfig
from recal.detect.static_detector import StaticDetector
from recal.model.coefficients import CoefficientSet
from recal.model.positions import Positions
from recal.model.terms import catalogue_terms
from recal.report.positions import RecordingEnvelope, TraceEnvelope, positions_html
from recal.sim.session import simulate_session
from recal.sim.simulate import TemperatureSpec, simulate_positions
from service.capture_sim import kvh_like_truth
from service.cli.main import main

ACC = "xsens_static_poses_acc.txt"
GYRO = "xsens_static_poses_gyro.txt"
EXTERNAL = re.compile(r"""(?:src|href)\s*=\s*["']?\s*(?:https?:)?//""", re.IGNORECASE)


def assert_self_contained(page: str) -> None:
    assert page.startswith("<!doctype html>") and page.rstrip().endswith("</html>")
    assert not EXTERNAL.search(page), EXTERNAL.search(page).group(0)
    assert "<script" not in page and "<link" not in page and "<img" not in page


def window_patches(page: str, panel: int = 0) -> int:
    """Rectangles in the group of static windows the positions chart draws on one panel."""
    m = re.search(rf'<g id="static-windows-{panel}">(.*?)</g>', page, re.DOTALL)
    return m.group(1).count("<path") if m else 0  # matplotlib writes no empty group


# ---- calibrate and diagnose -------------------------------------------------------------------
@pytest.fixture(scope="module")
def hidden_temperature_csv(tmp_path_factory):
    """36 positions with a temperature swing and a hidden gyro bias temperature coefficient."""
    truth = CoefficientSet.seed_truth()
    truth.values["gyro.bias_temperature"] = np.array([0.004, -0.003, 0.002])
    swing = TemperatureSpec(start_c=15.0, slope_c_per_h=4.0, swing_c=8.0, period_h=0.7)
    pos = simulate_positions(truth, "random", 36, 40.0, seed=7, temperature=swing,
                             hidden=[catalogue_terms()["gyro.bias_temperature"]])  # fmt: skip
    path = tmp_path_factory.mktemp("reports") / "pos.csv"
    path.write_text(pos.to_csv_text())
    return path


def test_calibrate_report_has_labelled_charts_and_prints_its_path(
    hidden_temperature_csv, tmp_path, capsys
):
    report = tmp_path / "cal.html"
    args = ["calibrate", str(hidden_temperature_csv), "--latitude", "40", "--json"]
    assert main([*args, "--report", str(report)]) == 0
    out, err = capsys.readouterr()
    json.loads(out)  # stdout: the JSON object alone
    assert f"wrote the report to {report}" in err
    page = report.read_text()
    assert_self_contained(page)
    assert page.count("<svg") == 4  # gyro norm, accel norm, dot, singular values
    for label in ("position number", "residual [deg/h]", "residual [g]", "noise band",
                  "prior", "calibrated", "direction number", "singular value"):  # fmt: skip
        assert label in page, label
    assert "<table>" in page and "gyro.bias.bx" in page  # the coefficient table is kept
    # the unmodelled temperature effect leaves the calibrated gyro residual far above noise: no
    # zoom; a tick label is text in the SVG (not a path), so the axes can be read and searched
    assert re.search(r"<text[^>]*>[^<]*0\.0[0-9]", page)


def test_diagnose_report_shows_residual_against_each_driver(
    hidden_temperature_csv, tmp_path, capsys
):
    report = tmp_path / "diag.html"
    args = ["diagnose", str(hidden_temperature_csv), "--latitude", "40", "--json"]
    assert main([*args, "--report", str(report)]) == 0
    out, err = capsys.readouterr()
    doc = json.loads(out)
    assert doc["suggested_effects"][0] == "gyro.bias_temperature"
    assert f"recal diagnose: wrote the report to {report}" in err
    page = report.read_text()
    assert_self_contained(page)
    assert "Residual against what drives each candidate" in page
    for label in ("temperature [degC]", "temperature rate [degC/h]", "session time",
                  "specific force x [g]", "with gyro.bias_temperature", "current model",
                  "noise floor", "gyro_norm residual"):  # fmt: skip
        assert label in page, label
    # the suggested model reaches the noise: its residual gets a zoomed panel
    assert "with gyro.bias_temperature, zoomed" in page
    assert "<table>" in page and "delta BIC" in page


# ---- positions ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def session():
    return simulate_session(kvh_like_truth(3), "24", latitude_deg=50.0, rate_hz=100.0,
                            window_s=4.0, slew_s=2.0, seed=2)  # fmt: skip


def test_positions_report_shades_one_rectangle_per_window(session, tmp_path, capsys):
    log = tmp_path / "log.csv"
    names = ["time_s", *(f"{s}_{a}" for s in ("gyro", "accel") for a in "xyz"), "temperature_c"]
    table = np.column_stack((session.time_s, session.gyro_out, session.accel_out,
                             session.temperature_c))  # fmt: skip
    np.savetxt(log, table, delimiter=",", header=",".join(names), comments="", fmt="%.12g")
    out, report = tmp_path / "pos.csv", tmp_path / "pos.html"
    rc = main(["positions", str(log), "--format", "csv", "--report", str(report), "-o", str(out)])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert f"recal positions: wrote the report to {report}" in err
    n = len(Positions.from_csv_text(out.read_text()))
    assert n == session.n_holds == 24
    page = report.read_text()
    assert_self_contained(page)
    assert page.count("<svg") == 1 and f'data-windows="{n}"' in page
    panels = len(re.findall(r'<g id="static-windows-\d+">', page))
    assert panels == 5  # accel and gyro moving variance, gyro, accel, temperature
    assert all(window_patches(page, k) == n for k in range(panels))
    for label in ("accel moving", "gyro moving", "threshold", "noise floor",
                  "time from the start of the recording [s]", "temperature", "gyro x",
                  f"static window ({n})"):  # fmt: skip
        assert label in page, label
    assert page.count("<tr><td>") == n  # the windows table, no rejected stretch


def test_positions_report_marks_rejected_stretches_by_reason(session):
    """Holes of invalid frames inside holds: the pieces they cut too short are marked."""
    valid = np.ones(len(session), dtype=bool)
    for a in session.hold_first[::3]:  # 4 s holds at 100 Hz; about 300 quiet frames each
        valid[a + 110 : a + 130] = False  # leaves 60 quiet frames before (too few), 220 after
    floor = estimate_noise_floor(session.time_s, session.gyro_out, session.accel_out)
    env = RecordingEnvelope(max_points=200)
    det = StaticDetector(DetectorConfig(noise_floor=floor), on_traces=env.on_traces)
    windows = det.feed(session.time_s, session.gyro_out, session.accel_out,
                       session.temperature_c, valid) + det.flush()  # fmt: skip
    rep = det.report
    assert rep.rejected["invalid_status"] == 8
    assert len(rep.rejected_stretches) == sum(rep.rejected.values())
    for start, end, why in rep.rejected_stretches:
        assert why == "invalid_status" and 0.3 < end - start < 0.7
        assert np.any(np.abs(session.hold_start_s + 1.1 - end) < 0.05)  # ends at the hole
    page = positions_html(env, rep, windows, units={"gyro": "deg/h", "accel": "g"})
    assert_self_contained(page)
    assert 'data-rejected="8"' in page and "rejected: invalid status (8)" in page
    m = re.search(r'<g id="rejected-invalid_status-0">(.*?)</g>', page, re.DOTALL)
    assert m and m.group(1).count("<path") == 8
    assert window_patches(page) == len(windows) == 24


def test_positions_report_when_no_window_is_found(session, tmp_path, capsys):
    """The report is written (it shows why) and named, then the one-line error."""
    log = tmp_path / "log.csv"
    cols = np.column_stack((session.time_s, session.gyro_out, session.accel_out))
    np.savetxt(log, cols, delimiter=",", comments="", fmt="%.12g",
               header="time_s,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z")  # fmt: skip
    report = tmp_path / "none.html"
    rc = main(["positions", str(log), "--format", "csv", "--min-duration", "100",
               "--report", str(report), "-o", str(tmp_path / "p.csv")])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 2 and "no static window found" in err and str(report) in err
    page = report.read_text()
    assert 'data-windows="0"' in page and "too short" in page
    assert window_patches(page) == 0


def test_xsens_recording_report(shared_data, tmp_path, capsys):
    out, report = tmp_path / "xsens.csv", tmp_path / "xsens.html"
    rc = main(["positions", str(shared_data / ACC), str(shared_data / GYRO), "--format",
               "xsens-text", "--no-slews", "--report", str(report), "-o", str(out)])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 0, err
    assert err.rstrip().endswith(f"recal positions: wrote the report to {report}")
    page = report.read_text()
    assert_self_contained(page)
    assert 'data-windows="38"' in page and window_patches(page) == 38
    assert "[(counts)²]" in page and "accel\n[counts]" not in page  # units named on the axes
    assert len(page) < 3_000_000  # an envelope, not every sample


# ---- the envelope -----------------------------------------------------------------------------
def test_envelope_is_bounded_exact_and_independent_of_chunking():
    rng = np.random.default_rng(1)
    n = 100_003
    t = np.arange(n) / 100.0
    v = rng.normal(size=(n, 2))
    v[rng.integers(0, n, 500), 1] = np.nan  # invalid frames are left out
    whole = TraceEnvelope(("a", "b"), max_points=100)
    whole.feed(t, v)
    pieces = TraceEnvelope(("a", "b"), max_points=100)
    cuts = np.sort(rng.integers(0, n, 40))
    for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, n], strict=True):
        pieces.feed(t[lo:hi], v[lo:hi])
    a, b = whole.result(), pieces.result()
    assert 100 <= a["time_s"].size <= 201 and whole.frames_per_bucket == 512
    for key in a:
        np.testing.assert_allclose(a[key], b[key], rtol=1e-12, equal_nan=True)
    assert a["a_min"].min() == v[:, 0].min() and a["a_max"].max() == v[:, 0].max()
    assert np.nanmax(a["b_max"]) == np.nanmax(v[:, 1])
    b_per = 512
    np.testing.assert_allclose(a["a_mean"][0], v[:b_per, 0].mean(), rtol=1e-12)
