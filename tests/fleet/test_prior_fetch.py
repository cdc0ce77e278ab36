"""The fleet prior goes back to the vessels (issue 28): the sync client fetches its model's
prior from the shore (``GET /fleet/prior``, a unit's token defaulting to its own model) into
the state folder, and the gate uses it unless ``[gate] fleet_prior`` names a file."""

from __future__ import annotations

import os
from typing import Any

import pytest

from service.config import Settings
from service.startup import read_fleet_prior_file
from service.store.repository import Store
from service.sync import SyncThread

NEW_UNIT = "KVH-1750-SN0999"


@pytest.fixture
def seeded(shore: Any, wire: Any, simulated_fleet: Any) -> Any:
    """Eight KVH-1750 ageing over two years, sent through POST /fleet/ingest."""
    for serial, rows in simulated_fleet()["units"].items():
        token = shore.store.add_unit(serial, "KVH-1750")
        assert shore.send(token, wire.batch(serial, rows)).status_code == 200
    assert shore.priors.wait_idle(60)  # the prior recomputed after the batches
    return shore


def _client(tmp_path, shore, unit: str, token: str) -> SyncThread:
    store = Store(f"sqlite:///{tmp_path / 'vessel.db'}")
    store.create_schema()
    return SyncThread(store, shore.url, unit, token, 60.0,
                      prior_path=tmp_path / "state" / "fleet_prior.json")  # fmt: skip


def test_a_new_unit_fetches_its_models_prior_once_per_version(tmp_path, seeded) -> None:
    (tmp_path / "state").mkdir()
    token = seeded.store.add_unit(NEW_UNIT, "KVH-1750")
    # the unit's own model is the default; the administrator must name one
    served = seeded.get(token, "/fleet/prior")
    assert served.json()["model"] == "KVH-1750"
    # a unit with no accepted version yet changes nothing the prior learns from
    assert served.headers["X-Fleet-Prior-Stale"] == "false"
    # the administrator has no model of its own
    assert seeded.get("admin-token-0123456789abcdef", "/fleet/prior").status_code == 404
    # a unit's view: the model's figures, and of the outliers none but itself (issue 37)
    assert served.json()["outliers"] == []
    client = _client(tmp_path, seeded, NEW_UNIT, token)
    try:
        assert client.step() == 60.0  # the outbox is empty: the prior is fetched
        path = client.prior_path
        prior = read_fleet_prior_file(str(path))
        assert (prior.model, prior.version) == ("KVH-1750", served.json()["version"])
        assert prior.coefficients["gyro.bias.bx"].units == 7  # the outlier unit set aside
        # not due again for hours; when due, the same version leaves the file alone
        stamp = os.stat(path).st_mtime_ns
        client.step()
        client._prior_due = 0.0
        client.step()
        assert os.stat(path).st_mtime_ns == stamp
    finally:
        client.store.close()

    # the daemon's settings: the gate takes the fetched file, unless [gate] names one
    sync = {"url": seeded.url, "unit": NEW_UNIT, "token": token}
    settings = Settings(state_dir=str(tmp_path / "state"), sync=sync)
    assert settings.gate_fleet_prior() == str(path)
    named = Settings(state_dir=str(tmp_path / "state"), sync=sync,
                     gate={"fleet_prior": str(tmp_path / "mine.json")})  # fmt: skip
    assert named.gate_fleet_prior() == str(tmp_path / "mine.json")
    off = Settings(state_dir=str(tmp_path / "state"), sync={**sync, "fleet_prior": False})
    assert off.gate_fleet_prior() is None


def test_no_prior_yet_writes_nothing(tmp_path, shore) -> None:
    token = shore.store.add_unit("DSP-1760-SN0001", "DSP-1760")
    client = _client(tmp_path, shore, "DSP-1760-SN0001", token)
    try:
        client.step()  # 404: the model has no unit with two accepted versions
        assert not client.prior_path.exists()
        assert client.stats.last_error is None  # not a link fault
    finally:
        client.store.close()
