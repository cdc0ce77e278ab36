"""Start-up checks: a setting the machine cannot honour is one line naming it, exit code 2."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import pytest

from recal.errors import RecalInputError
from service.config import load_settings
from service.startup import check_api_port, check_database, check_startup

DEPLOY_CONFIG = Path(__file__).resolve().parents[2] / "deploy" / "recal.toml"


def _serve(config: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "service.cli.main", "serve", "--config", str(config)],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip


def _config(tmp_path: Path, text: str) -> Path:
    cfg = tmp_path / "recal.toml"
    cfg.write_text(f'publish_path = "{tmp_path / "pub" / "c.json"}"\n' + text)
    return cfg


def test_sqlite_folder_missing_names_the_folder(tmp_path: Path) -> None:
    folder = tmp_path / "var" / "lib" / "recal"
    with pytest.raises(RecalInputError) as info:
        check_database(f"sqlite:///{folder / 'recal.db'}")
    assert str(info.value).startswith(f"database_url: the database folder {folder} does not exist")
    assert f"mkdir -p {folder}" in str(info.value)
    folder.mkdir(parents=True)
    check_database(f"sqlite:///{folder / 'recal.db'}")


def test_unreachable_database_server_is_one_line() -> None:
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(RecalInputError) as info:
        check_database(f"postgresql+psycopg://recal@127.0.0.1:{port}/recal", timeout_s=2)
    assert str(info.value).startswith("database_url: cannot open database postgresql+psycopg")
    assert "\n" not in str(info.value)


def test_port_in_use_names_the_setting() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        with pytest.raises(RecalInputError, match=rf"^\[api\] port {port} is already in use"):
            check_api_port("127.0.0.1", port)
    check_api_port("127.0.0.1", port)  # free again
    with pytest.raises(RecalInputError, match=r"^\[api\] host 10.255.255.1 is not an address"):
        check_api_port("10.255.255.1", 8750)


def test_missing_prior_file(tmp_path: Path) -> None:
    settings = load_settings(
        database_url=f"sqlite:///{tmp_path / 'r.db'}", prior_path=str(tmp_path / "nope.json")
    )
    with pytest.raises(RecalInputError, match="^prior_path: .*nope.json is not a file"):
        check_startup(settings)


@pytest.mark.slow
def test_serve_refuses_bad_settings_in_one_line_with_exit_2(tmp_path: Path) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        cases = {
            f'database_url = "sqlite:///{tmp_path}/missing/recal.db"\n': "database folder",
            f'database_url = "sqlite:///{tmp_path}/r.db"\n[api]\nport = {port}\n': f"port {port}",
            '[api]\nhost = "0.0.0.0"\n': "set [api] token",
            "[scheduler]\nmin_postions = 3\n": "unknown key min_postions",
        }
        for text, message in cases.items():
            done = _serve(_config(tmp_path, text))
            assert done.returncode == 2, done.stderr
            lines = done.stderr.strip().splitlines()
            assert len(lines) == 1 and message in lines[0], done.stderr
            assert lines[0].startswith("recal serve: error: ")


@pytest.mark.skipif(Path("/var/lib/recal").exists(), reason="this machine has /var/lib/recal")
def test_shipped_config_on_a_fresh_machine_names_the_folder_to_create() -> None:
    done = _serve(DEPLOY_CONFIG)
    assert done.returncode == 2
    assert done.stderr.strip() == (
        "recal serve: error: database_url: the database folder /var/lib/recal does not exist: "
        "create it (mkdir -p /var/lib/recal, owned by the service's user) or change database_url"
    )
