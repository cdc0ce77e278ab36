"""``recal fleet add-unit`` and ``recal fleet serve`` (docs/fleet.md): the token alone
on one line of stdout, exit codes of the CLI contract, a real shore process stopped cleanly."""

from __future__ import annotations

import gzip
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from service.cli.main import main
from service.fleet.store import FleetStore

ADMIN = "admin-token-0123456789abcdef"


def shore_toml(tmp_path: Path, url: str, port: int = 8760, **api: str) -> Path:
    """A shore.toml whose administrator's token is in a file beside it (as systemd's
    LoadCredential= gives it), never in the file itself."""
    path = tmp_path / "shore.toml"
    (tmp_path / "admin-token").write_text(ADMIN + "\n")
    extra = "".join(f'{k} = "{v}"\n' for k, v in api.items())
    path.write_text(f'database_url = "{url}"\n\n[api]\nport = {port}\n'
                    f'token_file = "{tmp_path / "admin-token"}"\n{extra}')  # fmt: skip
    return path


def test_add_unit_prints_its_token_alone(tmp_path, fleet_url, capsys) -> None:
    config = str(shore_toml(tmp_path, fleet_url))
    assert main(["fleet", "add-unit", "KVH-1750-SN0042", "--config", config,
                 "--model", "KVH-1750"]) == 0  # fmt: skip
    out = capsys.readouterr()
    lines = out.out.splitlines(keepends=True)
    assert len(lines) == 1 and lines[0].endswith("\n")
    token = lines[0].strip()
    assert len(token) >= 43 and " " not in token
    assert "KVH-1750-SN0042" in out.err
    store = FleetStore(fleet_url)
    try:
        unit = store.unit_of_token(token)
        assert unit is not None and (unit.serial, unit.model) == ("KVH-1750-SN0042", "KVH-1750")
        # again: a clear one-line error, exit code 2, nothing on stdout, the token unchanged
        assert main(["fleet", "add-unit", "KVH-1750-SN0042", "--config", config]) == 2
        out = capsys.readouterr()
        assert out.out == ""
        assert out.err.count("\n") == 1 and "already registered" in out.err
        assert store.unit_of_token(token) is not None
        # --rotate: a new token, the old one refused
        assert main(["fleet", "add-unit", "KVH-1750-SN0042", "--rotate", "--config", config]) == 0
        new = capsys.readouterr().out.strip()
        assert new != token and store.unit_of_token(token) is None
        assert store.unit_of_token(new).serial == "KVH-1750-SN0042"
    finally:
        store.close()


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["fleet", "add-unit", "bad serial"], "serial 'bad serial'"),
        (["fleet", "add-unit", "SN-1", "--rotate"], "not registered"),
        (["fleet", "add-unit", "SN-1", "--config", "/nonexistent/shore.toml"], "does not exist"),
    ],
)
def test_bad_input_is_one_line_and_exit_code_2(tmp_path, argv, says, capsys) -> None:
    if "--config" not in argv:
        argv = [*argv, "--config", str(shore_toml(tmp_path, f"sqlite:///{tmp_path / 'f.db'}"))]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and says in err and "Traceback" not in err


def test_shore_settings_are_checked(tmp_path, monkeypatch, capsys) -> None:
    url = f"sqlite:///{tmp_path / 'f.db'}"
    cases = [
        ('database_url = "x"\n[api]\nhost = "0.0.0.0"\n', "reachable from other machines"),
        (f'database_url = "{url}"\n[api]\ntoken = "short"\n', "at least 16 characters"),
        (f'database_url = "{url}"\nlatitude = 3\n', "unknown key latitude"),
        ("[api]\nport = 1\n", "database_url"),
        ('database_url = "nonsense"\n', "bad database URL"),
    ]
    for text, says in cases:
        path = tmp_path / "s.toml"
        path.write_text(text)
        assert main(["fleet", "add-unit", "SN-1", "--config", str(path)]) == 2, text
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and says in err, err
    # the environment overrides the file, as on the vessel
    (tmp_path / "s.toml").write_text("[api]\nport = 1\n")
    monkeypatch.setenv("RECAL_DATABASE_URL", url)
    assert main(["fleet", "add-unit", "SN-1", "--config", str(tmp_path / "s.toml")]) == 0
    assert len(capsys.readouterr().out.split()) == 1


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_fleet_serve_runs_the_migrations_serves_and_stops_cleanly(tmp_path) -> None:
    port = _free_port()
    url = f"sqlite:///{tmp_path / 'fleet.db'}"
    config = shore_toml(tmp_path, url, port)
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "service.cli.main", "fleet", "serve", "--config", str(config),
         "--log-level", "WARNING"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
    )  # fmt: skip
    try:
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 60
        while True:
            assert proc.poll() is None, proc.communicate()[1].decode()
            assert time.monotonic() < deadline, "recal fleet serve did not start"
            try:
                httpx.get(f"{base}/openapi.json", timeout=1)
                break
            except httpx.TransportError:
                time.sleep(0.1)
        # the schema was made at start: a unit added now sends at once
        store = FleetStore(url)
        token = store.add_unit("SN-1")
        store.close()
        body = {"format": 1, "unit": "SN-1", "rows": [
            {"kind": "event", "id": 1, "at": "2026-11-27T00:00:00Z",
             "data": {"kind": "started", "message": "", "data": {}}}]}  # fmt: skip
        r = httpx.post(f"{base}/fleet/ingest", content=gzip.compress(json.dumps(body).encode()),
                       headers={"Authorization": f"Bearer {token}", "Content-Encoding": "gzip",
                                "Content-Type": "application/json"})  # fmt: skip
        assert r.json() == {"stored": 1, "duplicates": 0, "conflicts": 0}
        units = httpx.get(f"{base}/fleet/units", headers={"Authorization": f"Bearer {ADMIN}"})
        assert [u["unit"] for u in units.json()] == ["SN-1"]
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err.decode()


def test_reanalyse_prints_json_and_says_what_it_did(tmp_path, capsys) -> None:
    url = f"sqlite:///{tmp_path / 'fleet.db'}"
    config = str(shore_toml(tmp_path, url))
    assert main(["fleet", "add-unit", "SN-1", "--config", config, "--model", "M"]) == 0
    capsys.readouterr()
    out = tmp_path / "re.json"
    assert main(["fleet", "reanalyse", "--config", config, "--workers", "1", "-o", str(out)]) == 0
    report = json.loads(out.read_text())
    assert [u["unit"] for u in report["units"]] == ["SN-1"] and report["workers"] == 1
    assert report["units"][0]["versions"] == 0 and report["units"][0]["drift"] is None
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "re-analysed 1 units on 1 process(es)" in err
    assert main(["fleet", "reanalyse", "--config", config, "--workers", "0"]) == 2
