"""The administrator's token is never written in shore.toml (issue 37): it comes from a file
(``[api] token_file``, systemd's LoadCredential=), the environment (``RECAL_API__TOKEN``), or
only its sha256 (``[api] token_sha256``). A plain ``[api] token`` in the file still works for
one release, with a warning."""

from __future__ import annotations

import hashlib
import logging

import pytest
from fastapi.testclient import TestClient

from recal.errors import RecalInputError
from service.cli.main import main
from service.fleet.api import create_app
from service.fleet.config import load_shore_settings
from service.fleet.store import FleetStore

ADMIN = "admin-token-0123456789abcdef"


def _toml(tmp_path, api: str) -> str:
    path = tmp_path / "shore.toml"
    path.write_text(f'database_url = "sqlite:///{tmp_path / "fleet.db"}"\n[api]\n{api}')
    return str(path)


def _admin_reads(tmp_path, settings) -> int:
    """The status the administrator's token gets from GET /fleet/units on these settings."""
    store = FleetStore(settings.database_url)
    store.create_schema()
    try:
        # the app in a client of its own thread: a worker whose event loop another test left
        # running cannot asyncio.run() (seen under CI)
        with TestClient(create_app(store, settings.api), base_url="http://shore") as c:
            r = c.get("/fleet/units", headers={"Authorization": f"Bearer {ADMIN}"})
            wrong = c.get("/fleet/units", headers={"Authorization": "Bearer x" * 3})
        assert wrong.status_code == 401
        return r.status_code
    finally:
        store.close()


def test_the_token_comes_from_a_file_the_environment_or_its_hash(
    tmp_path, monkeypatch, caplog
) -> None:
    caplog.set_level(logging.WARNING, "recal.fleet")
    (tmp_path / "admin-token").write_text(ADMIN + "\n")  # as systemd-creds or echo write it
    digest = hashlib.sha256(ADMIN.encode()).hexdigest()
    ways = [
        f'host = "0.0.0.0"\ntoken_file = "{tmp_path / "admin-token"}"\n',
        f'host = "0.0.0.0"\ntoken_sha256 = "{digest.upper()}"\n',
        'host = "0.0.0.0"\n',  # with RECAL_API__TOKEN below
    ]
    for api in ways:
        with monkeypatch.context() as env:
            if "token" not in api:
                env.setenv("RECAL_API__TOKEN", ADMIN)
            settings = load_shore_settings(_toml(tmp_path, api))
        assert settings.api.has_admin
        assert _admin_reads(tmp_path, settings) == 200, api
        assert ADMIN not in repr(settings) and ADMIN not in str(settings.model_dump())
    assert not caplog.records  # none of them is deprecated
    # RECAL_API__TOKEN_FILE too, as every key
    monkeypatch.setenv("RECAL_API__TOKEN_FILE", str(tmp_path / "admin-token"))
    assert load_shore_settings(_toml(tmp_path, 'host = "0.0.0.0"\n')).api.is_admin(ADMIN)


def test_a_token_in_the_file_still_works_and_warns(tmp_path, caplog) -> None:
    caplog.set_level(logging.WARNING, "recal.fleet")
    settings = load_shore_settings(_toml(tmp_path, f'token = "{ADMIN}"\n'))
    assert _admin_reads(tmp_path, settings) == 200
    (record,) = caplog.records
    assert "[api] token in the file is deprecated" in record.getMessage()
    assert "token_file" in record.getMessage() and "0.4.0" in record.getMessage()


@pytest.mark.parametrize(
    ("api", "says"),
    [
        ('token_file = "/nonexistent/admin-token"\n', "token_file /nonexistent/admin-token cannot"),
        ('token_file = "{short}"\n', "at least 16 characters"),
        ('token_sha256 = "abc"\n', "64 hex digits"),
        (f'token = "{ADMIN}"\ntoken_sha256 = "{"0" * 64}"\n', "token and token_sha256 are set"),
        ('host = "0.0.0.0"\n', "token_file, token_sha256 or RECAL_API__TOKEN"),
    ],
)
def test_a_bad_token_setting_is_one_line(tmp_path, capsys, api, says) -> None:
    (tmp_path / "short").write_text("short\n")
    path = _toml(tmp_path, api.replace("{short}", str(tmp_path / "short")))
    with pytest.raises(RecalInputError, match="api"):
        load_shore_settings(path)
    assert main(["fleet", "add-unit", "SN-1", "--config", path]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and says in err, err
