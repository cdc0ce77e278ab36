"""A hull-fixed unit through the daemon's scheduler, gate and publisher (issue 25, item 3): what
the heading turns show is published only under ``[gate] publish_observable_part``, and the
published file says what was held at the prior."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from recal.model.coefficients import CoefficientSet
from recal.model.positions import Positions
from recal.sim.simulate import simulate_positions
from service.api import create_app
from service.capture_sim import kvh_like_truth
from service.config import DeviceSettings, GateSettings, SchedulerSettings, Settings
from service.daemon import build_service
from service.scheduler import SchedulerRefused

LAT = 45.0
PRIOR_SIGMA = {"scale": 1e-4, "bias": {"gyro": 0.01, "accel": 20e-6}, "misalignment": 1e-4,
               "quadratic": 1e-5}  # fmt: skip


@pytest.fixture(scope="module")
def unit() -> tuple[CoefficientSet, CoefficientSet, Positions]:
    """The truth, a prior within 100 ppm, 0.01 deg/h and 20 ug carrying that uncertainty, and
    24 windows of a hull-fixed unit (heading turns, small tilts)."""
    truth = kvh_like_truth(3)
    rng = np.random.default_rng(5)
    prior = truth.copy()
    for sensor in ("gyro", "accel"):
        prior.values[f"{sensor}.scale"] = truth.values[f"{sensor}.scale"] * (
            1 + 1e-4 * rng.standard_normal(3)
        )
        bias = truth.values[f"{sensor}.bias"]
        prior.values[f"{sensor}.bias"] = bias + PRIOR_SIGMA["bias"][sensor] * rng.standard_normal(3)
    prior.uncertainty = {}
    for name, value in truth.values.items():
        sigma = PRIOR_SIGMA[name.split(".")[1]]
        sigma = sigma[name.split(".")[0]] if isinstance(sigma, dict) else sigma
        prior.uncertainty[name] = np.full(np.size(value), sigma)
    positions = simulate_positions(truth, design="vessel", n_positions=24, latitude_deg=LAT,
                                   seed=2)  # fmt: skip
    return truth, prior, positions


#: Parameter names of the section 5 vectors (the misalignment is already a name -> value map).
_PARAMS = {
    "scale": ("Kx", "Ky", "Kz"),
    "bias": ("bx", "by", "bz"),
    "quadratic": ("K2x", "K2y", "K2z"),
}


def _held_names(status: dict[str, Any]) -> set[str]:
    """Flat names ("gyro.scale.Kz") whose status is "held" in a section 5 status layout."""
    out = set()
    for sensor, block in status.items():
        for key, entry in block.items():
            items = entry.items() if isinstance(entry, dict) else zip(_PARAMS[key], entry)
            out |= {f"{sensor}.{key}.{p}" for p, st in items if st == "held"}
    return out


def _service(tmp_path: Path, prior: CoefficientSet, **gate: Any) -> Any:
    prior_path = tmp_path / "prior.json"
    prior_path.write_text(json.dumps(prior.to_json_dict()), encoding="utf-8")
    settings = Settings(
        database_url=f"sqlite:///{tmp_path / 'recal.db'}",
        publish_path=str(tmp_path / "coefficients.json"),
        spool_dir=str(tmp_path / "spool"),
        prior_path=str(prior_path),
        device=DeviceSettings(url="replay://unit", rate_hz=100.0),
        site={"latitude_deg": LAT},
        scheduler=SchedulerSettings(min_positions=1000, min_new_positions=1000, method="lm"),
        gate=GateSettings(**gate),
    )
    return build_service(settings, with_reader=False)


def test_by_default_a_hull_fixed_unit_publishes_nothing(tmp_path: Path, unit) -> None:
    _, prior, positions = unit
    service = _service(tmp_path, prior)
    try:
        service.store.add_positions(service.session_id, positions.columns)
        with pytest.raises(SchedulerRefused, match="only a partial calibration.*gyro.scale.Kz"):
            service.scheduler.trigger("manual")
        assert service.store.current() is None
        assert not (tmp_path / "coefficients.json").exists()
    finally:
        service.close(wait_s=0)


def test_publish_observable_part_publishes_it_and_says_what_was_held(tmp_path: Path, unit) -> None:
    truth, prior, positions = unit
    service = _service(tmp_path, prior, publish_observable_part=True)
    try:
        service.store.add_positions(service.session_id, positions.columns)
        service.scheduler.trigger("manual")
        outcome = service.scheduler.wait(timeout=120)
        assert outcome is not None and outcome.accepted, outcome and outcome.reasons
        note = next(r for r in outcome.reasons if "publish_observable_part" in r)
        assert "held at the prior: gyro.scale.Kz" in note
        published = json.loads((tmp_path / "coefficients.json").read_text())
        client = TestClient(create_app(service.store, service.publisher))
        current = client.get("/coefficients").json()
    finally:
        service.close(wait_s=0)
    assert published["version"] == 1
    held = published["held"]
    # every coefficient whose status is "held", and only those, with the prior it was held at
    status = published["status"]
    assert set(held) == _held_names(status)
    assert {"gyro.scale.Kz", "accel.scale.Kx", "accel.scale.Ky"} <= set(held)
    assert held["gyro.scale.Kz"]["prior"] == pytest.approx(prior.values["gyro.scale"][2], rel=1e-12)
    assert held["gyro.scale.Kz"]["prior_sigma"] == pytest.approx(1e-4)
    assert held["accel.scale.Kx"]["prior"] == pytest.approx(prior.values["accel.scale"][0])
    # the published 1-sigma of a held coefficient is its prior's
    assert published["uncertainty"]["accel"]["scale"][0] == pytest.approx(1e-4, rel=0.05)
    # what the turns show: the horizontal gyro biases, estimated and within 3 sigma of the truth
    assert status["gyro"]["bias"][:2] == ["estimated", "estimated"]
    for i in range(2):
        err = published["coefficients"]["gyro"]["bias"][i] - truth.values["gyro.bias"][i]
        assert abs(err) < 3 * published["uncertainty"]["gyro"]["bias"][i]
    # the version carries the navigator's figures: heading error before (the prior) and after
    nav = current["document"]["navigation"]
    assert nav["before"]["from"].startswith("the prior ")
    assert nav["before"]["heading_error_deg_rms"] == pytest.approx(0.0539, abs=2e-4)
    assert nav["after"]["heading_error_deg_rms"] < 0.5 * nav["before"]["heading_error_deg_rms"]
    assert nav["after"]["position_error_nmi_1sigma"] < nav["before"]["position_error_nmi_1sigma"]
    assert abs(nav["vertical_body"][2]) > 0.999
