"""The coefficients file's ``schema``: checked on every read, one test per version written.

Versions: 0 is a hand-written file without ``schema``; 1 is what recal has written since its
first release (first without ``uncertainty``, later with it inside, then with ``covariance``);
stored versions in the service database keep ``uncertainty`` beside their coefficients.
"""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from recal.errors import InputError, RecalInputError
from recal.model.coefficient_schema import MIGRATIONS, SCHEMA, VERSION, schema_version, upgrade
from recal.model.coefficients import CoefficientSet, read_coefficients
from service.cli.main import main

RELEASE_DB = Path(__file__).parent / "data" / "release_612b796.db"
MIS = {"Exz": 1e-4, "Exy": -2e-4, "Eyz": 3e-4, "Eyx": 0.0, "Ezy": 5e-5, "Ezx": -1e-5}


def hand_written() -> dict:
    """Version 0: the section 5 layout as a user types it, no schema, no t0_c."""
    return {
        "gyro": {
            "scale": [643.5, 645.6, 645.2],
            "bias": [0.015, 0.032, 0.028],
            "misalignment": MIS,
        },
        "accel": {"scale": [1.0, 1.0, 1.0], "bias": [2e-4, -1e-4, 3e-4]},
    }


def test_every_older_version_has_one_migration_step() -> None:
    assert sorted(MIGRATIONS) == list(range(VERSION))
    assert SCHEMA == f"recal.coefficients/{VERSION}"


def test_version_0_hand_written_file_migrates() -> None:
    data = hand_written()
    assert schema_version(data) == 0
    up = upgrade(data)
    assert up["schema"] == SCHEMA and up["t0_c"] == 25.0
    assert "schema" not in data  # the caller's dict is left alone
    cs = read_coefficients(json.dumps(data), source="hand.json")
    assert cs.t0_c == 25.0 and cs.metadata["source"] == "hand.json"
    np.testing.assert_array_equal(cs.values["gyro.scale"], [643.5, 645.6, 645.2])
    np.testing.assert_array_equal(cs.values["gyro.misalignment"], list(MIS.values()))
    assert cs.uncertainty == {}


def test_version_1_first_release_file_without_uncertainty() -> None:
    """What calibrate -o wrote before files carried their uncertainty."""
    data = {**hand_written(), "t0_c": 20.0, "schema": "recal.coefficients/1",
            "metadata": {"method": "lm", "positions": 24}}  # fmt: skip
    cs = CoefficientSet.from_json_dict(data, source="old.json")
    assert cs.t0_c == 20.0 and cs.uncertainty == {} and cs.metadata["method"] == "lm"


def test_version_1_current_file_round_trips_with_uncertainty() -> None:
    cs = CoefficientSet.seed_truth()
    cs.uncertainty = {k: np.full(v.shape, 1e-3) for k, v in cs.values.items()}
    text = json.dumps(cs.to_json_dict())
    back = read_coefficients(text, source="new.json")
    assert json.loads(text)["schema"] == SCHEMA
    for name, value in cs.values.items():
        np.testing.assert_allclose(back.values[name], value, rtol=0, atol=0)
        np.testing.assert_allclose(back.uncertainty[name], 1e-3)


def test_stored_version_from_the_first_release_database() -> None:
    """A version document stored by release 612b796: schema 1 coefficients, uncertainty beside."""
    with sqlite3.connect(RELEASE_DB) as db:
        (raw,) = db.execute("SELECT document FROM calibrations ORDER BY id LIMIT 1").fetchone()
    doc = json.loads(raw)
    assert "uncertainty" not in doc["coefficients"] and doc.get("uncertainty")
    cs = read_coefficients(doc, source="version 1")
    assert cs.values["gyro.scale"][0] == doc["coefficients"]["gyro"]["scale"][0]
    assert set(cs.uncertainty) == {k for k in cs.values}


@pytest.mark.parametrize(
    ("schema", "expected"),
    [
        ("recal.coefficients/9", "schema recal.coefficients/9 is newer than this recal reads"),
        ("imucal.calibration/2", "schema 'imucal.calibration/2' is not a recal coefficients"),
        ("recal.coefficients/two", "is not a recal coefficients file"),
        (3, "schema 3 is not a recal coefficients file"),
        ("recal.coefficients/0", "schema recal.coefficients/0 does not exist"),
    ],
)
def test_newer_foreign_or_malformed_schema_is_an_input_error(schema, expected) -> None:
    data = {**hand_written(), "schema": schema}
    with pytest.raises(RecalInputError, match="^f.json: ") as err:
        read_coefficients(data, source="f.json")
    assert expected in str(err.value) and isinstance(err.value, InputError)
    with pytest.raises(RecalInputError) as bare:
        CoefficientSet.from_json_dict(data, source="f.json")  # the bare reader checks it too
    assert str(bare.value) == str(err.value)


def test_newer_schema_inside_a_calibrate_document() -> None:
    doc = {"coefficients": {**hand_written(), "schema": "recal.coefficients/2"}, "chi2_red": 1.0}
    with pytest.raises(RecalInputError, match="recal.coefficients/2 is newer"):
        read_coefficients(doc, source="doc.json")


def test_not_json_is_an_input_error() -> None:
    with pytest.raises(RecalInputError, match=r"^c.json: not valid JSON .* line 2"):
        read_coefficients('{"gyro":\n  [1, 2', source="c.json")


@pytest.fixture(scope="module")
def positions(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("schema") / "pos.csv"
    assert main(["simulate", "-o", str(path)]) == 0
    return path


def test_calibrate_prior_with_newer_schema_exits_2_naming_it(positions: Path) -> None:
    """Acceptance (issue 21): --prior with a newer schema is exit 2 naming it."""
    newer = positions.with_name("NEWER.json")
    newer.write_text(json.dumps({**hand_written(), "schema": "recal.coefficients/9"}))
    script = Path(sys.executable).with_name("recal")
    done = subprocess.run([str(script), "calibrate", str(positions), "--prior", str(newer)],
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode == 2 and done.stdout == ""
    last = done.stderr.strip().splitlines()[-1]
    assert last == (
        f"recal calibrate: error: {newer}: schema recal.coefficients/9 is newer than this "
        "recal reads (up to /1); upgrade recal"
    )
    assert "Traceback" not in done.stderr


def test_drift_coefficients_with_foreign_schema_exits_2(positions: Path, capsys) -> None:
    foreign = positions.with_name("foreign.json")
    foreign.write_text(json.dumps({**hand_written(), "schema": "imucal.calibration/2"}))
    assert main(["drift", str(positions), "--coefficients", str(foreign)]) == 2
    assert "schema 'imucal.calibration/2' is not a recal coefficients file" in (
        capsys.readouterr().err
    )


def test_calibrate_reads_a_hand_written_prior(positions: Path, capsys) -> None:
    prior = positions.with_name("hand.json")
    prior.write_text(json.dumps(hand_written()))
    assert main(["calibrate", str(positions), "--prior", str(prior), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["coefficients"]["schema"] == SCHEMA
    # a calibrate --json document is a prior too: its coefficients, its uncertainty beside them
    document = positions.with_name("calibrate.json")
    document.write_text(json.dumps(out))
    assert main(["calibrate", str(positions), "--prior", str(document), "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["coefficients"]["metadata"]["prior"].endswith("calibrate.json")


def test_service_prior_path_with_newer_schema_stops_the_daemon_at_start(tmp_path: Path) -> None:
    from service.startup import check_prior

    prior = tmp_path / "prior.json"
    prior.write_text(json.dumps({**hand_written(), "schema": "recal.coefficients/3"}))
    with pytest.raises(InputError, match=r"^prior_path: .*prior.json: schema recal.coefficients/3"):
        check_prior(str(prior))
    prior.write_text(json.dumps(hand_written()))
    check_prior(str(prior))  # a hand-written prior starts
