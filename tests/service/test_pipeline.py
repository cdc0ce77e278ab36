"""The service end to end: replay:// port -> pipeline -> SQLite -> gate -> publish -> HTTP."""

import json
import time

import httpx
import numpy as np
import pytest

from recal.detect.slew_gauge import in_accel_frame
from recal.model.coefficients import CoefficientSet
from recal.model.error_model import ParameterLayout
from recal.sim.session import simulate_session
from recal.solve.calibrate import build_models
from service.capture_sim import kvh_like_truth, session_to_kvh
from service.cli.main import main
from service.config import (
    DetectorSettings,
    DeviceSettings,
    SchedulerSettings,
    Settings,
    SiteSettings,
)

TOKEN = "pipeline-test-token-0123456789"


@pytest.mark.slow
def test_demo_runs_the_whole_product(tmp_path, capsys):
    folder = tmp_path / "demo"
    assert main(["demo", "--dir", str(folder), "--seed", "3"]) == 0
    out = capsys.readouterr().out
    published = json.loads((folder / "coefficients.json").read_text())
    assert published["version"] >= 1 and "gyro" in published["coefficients"]
    # every printed error / sigma of the accepted version is within 3.5
    zs = [float(v) for line in out.splitlines() if line.startswith("  gyro.") or
          line.startswith("  accel.") for v in line.split()[1:]]  # fmt: skip
    assert len(zs) == 12 and max(abs(z) for z in zs) < 3.5
    truth = json.loads((folder / "truth.json").read_text())
    assert truth["gyro"]["scale"][0] == pytest.approx(1.0, abs=1e-3)


def _leaves(tree):
    """The leaves of a section 5 layout (lists and name -> value maps), in order."""
    if isinstance(tree, dict):
        return [v for k in tree for v in _leaves(tree[k])]
    return list(tree) if isinstance(tree, list) else [tree]


@pytest.fixture()
def capture(tmp_path):
    rate = 200.0
    truth = kvh_like_truth(5)
    session = simulate_session(truth, "24", latitude_deg=40.0, seed=5, rate_hz=rate,
                               window_s=20.0, slew_s=4.0, first_hold_s=35.0)  # fmt: skip
    data, _ = session_to_kvh(session, rng=5)
    path = tmp_path / "session.bin"
    path.write_bytes(data)
    return path, len(data), rate, truth


#: Monte Carlo runs of the HTTP test's job: 12 batches, about a second on 2 cores (100 runs take
#: 0.3 s, over before a poll of /health could see them running)
MC_RUNS = 600


@pytest.mark.slow
def test_daemon_over_a_real_http_server(tmp_path, capture, serve, replay):
    path, size, rate, truth = capture
    settings = Settings(
        database_url=f"sqlite:///{tmp_path / 'recal.db'}",
        publish_path=str(tmp_path / "coefficients.json"),
        device=DeviceSettings(url=f"replay://{path}?speed=max&rate={rate:g}", rate_hz=rate),
        site=SiteSettings(latitude_deg=40.0),
        detector=DetectorSettings(init_still_s=25.0, min_duration_s=5.0),
        # manual only; MCS-NAFSA (the default method) on MC_RUNS runs, not the default 100, so
        # that the job lasts long enough (about a second) to be seen running through /health
        scheduler=SchedulerSettings(min_positions=100, min_new_positions=100, mc_runs=MC_RUNS),
        api={"port": 0, "token": TOKEN},
    )
    with serve(settings) as (base, service), httpx.Client(base_url=base, timeout=30) as http:
        assert http.get("/coefficients").status_code == 404  # nothing accepted yet
        replay(service, size)
        health = http.get("/health").json()
        # the capture has ended: a reader that has gone silent may already say so
        assert health["positions"] == 24, health
        assert all(p.startswith("reader:") for p in health["problems"]), health["problems"]
        # the motion between the windows is stored with them (23 slews, none dropped)
        part = health["service"]
        assert part["slews"] == 23 and not any(part["slews_dropped"].values())
        assert http.post("/recalibrate").status_code == 401  # writes need the token
        r = http.post("/recalibrate", headers={"Authorization": f"Bearer {TOKEN}"})
        assert r.status_code == 202
        # while MCS-NAFSA runs /health shows its elapsed time and MC runs
        seen, deadline = None, time.monotonic() + 120
        while seen is None and service.scheduler.last_end is None:
            assert time.monotonic() < deadline
            job = http.get("/health").json()["service"]["scheduler"]["job"]
            if job is not None and job["done"] is not None:
                seen = job
            time.sleep(0.05)
        assert seen is not None and seen["total"] == MC_RUNS and 0 <= seen["done"] <= MC_RUNS
        assert seen["elapsed_s"] > 0 and seen["timeout_s"] == settings.scheduler.job_timeout_s
        service.scheduler.wait(timeout=120)
        current = http.get("/coefficients")
        assert current.status_code == 200
        doc = current.json()
        version = doc["version"]
        assert doc["accepted"] and len(doc["positions_used"]) == 24
        assert doc["document"]["method"] == "nafsa" and doc["document"]["mc"]["runs"] == MC_RUNS
        coeffs = doc["document"]["coefficients"]
        sd = np.array(doc["document"]["uncertainty"]["gyro"]["bias"])
        err = np.array(coeffs["gyro"]["bias"]) - truth.values["gyro.bias"]
        assert np.all(np.abs(err) < 4 * sd)
        # with the slews every gyro coefficient is estimated: none held at the prior
        status = doc["document"]["status"]["gyro"]
        assert all(v == "estimated" for v in _leaves(status)), status
        # ... within 4 sigma of the truth, in the gauge the fit holds (accelerometer frame)
        layout = ParameterLayout(build_models(("gyro", "accel"), (), (), 25.0))
        want = in_accel_frame(truth.to_vector(layout), layout)
        got = CoefficientSet.from_json_dict(coeffs).to_vector(layout)
        sdE = np.array(_leaves(doc["document"]["uncertainty"]["gyro"]["misalignment"]))
        E = layout.term_slices()["gyro.misalignment"]
        assert np.all(np.abs(got[E] - want[E]) < 4 * sdE)
        # every version carries its predicted navigation impact at the site's latitude
        impact = doc["document"]["navigation_impact"]
        assert impact["latitude_deg"] == 40.0 and impact["change"] is None
        assert 0 < impact["static_24h_error_nmi_1sigma"] < 50
        assert http.get(f"/coefficients/{version}").json()["version"] == version
        assert http.get("/coefficients/999").status_code == 404
        published = json.loads((tmp_path / "coefficients.json").read_text())
        assert published["version"] == version
