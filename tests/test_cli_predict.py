"""recal predict: the static navigation error of coefficient sets, without a recording."""

from __future__ import annotations

import json

import pytest

from recal.model.coefficients import CoefficientSet
from recal.nav.ins_static import predict_static_error
from recal.sim.simulate import simulate_positions
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions
from service.cli.main import main


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """Two calibrations of the same simulated unit: a calibrate --json output and a -o file."""
    d = tmp_path_factory.mktemp("predict")
    out = {}
    for seed in (1, 2):
        pos = simulate_positions(CoefficientSet.seed_truth(), seed=seed, latitude_deg=52.0)
        result = calibrate(pos, CalibrationOptions(latitude_deg=52.0))
        out[f"json{seed}"] = str(d / f"cal{seed}.json")
        out[f"coeffs{seed}"] = str(d / f"coeffs{seed}.json")
        (d / f"cal{seed}.json").write_text(json.dumps(result.to_json_dict()))
        (d / f"coeffs{seed}.json").write_text(json.dumps(result.coefficients.to_json_dict()))
    bare = result.coefficients.to_json_dict()  # a hand-written file: no "uncertainty"
    assert bare.pop("uncertainty")
    out["bare"] = str(d / "bare.json")
    (d / "bare.json").write_text(json.dumps(bare))
    return out


def test_prediction_of_a_change_is_the_linear_model(files, capsys) -> None:
    new, old = files["json1"], files["coeffs2"]
    args = ["predict", new, "--from", old, "--latitude", "52", "--attitude", "0,0,30"]
    assert main([*args, "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    a = CoefficientSet.from_json_dict(json.load(open(old)))
    b = CoefficientSet.from_json_dict(json.load(open(new))["coefficients"])
    p = predict_static_error(a, b, 52.0, 0.0, (0, 0, 30))
    assert doc["change"]["old_error_nmi"] == pytest.approx(p.final_nmi, rel=1e-9)
    assert doc["static_24h_error_nmi_1sigma"] > 0 and doc["from"] == old
    # two calibrations of the same unit: the difference is within the new uncertainty
    assert doc["change"]["significant"] is False
    assert main(args) == 0
    text = capsys.readouterr().out
    assert f"{old}: {p.final_nmi:.3f} nmi" in text and "within the new uncertainty" in text


@pytest.mark.parametrize(
    "extra, message",
    [
        ([], "has no uncertainties (no 'uncertainty' beside the coefficients): give --from"),
        (["--latitude", "95"], "--latitude 95.0 is outside [-90, 90] deg"),
        (["--hours", "0"], "--hours in (0, 720]"),
    ],
)
def test_bad_input_is_one_line_exit_2(files, capsys, extra: list[str], message: str) -> None:
    args = ["predict", files["bare"], "--latitude", "52", *extra]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
