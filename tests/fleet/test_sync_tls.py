"""Sync over real TLS (issue 28, "over HTTP(S)"): the shore's API served by uvicorn with a
certificate from a private CA (made by trustme), and the vessel's ``recal sync`` trusting that
CA through ``SSL_CERT_FILE``, as the daemon's systemd unit sets it (docs/fleet.md, "TLS"). A
vessel that does not trust the certificate sends nothing and says why."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
import trustme

from service.cli.main import main
from service.fleet.config import ShoreApiSettings
from service.fleet.store import FleetStore
from service.store.repository import Store

SERIAL = "KVH-1750-SN0TLS"


@pytest.fixture
def tls_shore(tmp_path: Path, fleet_store: FleetStore, run_server) -> Iterator[tuple[str, Path]]:
    """(the shore's https:// URL, the PEM file of the CA that signed its certificate)."""
    import uvicorn

    from service.fleet.api import create_app

    ca = trustme.CA()
    issued = ca.issue_cert("127.0.0.1")
    key, chain, ca_pem = tmp_path / "shore.key", tmp_path / "shore.pem", tmp_path / "ca.pem"
    issued.private_key_pem.write_to_path(str(key))
    for k, pem in enumerate(issued.cert_chain_pems):
        pem.write_to_path(str(chain), append=k > 0)
    ca.cert_pem.write_to_path(str(ca_pem))
    app = create_app(fleet_store, ShoreApiSettings(token="admin-token-0123456789abcdef"))
    config = uvicorn.Config(app, host="127.0.0.1", port=0, log_level="warning",
                            ssl_keyfile=str(key), ssl_certfile=str(chain))  # fmt: skip
    with run_server(uvicorn.Server(config)) as port:
        yield f"https://127.0.0.1:{port}", ca_pem


def _vessel(tmp_path: Path, url: str, token: str) -> Path:
    """A vessel database with three events in its outbox, and its settings file."""
    db = tmp_path / "vessel.db"
    store = Store(f"sqlite:///{db}")
    store.create_schema()
    for k in range(3):
        store.add_event("start", f"event {k}")
    store.close()
    path = tmp_path / "recal.toml"
    path.write_text(f'database_url = "sqlite:///{db}"\nstate_dir = "{tmp_path / "state"}"\n'
                    f'[sync]\nurl = "{url}"\nunit = "{SERIAL}"\ntoken = "{token}"\n'
                    "interval_s = 1\nfleet_prior = false\n")  # fmt: skip
    return path


def _events_on_shore(store: FleetStore) -> list[str]:
    unit = store.unit_by_serial(SERIAL)
    assert unit is not None
    return [r["data"]["message"] for r in store.rows("event", unit, limit=10)]


def test_recal_sync_sends_over_tls_to_a_shore_whose_ca_it_trusts(
    tmp_path, tls_shore, fleet_store, monkeypatch, capsys
) -> None:
    url, ca_pem = tls_shore
    config = _vessel(tmp_path, url, fleet_store.add_unit(SERIAL, "KVH-1750"))
    monkeypatch.setenv("SSL_CERT_FILE", str(ca_pem))
    assert main(["sync", "--config", str(config), "--timeout", "30", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["rows_sent"] == 3 and summary["backlog"] == 0, summary
    assert _events_on_shore(fleet_store) == ["event 0", "event 1", "event 2"]


def test_an_untrusted_certificate_sends_nothing_and_says_why(
    tmp_path, tls_shore, fleet_store, monkeypatch, capsys
) -> None:
    url, _ = tls_shore
    config = _vessel(tmp_path, url, fleet_store.add_unit(SERIAL, "KVH-1750"))
    monkeypatch.delenv("SSL_CERT_FILE", raising=False)
    monkeypatch.delenv("SSL_CERT_DIR", raising=False)
    assert main(["sync", "--config", str(config), "--timeout", "2", "--json"]) == 1
    out = capsys.readouterr()
    summary = json.loads(out.out)
    assert summary["rows_sent"] == 0 and summary["backlog"] == 3, summary
    assert "TLS with 127.0.0.1:" in summary["last_error"], summary["last_error"]
    assert "CERTIFICATE_VERIFY_FAILED" in summary["last_error"], summary["last_error"]
    assert _events_on_shore(fleet_store) == []
