"""``recal navigate`` (and ``recal simulate --trajectory``): JSON contract, report, truth
comparison, KVH input, and one-line errors with exit code 2 for bad input."""

from __future__ import annotations

import json

import pytest

from service.cli.main import main


def _run(capsys, *args) -> tuple[int, str, str]:
    rc = main([str(a) for a in args])
    out = capsys.readouterr()
    return rc, out.out, out.err


@pytest.fixture(scope="module")
def static_files(tmp_path_factory):
    """A noiseless 20 min static csv recording at 10 Hz, its truth and an 'old' set."""
    d = tmp_path_factory.mktemp("nav")
    rc = main(
        ["simulate", "--trajectory", "static", "--duration", "1200", "--rate", "10", "--arw",
         "0", "--vrw", "0", "--attitude", "1,-2,40", "--recording", str(d / "rec.csv"),
         "--truth-out", str(d / "truth.json")]
    )  # fmt: skip
    assert rc == 0
    doc = json.loads((d / "truth.json").read_text())
    doc["gyro"]["bias"][0] += 0.02  # an aged north-ish gyro bias
    (d / "old.json").write_text(json.dumps(doc))
    return d


def test_json_runs_best_first_with_the_contract_keys(static_files, capsys):
    d = static_files
    rc, out, err = _run(
        capsys, "navigate", d / "rec.csv", "--format", "csv", "--coefficients", d / "old.json",
        "--coefficients", d / "truth.json", "--latitude", "45", "--json",
    )  # fmt: skip
    assert rc == 0, err
    doc = json.loads(out)
    runs = doc["runs"]
    assert [r["coefficients"] for r in runs] == [str(d / "truth.json"), str(d / "old.json")]
    for key in ("coefficients", "final_error_m", "max_error_m", "time_s", "north_error_m",
                "east_error_m", "final_error_nmi", "max_error_nmi"):  # fmt: skip
        assert key in runs[0]
    assert runs[0]["time_s"] == pytest.approx(900.0)  # 1200 s minus the 300 s alignment
    assert runs[0]["final_error_m"] < 5.0
    assert runs[1]["final_error_m"] > 10 * runs[0]["final_error_m"] + 20.0
    # per set in the order given; the old set's east bias turns its heading (gyrocompass)
    assert doc["alignment"]["attitude_deg"][1] == pytest.approx([1.0, -2.0, 40.0], abs=1e-3)
    assert doc["schuler_period_min"] == pytest.approx(84.4, abs=0.2)


def test_report_and_attitude(static_files, tmp_path, capsys):
    d = static_files
    report = tmp_path / "nav.html"
    rc, out, err = _run(
        capsys, "navigate", d / "rec.csv", "--format", "csv", "--coefficients", d / "truth.json",
        "--latitude", "45", "--attitude", "1,-2,40", "--duration", "600", "--report", report,
    )  # fmt: skip
    assert rc == 0, err
    assert out.splitlines()[0] == str(report)
    page = report.read_text()
    assert "<svg" in page and "horizontal error (m)" in page and "truth.json" in page
    assert "final" in out


def test_voyage_against_truth(tmp_path, capsys):
    rec, track = tmp_path / "voyage.csv", tmp_path / "track.csv"
    rc, _, err = _run(
        capsys, "simulate", "--trajectory", "voyage", "--moor", "400", "--rate", "10",
        "--recording", rec, "--track", track, "--truth-out", tmp_path / "truth.json",
    )  # fmt: skip
    assert rc == 0, err
    rc, out, err = _run(
        capsys, "navigate", rec, "--format", "csv", "--coefficients", tmp_path / "truth.json",
        "--latitude", "45", "--truth", track, "--duration", "1800", "--json",
    )  # fmt: skip
    assert rc == 0, err
    doc = json.loads(out)
    assert doc["against"] == "truth"
    run = doc["runs"][0]
    assert run["time_s"] == pytest.approx(1800.0)
    assert abs(run["north_error_m"]) < 100 and abs(run["east_error_m"]) < 100


def test_kvh_capture(tmp_path, capsys):
    cap = tmp_path / "static.bin"
    rc, _, err = _run(
        capsys, "simulate", "--trajectory", "static", "--duration", "400", "--rate", "100",
        "--capture", cap, "--truth-out", tmp_path / "truth.json", "--arw", "0", "--vrw", "0",
    )  # fmt: skip
    assert rc == 0, err
    rc, out, err = _run(
        capsys, "navigate", cap, "--format", "kvh-a", "--rate", "100", "--coefficients",
        tmp_path / "truth.json", "--latitude", "45", "--json",
    )  # fmt: skip
    assert rc == 0, err
    assert json.loads(out)["runs"][0]["final_error_m"] < 5.0


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--attitude", "1,2"], "--attitude must be ROLL,PITCH,YAW"),
        (["--attitude", "0,100,0"], "pitch must be within"),
        (["--align", "1500"], "not longer than the alignment period"),
        (["--latitude", "95"], "--latitude 95"),
        (["--nav-rate", "0"], "--nav-rate must be a positive number"),
    ],
)
def test_bad_input_is_one_line_exit_2(static_files, capsys, extra, message):
    d = static_files
    args = ["navigate", d / "rec.csv", "--format", "csv", "--coefficients", d / "truth.json",
            "--latitude", "45", *extra]  # fmt: skip
    if "--latitude" in extra:
        args = args[:6] + extra
    rc, out, err = _run(capsys, *args)
    assert rc == 2
    assert out == ""
    assert len(err.strip().splitlines()) == 1 and message in err


def test_no_static_start_is_refused(tmp_path, capsys):
    rec = tmp_path / "voyage.csv"
    rc, _, err = _run(
        capsys, "simulate", "--trajectory", "voyage", "--moor", "20", "--rate", "5",
        "--recording", rec, "--truth-out", tmp_path / "t.json",
    )  # fmt: skip
    assert rc == 0, err
    rc, out, err = _run(
        capsys, "navigate", rec, "--format", "csv", "--coefficients", tmp_path / "t.json",
        "--latitude", "45", "--align", "300",
    )  # fmt: skip
    assert rc == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and "not static" in err


def test_missing_coefficients_and_accel_only_recording(static_files, tmp_path, capsys):
    d = static_files
    rc, _, err = _run(capsys, "navigate", d / "rec.csv", "--format", "csv", "--coefficients",
                      tmp_path / "none.json", "--latitude", "45")  # fmt: skip
    assert rc == 2 and "does not exist" in err
    lines = (d / "rec.csv").read_text().splitlines()[:200]
    accel_only = tmp_path / "accel.csv"
    accel_only.write_text("\n".join(",".join(r.split(",")[i] for i in (0, 4, 5, 6)) for r in lines))
    rc, _, err = _run(capsys, "navigate", accel_only, "--format", "csv", "--coefficients",
                      d / "truth.json", "--latitude", "45")  # fmt: skip
    assert rc == 2 and "both gyro and accel" in err
