"""Fleet sync in the daemon: a ``[sync]`` section starts the sync thread beside the reader,
``/health`` shows the link, the stored settings keep no token, and stopping the daemon does
not wait on a dead link. Also the ``[sync]`` settings' checks."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import httpx
import pytest

from recal.errors import RecalInputError
from service.config import Settings, SyncSettings, load_settings


def wait_for(predicate: Any, timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


def settings_for(tmp_path: Path, shore: Any) -> Settings:
    return Settings(
        database_url=f"sqlite:///{tmp_path / 'recal.db'}",
        publish_path=str(tmp_path / "coefficients.json"),
        api={"port": 0},
        sync=SyncSettings(url=shore.url, unit=shore.unit, token=shore.token, interval_s=60),
    )


def test_the_daemon_syncs_and_stops_without_waiting_on_the_link(
    tmp_path: Path, shore: Any, serve: Any
) -> None:
    with serve(settings_for(tmp_path, shore)) as (base, service):
        service.sync.start()  # as run_daemon does, with the reader
        wait_for(lambda: service.store.outbox_count() == 0 and shore.rows("event"))
        sync = httpx.get(f"{base}/health", timeout=10).json()["sync"]
        assert sync["state"] == "up" and sync["unit"] == shore.unit and sync["backlog"] == 0
        assert "sync" not in service.dead_parts()
        (session,) = [d for k, _, d in shore.rows("session")]
        assert (
            session["meta"]["sync"]["url"] == shore.url and "token" not in session["meta"]["sync"]
        )
        assert shore.token not in str(shore.rows())

        shore.mode = "hang"  # the link dies with a request in flight
        service.events.emit("test", "one more row")
        service.sync.poke()
        wait_for(lambda: shore.requests[-1]["status"] is None)
        started = time.monotonic()
    assert time.monotonic() - started < 5.0  # the whole shutdown, the sync thread's part aborted
    assert not service.sync.alive


def test_a_dead_sync_thread_is_a_dead_part(tmp_path: Path, shore: Any, serve: Any) -> None:
    with serve(settings_for(tmp_path, shore)) as (_, service):
        service.sync.run = lambda: None  # a thread that ends at once (a bug)
        service.sync.start()
        wait_for(lambda: not service.sync.alive)
        assert service.dead_parts()["sync"] == "the fleet sync thread has stopped"


def test_without_a_sync_section_there_is_no_sync_thread(tmp_path: Path, serve: Any) -> None:
    settings = Settings(database_url=f"sqlite:///{tmp_path / 'recal.db'}",
                        publish_path=str(tmp_path / "c.json"), api={"port": 0})  # fmt: skip
    with serve(settings) as (base, service):
        assert service.sync is None
        sync = httpx.get(f"{base}/health", timeout=10).json()["sync"]
        assert sync["state"] == "off" and sync["backlog"] >= 2  # the session and its start event


@pytest.mark.parametrize(
    "body, message",
    [
        ('url = "https://shore.example:8443"\n', "sync: url, unit and token go together "
         "(missing: unit, token; the token may come from RECAL_SYNC__TOKEN)"),
        ('url = "http://shore.example"\nunit = "U1"\ntoken = "t0k"\n',
         "sync.url: 'http://shore.example' would send the token in clear"),
        ('url = "shore.example"\nunit = "U1"\ntoken = "t0k"\n', "is not a URL like https://"),
        ('url = "https://s.example"\nunit = "U1"\ntoken = "t0k"\ninterval_s = 0\n',
         "sync.interval_s: Input should be greater than 0"),
        ('url = "https://s.example"\nunit = "SN 42"\ntoken = "t0k"\n',
         "sync.unit: 'SN 42': a serial is 1 to 64 letters, digits"),
        ('urls = "https://s.example"\n', "sync: unknown key urls (known: url, unit, token, "
         "interval_s)"),
    ],
)  # fmt: skip
def test_bad_sync_settings_are_one_line(
    tmp_path: Path, body: str, message: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("RECAL_SYNC__TOKEN", raising=False)
    path = tmp_path / "recal.toml"
    path.write_text("[sync]\n" + body, encoding="utf-8")
    with pytest.raises(RecalInputError) as err:
        load_settings(path)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_sync_settings_from_the_file_and_the_environment(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("RECAL_SYNC__TOKEN", raising=False)
    assert not load_settings().sync.enabled  # no [sync] section: no sync
    path = tmp_path / "recal.toml"
    path.write_text('[sync]\nurl = "https://shore.example:8443/"\nunit = "KVH-1750-SN0042"\n',
                    encoding="utf-8")  # fmt: skip
    monkeypatch.setenv("RECAL_SYNC__TOKEN", "from-the-environment")
    sync = load_settings(path).sync
    assert sync.enabled and sync.url == "https://shore.example:8443" and sync.interval_s == 60
    assert sync.token.get_secret_value() == "from-the-environment"
    assert "from-the-environment" not in repr(sync)
    loopback = SyncSettings(url="http://127.0.0.1:8443", unit="U", token="t")  # a local tunnel
    assert loopback.enabled
