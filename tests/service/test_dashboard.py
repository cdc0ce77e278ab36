"""The dashboard's routes and its orientation advice, without a browser."""

from __future__ import annotations

import numpy as np
from fastapi.testclient import TestClient

from recal.model.positions import Positions
from recal.sim.simulate import simulate_positions
from recal.solve.calibrate import calibrate
from recal.solve.options import CalibrationOptions
from service.api import create_app
from service.capture_sim import kvh_like_truth
from service.dashboard import plotly_js
from service.dashboard.coverage import azimuth_elevation, gravity_directions, orientation_advice
from service.publish import Publisher


def test_page_assets_and_csp(sqlite_store, tmp_path):
    client = TestClient(create_app(sqlite_store, Publisher(tmp_path / "c.json")))
    page = client.get("/")
    assert page.status_code == 200 and "text/html" in page.headers["content-type"]
    csp = page.headers["content-security-policy"]
    assert "script-src 'self';" in csp and "unsafe-eval" not in csp
    assert "<script>" not in page.text  # no inline script: the CSP would block it
    for ref in (
        "dashboard/plotly.min.js",
        "dashboard/static/app.js",
        "dashboard/static/dashboard.css",
    ):
        assert ref in page.text
        asset = client.get(f"/{ref}")
        assert asset.status_code == 200 and len(asset.content) > 1000, ref
    assert client.get("/dashboard/plotly.min.js").content == plotly_js().read_bytes()
    assert "http" not in client.get("/dashboard/static/app.js").text  # no CDN, no other host
    empty = client.get("/dashboard/coverage").json()
    assert empty == {"windows": [], "version": None, "residuals": [], "advice": None}
    assert "/" not in client.get("/openapi.json").json()["paths"]


def test_gravity_direction_of_a_window():
    # at rest the accelerometer reads +1 g along the up axis: gravity points the other way
    down = gravity_directions(np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]]))
    assert np.allclose(down, [[0, 0, 1], [1, 0, 0]])
    az, el = azimuth_elevation(down)
    assert np.allclose(el, [90, 0]) and np.isclose(az[1], 0)


def test_advice_names_the_orientation_that_pins_a_weak_coefficient():
    truth = kvh_like_truth(1)
    pos = simulate_positions(truth, "24", latitude_deg=50, seed=1)
    down = gravity_directions(np.column_stack([pos.columns[f"accel_{a}"] for a in "xyz"]))
    keep = down[:, 0] < 0.5  # no window with x down: K2x cannot be told from bx
    sub = Positions.from_columns({k: v[keep] for k, v in pos.columns.items()})
    doc = calibrate(sub, CalibrationOptions(latitude_deg=50)).to_json_dict()
    assert "accel.quadratic.K2x" in doc["observability"]["held_directions"][-1]
    advice = orientation_advice(sub, doc)
    assert advice["weak"] == ["accel.quadratic.K2x"]
    assert advice["suggestions"] == [{"orientation": "x down", "pins": ["accel.quadratic.K2x"]}]
    assert advice["unresolved"] == []
    # the rotations of the frames: no orientation shows them, and the advice says why
    assert advice["unseeable"] and all("rotation" in h["reason"] for h in advice["unseeable"])


def test_drift_series_is_the_drift_events_and_the_last_reason(sqlite_store, tmp_path):
    from datetime import UTC, datetime

    from service.store.records import CalibrationRecord

    client = TestClient(create_app(sqlite_store, Publisher(tmp_path / "c.json")))
    assert client.get("/dashboard/drift").json() == {"points": [], "last_reason": None}
    sqlite_store.add_event("drift", "steady", {"version": 1, "statistic": 2.0, "threshold": 17.0,
                                               "last_id": 30, "alarm_window": None})  # fmt: skip
    sqlite_store.add_event("job", "started", {"state": "started"})
    sqlite_store.add_event("drift", "DRIFT", {"version": 1, "statistic": 40.0, "threshold": 17.5,
                                              "last_id": 31, "alarm_window": 1,
                                              "suspect": "accel x bias, about +5 micro-g"})  # fmt: skip
    why = {"trigger": "drift", "statistic": 40.0, "threshold": 17.5,
           "suspect": "accel x bias, about +5 micro-g"}  # fmt: skip
    sqlite_store.add_calibration(CalibrationRecord(
        version=None, created_at=datetime.now(UTC), trigger="drift", method="lm", accepted=True,
        reasons=[], document={"coefficients": {}, "trigger_detail": why}, positions_used=[31],
        prior_version=None))  # fmt: skip
    out = client.get("/dashboard/drift").json()
    assert [p["statistic"] for p in out["points"]] == [2.0, 40.0]  # oldest first, drift only
    assert [p["alarm"] for p in out["points"]] == [False, True]
    assert out["points"][1]["suspect"] == "accel x bias, about +5 micro-g"
    assert out["last_reason"]["trigger"] == "drift"
    assert out["last_reason"]["text"] == (
        "drift: statistic 40.0 > 17.5, looks like accel x bias, about +5 micro-g"
    )


def test_the_page_shows_the_versions_heading_error(sqlite_store, tmp_path):
    """The current version's ``navigation`` block reaches the page through ``/coefficients``,
    and every figure the script reads from it is one the service writes."""
    import re
    from datetime import UTC, datetime

    from service.gate import GateConfig
    from service.recalibration import calibration_job
    from service.store.records import CalibrationRecord

    truth = kvh_like_truth(2)
    pos = simulate_positions(truth, "vessel", n_positions=24, latitude_deg=45, seed=2)
    prior = truth.copy()  # a hull-fixed unit needs its prior for what the turns cannot show
    prior.uncertainty = {n: np.full(np.size(v), 1e-4) for n, v in truth.values.items()}
    prior.uncertainty["gyro.bias"] = np.full(3, 0.01)
    options = CalibrationOptions(latitude_deg=45, prior=prior)
    gate = GateConfig(publish_observable_part=True).model_dump()
    outcome = calibration_job(pos.columns, options, None, gate)
    assert outcome.accepted, outcome.reasons
    sqlite_store.add_calibration(CalibrationRecord(
        version=None, created_at=datetime.now(UTC), trigger="manual", method="lm", accepted=True,
        reasons=outcome.reasons, document=outcome.document, positions_used=[],
        prior_version=None))  # fmt: skip
    client = TestClient(create_app(sqlite_store, Publisher(tmp_path / "c.json")))
    nav = client.get("/coefficients").json()["document"]["navigation"]
    assert 0 < nav["after"]["heading_error_deg_rms"] < nav["before"]["heading_error_deg_rms"]
    script = client.get("/dashboard/static/app.js").text
    assert "renderNavImpact(doc.navigation_impact, rec.reasons || [], doc.navigation)" in script
    read = set(re.findall(r"\b(?:after|before)\??\.(\w+)", script))
    assert {"heading_error_deg_rms", "heading_error_deg_worst", "from"} <= read
    assert read <= set(nav["after"]) | set(nav["before"]), read
    assert "gyrocompass heading error" in script
