"""Every file the daemon writes by default goes under one state folder (issue 27): ``state_dir``,
else ``$STATE_DIRECTORY`` (systemd's ``StateDirectory=``), else the user's state folder; never
the working folder. Paths given explicitly stay as they are."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from recal.sim.session import simulate_session
from service.capture_sim import kvh_like_truth, session_to_kvh
from service.config import DeviceSettings, Settings, default_state_dir, load_settings
from service.daemon import build_service
from service.startup import prepare_state_dir, spool_folder


def test_the_default_state_dir_is_systemds_then_the_users(tmp_path, monkeypatch) -> None:
    systemd = {"STATE_DIRECTORY": "/var/lib/recal:/var/lib/other", "XDG_STATE_HOME": "/x"}
    assert default_state_dir(systemd) == Path("/var/lib/recal")  # the first of several
    assert default_state_dir({"XDG_STATE_HOME": "/home/u/.st"}) == Path("/home/u/.st/recal")
    monkeypatch.setenv("HOME", str(tmp_path))
    home = tmp_path / ".local" / "state" / "recal"
    assert default_state_dir({"XDG_STATE_HOME": "relative"}) == home  # the spec ignores it
    assert default_state_dir({}) == home


def test_unset_paths_go_under_the_state_dir_and_given_ones_stay(tmp_path, monkeypatch) -> None:
    state = tmp_path / "state"
    s = Settings(state_dir=str(state))
    assert s.database_url == f"sqlite:///{state / 'recal.db'}"
    assert s.publish_path == str(state / "coefficients.json")
    assert spool_folder(s) == state / "recal.db.spool"
    # the case: a database server's spool was ./recal-spool/... in the working folder
    pg = Settings(state_dir=str(state), database_url="postgresql+psycopg://u:pw@db:5433/recal")
    assert spool_folder(pg) == state / "spool" / "db_5433_recal"
    # the environment: STATE_DIRECTORY (as systemd sets it), overridden by RECAL_STATE_DIR
    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path / "unit"))
    assert Settings().database_url == f"sqlite:///{tmp_path / 'unit' / 'recal.db'}"
    monkeypatch.setenv("RECAL_STATE_DIR", str(tmp_path / "env"))
    assert Settings().state_dir == str(tmp_path / "env")
    monkeypatch.delenv("RECAL_STATE_DIR")
    # the TOML file's top-level key; explicit paths, relative ones too, are kept as given
    cfg = tmp_path / "recal.toml"
    cfg.write_text(f'state_dir = "{tmp_path / "file"}"\npublish_path = "out/c.json"\n')
    s = load_settings(cfg)
    assert s.state_dir == str(tmp_path / "file") and s.publish_path == "out/c.json"
    assert s.database_url == f"sqlite:///{tmp_path / 'file' / 'recal.db'}"
    given = Settings(database_url="sqlite:///x.db", publish_path="c.json", spool_dir="sp")
    assert (given.database_url, given.publish_path, spool_folder(given)) == (
        "sqlite:///x.db", "c.json", Path("sp"))  # fmt: skip
    # the state folder is made only when something is written in it
    elsewhere = Settings(state_dir=str(state), database_url=f"sqlite:///{tmp_path / 'r.db'}",
                         publish_path=str(tmp_path / "c.json"))  # fmt: skip
    assert prepare_state_dir(elsewhere) is None and not state.exists()
    assert prepare_state_dir(s) == tmp_path / "file" and (tmp_path / "file").is_dir()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_recal_serve_writes_nothing_in_its_working_folder(tmp_path) -> None:
    """`recal serve` started in an empty folder with a configuration that names no path: the
    database, its spool (and the published file, once there is one) land in STATE_DIRECTORY,
    which it creates; the folder it was started from stays empty."""
    session = simulate_session(kvh_like_truth(4), "24", latitude_deg=45.0, seed=4, rate_hz=100.0,
                               window_s=6.0, slew_s=2.0, first_hold_s=8.0)  # fmt: skip
    capture = tmp_path / "capture.bin"
    capture.write_bytes(session_to_kvh(session, rng=4)[0])
    port = _free_port()
    config = tmp_path / "recal.toml"
    config.write_text(f'[device]\nurl = "replay://{capture}?speed=max&rate=100"\nrate_hz = 100\n'
                      f"[scheduler]\nmin_positions = 1000\n[api]\nport = {port}\n")  # fmt: skip
    work, state = tmp_path / "work", tmp_path / "state" / "recal"
    work.mkdir()
    env = {**os.environ, "STATE_DIRECTORY": str(state)}
    env.pop("NOTIFY_SOCKET", None)
    proc = subprocess.Popen(
        [sys.executable, "-m", "service.cli.main", "serve", "--config", str(config),
         "--log-level", "WARNING"],
        cwd=work, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=10) as http:
            while True:  # the replay ends: learning ends and every hold is stored
                assert proc.poll() is None, proc.communicate()[1]
                assert time.monotonic() < deadline, "the daemon did not store the holds"
                try:
                    health = http.get("/health").json()
                except httpx.TransportError:  # not serving yet
                    health = None
                if health is not None and health["positions"] == session.n_holds:
                    break
                time.sleep(0.2)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 0, err
    finally:
        if proc.poll() is None:
            proc.kill()
    assert sorted(os.listdir(work)) == []
    assert {"recal.db", "recal.db.spool"} <= set(os.listdir(state))
    assert health["service"]["spool"]["dir"] == str(state / "recal.db.spool")
    assert health["service"]["publisher"]["path"] == str(state / "coefficients.json")


def test_with_a_database_server_the_spool_is_in_the_state_dir(
    tmp_path, monkeypatch, pg_database
) -> None:
    """The issue's case, in process: a PostgreSQL URL and no spool_dir left ./recal-spool/ in
    the working folder; now the spool is STATE_DIR/spool/HOST_PORT_DB."""
    _, url = pg_database
    work, state = tmp_path / "work", tmp_path / "state"
    work.mkdir()
    monkeypatch.chdir(work)
    monkeypatch.setenv("STATE_DIRECTORY", str(state))
    service = build_service(Settings(database_url=url, device=DeviceSettings(url="replay://x")),
                            with_reader=False)  # fmt: skip
    try:
        spool = Path(service.health()["spool"]["dir"])
        assert spool.parent == state / "spool" and spool.is_dir()
        assert service.publisher.path == state / "coefficients.json"
    finally:
        service.close(wait_s=0)
    assert os.listdir(work) == []


@pytest.mark.parametrize("explicit", [False, True])
def test_a_state_dir_that_cannot_be_made_is_one_line(tmp_path, explicit) -> None:
    from recal.errors import RecalInputError
    from service.startup import check_startup

    (tmp_path / "file").write_text("x")
    blocked = tmp_path / "file" / "state"
    settings = Settings(state_dir=str(blocked), api={"port": 0})
    if explicit:  # every path given elsewhere: the state folder is not needed
        settings = Settings(state_dir=str(blocked), database_url=f"sqlite:///{tmp_path / 'r.db'}",
                            publish_path=str(tmp_path / "c.json"), api={"port": 0})  # fmt: skip
        check_startup(settings)
        return
    with pytest.raises(RecalInputError, match=rf"^state_dir {blocked} cannot be created"):
        check_startup(settings)
