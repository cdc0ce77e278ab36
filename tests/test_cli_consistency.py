"""Commands say one consistent thing (issue 18 item 7): a slews side file is checked against
its positions before it is announced, the prior's description is true to the values held, and
diagnose names the same positions in its verdict and its JSON."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from recal.diagnose.effects import diagnose
from recal.model.coefficients import CoefficientSet
from recal.sim.session import simulate_session
from recal.sim.simulate import NoiseSpec, simulate_positions
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions
from service.cli.diagnose import format_diagnosis
from service.cli.main import main


@pytest.fixture(scope="module")
def with_slews(tmp_path_factory):
    """pos.csv and its pos.slews.npz from one recording (`recal positions`)."""
    d = tmp_path_factory.mktemp("slews")
    s = simulate_session(CoefficientSet.seed_truth(), "24", latitude_deg=40.0, seed=4,
                         rate_hz=100.0, window_s=6.0, slew_s=3.0, first_hold_s=12.0,
                         noise=NoiseSpec(arw_deg_rt_h=0.0005, vrw_ug_rt_hz=20.0))  # fmt: skip
    log = d / "log.csv"
    rows = np.column_stack([s.time_s, s.gyro_out, s.accel_out])
    np.savetxt(log, rows, delimiter=",", header="time_s,gyro_x,gyro_y,gyro_z,accel_x,accel_y,"
               "accel_z", comments="", fmt="%.17g")  # fmt: skip
    assert main(["positions", str(log), "--format", "csv", "-o", str(d / "pos.csv")]) == 0
    return d


def test_stale_side_file_is_ignored_with_the_reason_and_never_announced(with_slews, capsys):
    d = with_slews
    capsys.readouterr()
    stale = d / "stale.csv"
    (d / "stale.slews.npz").write_bytes((d / "pos.slews.npz").read_bytes())
    # a new pos.csv from another source beside the old side file
    assert main(["simulate", "--latitude", "40", "-o", str(stale)]) == 0
    assert "stale.slews.npz beside it belongs to the positions file it replaced" in (
        capsys.readouterr().err
    )
    assert main(["calibrate", str(stale), "--latitude", "40", "--json"]) == 0
    out = capsys.readouterr()
    doc = json.loads(out.out)
    assert "ignoring" in out.err and "written for another positions file" in out.err
    assert "window 0 (0-based row) spans 0-100 s in the positions file" in out.err
    assert "used" not in out.err and "using" not in out.err
    assert "slew" not in doc["residuals"]
    assert not any("slew" in n for n in doc["notes"])  # nothing contradicts the stderr line
    # asked for explicitly, a side file of another recording is bad input: one line, exit 2
    assert main(["calibrate", str(stale), "--latitude", "40", "--slews"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "written for another positions file" in err[0]
    assert main(["diagnose", str(stale), "--latitude", "40", "--json"]) == 0
    assert "ignoring" in capsys.readouterr().err


def test_side_file_is_announced_only_when_the_fit_uses_it(with_slews, capsys):
    pos = str(with_slews / "pos.csv")
    capsys.readouterr()
    assert main(["calibrate", pos, "--latitude", "40", "--json"]) == 0
    out = capsys.readouterr()
    n = json.loads(out.out)["residuals"]["slew"]["slews"]
    assert f"recal: used {n} slews from" in out.err and "not used" not in out.err
    # one triad: the engine drops the slews, and stderr says so instead of "using"
    assert main(["calibrate", pos, "--latitude", "40", "--sensor", "accel", "--json"]) == 0
    out = capsys.readouterr()
    assert "slews not used: they need both triads" in out.err and "used " not in out.err.replace(
        "not used", ""
    )
    assert any(n.startswith("slews not used") for n in json.loads(out.out)["notes"])


def _prior_claims_zero(prior: str) -> set[str]:
    """Terms the prior description says start at zero."""
    m = re.search(r"([\w., ]+) zero\)", prior)
    return {t.strip() for t in m.group(1).split(",")} if m else set()


@pytest.mark.parametrize("sensors", [("accel",), ("gyro",)])
def test_prior_description_matches_the_held_values(sensors):
    """8 random positions: a held coefficient stands exactly at the prior the description names (issue 25: held means held; before, the part of it the
    estimated combinations shared moved it off the prior's zero)."""
    pos = simulate_positions(CoefficientSet.seed_truth(), "random", 8, 45.0, seed=0,
                             sensors=sensors)  # fmt: skip
    r = calibrate(pos, CalibrationOptions(latitude_deg=45.0))
    doc = r.to_json_dict()
    zero = _prior_claims_zero(doc["prior"])
    assert f"{sensors[0]}.misalignment" in zero, doc["prior"]
    held = [(name, r.theta[i], r.theta_prior[i]) for i, name in enumerate(r.layout.names)
            if not r.observability.estimated[i]]  # fmt: skip
    # the accelerometer holds K2 (and misalignment); the gyro's 8 positions touch every
    # misalignment through the directions they see (then "estimated", partly held)
    assert held or sensors == ("gyro",)
    for name, value, prior in held:
        if name.rsplit(".", 1)[0] in zero:
            assert prior == 0.0
        assert value == prior, name  # bitwise
    assert not any("moved off the prior" in n for n in doc["notes"])


def test_prior_description_says_when_there_is_no_ellipsoid_fit():
    """Six positions are too few for the ellipsoid fit: the scale is the median norm's."""
    pos = simulate_positions(CoefficientSet.seed_truth(), "random", 6, 45.0, seed=1,
                             sensors=("accel",))  # fmt: skip
    prior = calibrate(pos, CalibrationOptions(latitude_deg=45.0)).prior_source
    assert "accel: common scale from the median norm, bias zero" in prior
    assert "ellipsoid fit" in prior and "scale and bias from an ellipsoid fit" not in prior


def test_diagnose_verdict_and_json_name_the_same_worst_positions():
    truth = CoefficientSet.seed_truth()
    truth.values["gyro.bias_drift"] = np.array([0.05, 0.0, -0.03])
    from recal.model.terms import catalogue_terms

    pos = simulate_positions(truth, "random", 24, 45.0, seed=2,
                             hidden=[catalogue_terms()["gyro.bias_drift"]])  # fmt: skip
    d = diagnose(pos, CalibrationOptions(latitude_deg=45.0), candidates=["accel.scale_asymmetry"])
    assert d.model_fails
    doc = d.to_json_dict()
    m = re.search(r"worst positions \(0-based rows\) ([\d, ]+)", format_diagnosis(d))
    assert m, d.verdict
    named = [int(v) for v in m.group(1).split(",")]
    assert named == doc["worst_positions"] and len(set(named)) == len(named) == 3
    assert "0-based rows" in doc["indexing"]
    # the positions named carry the largest misfit of the final model, all invariants together
    w = {k: v / d.baseline.problem.sigma[k] for k, v in d.final_residuals.items()}
    score = sum(v**2 for v in w.values())
    assert set(named) == set(np.argsort(-score)[:3].tolist())


def test_a_disagreement_note_names_the_effect_that_explains_more_or_none():
    """The note used to send the reader to 'the first ranked' even when it was that candidate:
    out-of-catalogue misfit (a magnetic bias), only drift-like candidates tried."""
    from pathlib import Path

    from recal.model.plugins import hidden_plugin
    from recal.sim.simulate import design_orientations
    from service.cli.common import load_plugin

    plugin = Path(__file__).resolve().parents[1] / "docs" / "examples" / "faraday_plugin.py"
    (term,) = load_plugin(str(plugin))
    C = design_orientations("random", 24, np.random.default_rng(2))
    truth = CoefficientSet.seed_truth()
    truth.values["gyro.faraday"] = np.array([0.04, -0.03, 0.05])
    pos = simulate_positions(truth, "random", 24, 45.0, seed=2,
                             hidden=[hidden_plugin(term, C, 45.0)])  # fmt: skip
    d = diagnose(pos, CalibrationOptions(latitude_deg=45.0),
                 candidates=["gyro.bias_drift", "accel.scale_asymmetry"])  # fmt: skip
    top = d.candidates[0]
    assert top.effect == "gyro.bias_drift" and not top.significant
    assert top.explained_better_by == ""
    # issue 35: the misfit is as well an excess independent on each window, so the drift's
    # share of it is measured from that null (delta BIC > 0) and there is nothing to explain;
    # the note's wording is checked where delta BIC and p disagree
    assert top.hypotheses["null"] == "noise" and top.delta_bic > 0 and top.disagreement == ""
    assert "first ranked" not in format_diagnosis(d)
    from recal.diagnose.candidates import Candidate

    odd = Candidate("gyro.bias_drift", "", True, delta_bic=-20.0, p_adjusted=0.3,
                    explained_fraction=0.2, added_directions=3)  # fmt: skip
    assert "a misfit no candidate explains (see the verdict)" in odd.disagreement


def test_diagnose_does_not_call_an_exactly_determined_fit_at_the_noise_floor():
    """Six positions, one triad: six equations for six directions, so the residual is zero by
    construction; calibrate says it cannot check the fit, and so must diagnose."""
    from recal.report.html import diagnosis_html

    pos = simulate_positions(CoefficientSet.seed_truth(), "random", 6, 45.0, seed=1,
                             sensors=("accel",))  # fmt: skip
    assert any("exactly determined" in n for n in calibrate(pos, CalibrationOptions()).notes)
    d = diagnose(pos, CalibrationOptions(latitude_deg=45.0))
    assert d.verdict.startswith("exactly determined") and "noise floor" not in d.verdict
    doc = d.to_json_dict()
    assert doc["chi2_red"] is None and doc["ladder"][0]["chi2_red"] is None
    assert not d.model_fails and "exactly determined" in format_diagnosis(d)
    assert "chi2_red n/a (no redundancy)" in diagnosis_html(d)


def test_diagnose_says_why_its_baseline_chi2_differs_from_calibrates():
    pos = simulate_positions(CoefficientSet.seed_truth(), "random", 10, 45.0, seed=1)
    cal = calibrate(pos, CalibrationOptions(latitude_deg=45.0))
    d = diagnose(pos, CalibrationOptions(latitude_deg=45.0), candidates=[])
    doc = d.to_json_dict()
    assert doc["ladder"][0]["directions"] != cal.observability.rank
    (note,) = [n for n in doc["notes"] if n.startswith("the baseline here fits")]
    assert f"({doc['chi2_red']:.3g}) differs from calibrate's ({cal.chi2_red:.3g})" in note
    assert f"recal calibrate {cal.observability.rank}" in note


IMUCAL_COLUMNS = "gyro_x=gyr_x,gyro_y=gyr_y,gyro_z=gyr_z,accel_x=acc_x,accel_y=acc_y,accel_z=acc_z"
REAL = {  # recording args for `recal positions`, then calibrate's
    "ferraris": (["imucal/example_ferraris_session.csv", "--format", "csv", "--rate", "102.4",
                  "--columns", IMUCAL_COLUMNS], []),
    "xsens": (["xsens_static_poses_acc.txt", "xsens_static_poses_gyro.txt", "--format",
               "xsens-text"], ["--latitude", "57.834"]),
}  # fmt: skip


@pytest.mark.parametrize("name", sorted(REAL))
def test_real_recordings_say_one_thing_about_the_gyro_frame(name, shared_data, tmp_path, capsys):
    """With slews the notes said "the gyro frame is estimated relative to the accelerometer
    frame" while the Ferraris fit held those rotations for "no norm can see it"."""
    rec, cal = REAL[name]
    first = rec.index("--format")
    files = [str(shared_data / f) for f in rec[:first]]
    pos = tmp_path / "pos.csv"
    assert main(["positions", *files, *rec[first:], "-o", str(pos)]) == 0
    capsys.readouterr()
    assert main(["calibrate", str(pos), *cal, "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert "slew" in doc["residuals"]
    held = doc["observability"]["held"]
    gyro_rot = [h for h in held if h["reason"].startswith("a rotation of the gyro frame")]
    assert not [h for h in held if "no norm can see it" in h["reason"]]  # the slews see them
    said = " ".join(doc["notes"])
    assert ("the gyro frame is estimated relative to the accelerometer frame" in said) == (
        not gyro_rot
    )
    for h in gyro_rot:
        assert h["direction"] in said and "only the slews see it" in said
