"""The systemd watchdog as documented: petted only while every part of the daemon lives.

A real daemon (uvicorn over HTTP, the replay reader, the job supervisor, the publisher) and the
daemon's own housekeeping loop send their notifications to a real notify socket, a Unix datagram
socket that NOTIFY_SOCKET names, as systemd's would. Each part is stopped in turn: the
watchdog must stop being petted, ``/health`` (or, for the API itself, the daemon's health
object) must name that part and no other, and systemd's STATUS line must name it too. Nothing
here asserts a duration: every wait polls with a generous deadline and asserts on content.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx
import pytest

from recal.sim.session import simulate_session
from service.capture_sim import kvh_like_truth, session_to_kvh
from service.config import (
    ApiSettings,
    DetectorSettings,
    DeviceSettings,
    SchedulerSettings,
    Settings,
)
from service.daemon import Housekeeping

RATE_HZ = 100.0
#: Generous deadline of every wait, s (nothing is timed: this only bounds a hang).
DEADLINE_S = 60.0
#: The housekeeping loop's tick and watchdog period in these tests, s (1 s and 5 s in service).
TICK_S, WATCHDOG_S = 0.05, 0.1


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A KVH capture, replayed in real time and looped so the reader never goes silent."""
    session = simulate_session(kvh_like_truth(3), "24", seed=3, rate_hz=RATE_HZ, window_s=5.0,
                               slew_s=2.0)  # fmt: skip
    path = tmp_path_factory.mktemp("watchdog") / "capture.bin"
    path.write_bytes(session_to_kvh(session, rng=3)[0])
    return path


def _settings(tmp_path: Path, capture: Path) -> Settings:
    return Settings(
        database_url=f"sqlite:///{tmp_path / 'r.db'}",
        publish_path=str(tmp_path / "c.json"),
        device=DeviceSettings(
            url=f"replay://{capture}?speed=1&rate=100&eof=loop", rate_hz=RATE_HZ
        ),  # fmt: skip
        detector=DetectorSettings(accel_threshold=1e-3, gyro_threshold=1e2),  # nothing to learn
        scheduler=SchedulerSettings(min_positions=1000, min_new_positions=1000),  # no job
        api=ApiSettings(port=0),
    )


def _wait_for(condition: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + DEADLINE_S
    while not condition():
        assert time.monotonic() < deadline, f"{what}: not within {DEADLINE_S} s"
        time.sleep(0.02)


def _checks_after(keeper: Housekeeping, n: int) -> None:
    """Wait until the housekeeping loop has made ``n`` more liveness checks."""
    target = keeper.checks + n
    _wait_for(lambda: keeper.checks >= target, f"{n} watchdog checks")


def _hang_event_loop(server: Any, release: threading.Event) -> None:
    """Block the API's event loop until ``release``, as a blocking call in a handler would."""

    async def block() -> None:
        release.wait(DEADLINE_S)

    asyncio.run_coroutine_threadsafe(block(), server.servers[0].get_loop())


def _end_event_loop(server: Any) -> None:
    """Stop the API's event loop under uvicorn's feet, as a crash would: no stop was asked."""
    loop = server.servers[0].get_loop()
    loop.call_soon_threadsafe(loop.stop)


#: How each part is stopped: the thread ends, the supervisor leaves its loop, the publisher
#: closes (every /events stream ends), the HTTP server's event loop ends or hangs.
STOPS: dict[str, Callable[[Any, threading.Event], None]] = {
    "reader": lambda service, _: service.reader.stop(),
    "scheduler": lambda service, _: service.scheduler._runner._requests.put(None),
    "publisher": lambda service, _: service.publisher.close(),
    "api-ended": lambda service, _: _end_event_loop(service.server),
    "api-hung": lambda service, release: _hang_event_loop(service.server, release),
}


@contextmanager
def _housekeeping(service: Any) -> Iterator[Housekeeping]:
    """The daemon's housekeeping loop (what ``run_daemon`` runs) on ``service``, fast."""
    stop = threading.Event()
    keeper = Housekeeping(service, stop, tick_s=TICK_S, watchdog_s=WATCHDOG_S)
    thread = threading.Thread(target=keeper.run, name="housekeeping", daemon=True)
    thread.start()
    try:
        yield keeper
    finally:
        stop.set()
        thread.join(DEADLINE_S)


@pytest.mark.parametrize(
    "how",
    [
        pytest.param(how, marks=pytest.mark.filterwarnings(
            "ignore::pytest.PytestUnhandledThreadExceptionWarning"))  # the crash, as wanted
        if how == "api-ended" else how
        for how in STOPS
    ],
)  # fmt: skip
@pytest.mark.slow
def test_a_dead_part_stops_the_watchdog_and_health_names_it(
    how: str, tmp_path: Path, capture: Path, systemd: Any, serve: Callable
) -> None:
    part = how.split("-")[0]
    release = threading.Event()
    with serve(_settings(tmp_path, capture)) as (base_url, service):
        service.reader.start()
        with _housekeeping(service) as keeper:
            try:
                with httpx.Client(base_url=base_url, timeout=DEADLINE_S) as http:
                    # all parts live: READY=1, the watchdog is petted and nothing is dead
                    assert systemd.wait_for(b"READY=1") == [b"READY=1"]
                    assert set(systemd.wait_for(b"WATCHDOG=1")) == {b"READY=1", b"WATCHDOG=1"}
                    health = http.get("/health").json()
                    assert health["service"]["dead_parts"] == []
                    assert not any(p.startswith(f"{part}: ") for p in health["problems"])

                    STOPS[how](service, release)

                    # health names the part, and only it (the daemon's own object for the API:
                    # once the API is down, /health cannot answer)
                    _wait_for(lambda: service.dead_parts().keys() == {part}, f"{part} dead")
                    health = service.health() if part == "api" else http.get("/health").json()
                    parts = health if part == "api" else health["service"]
                    assert health["status"] == "degraded"
                    assert parts["dead_parts"] == [part]
                    assert any(p.startswith(f"{part}: ") for p in health["problems"])
                # a check begun before the death may still pet: from the next one on, none may
                _checks_after(keeper, 1)
                fed, mark = keeper.fed, len(systemd.messages)
                _checks_after(keeper, 10)
                after = systemd.since(mark)
                assert b"WATCHDOG=1" not in after, after  # ten checks, no petting
                assert keeper.fed == fed
            finally:
                release.set()
        # systemd is told which part died (``systemctl status`` shows the STATUS line)
        status = [m.decode() for m in systemd.messages if m.startswith(b"STATUS=")]
        assert len(status) == 1 and status[0].startswith("STATUS=not petting"), status
        assert f": {part}: " in status[0], status
        logged = service.store.last_event("watchdog")
        assert logged is not None and logged["data"]["dead"] == part


def test_a_part_that_lives_but_fails_keeps_the_watchdog_petted(
    tmp_path: Path, capture: Path, systemd: Any, serve: Callable, make_record: Callable
) -> None:
    """An unwritable publish file is degraded with the reason, but a restart would not mend
    it: the watchdog goes on being petted."""
    with serve(_settings(tmp_path, capture)) as (base_url, service):
        service.store.add_calibration(make_record())
        (tmp_path / "c.json").mkdir()  # the file cannot be written
        service.sync_published()
        assert service.publisher.error is not None
        service.reader.start()
        with _housekeeping(service) as keeper:
            systemd.wait_for(b"READY=1")
            health = httpx.get(f"{base_url}/health", timeout=DEADLINE_S).json()
            assert health["status"] == "degraded"
            assert any(p.startswith("publisher: cannot write") for p in health["problems"])
            assert health["service"]["dead_parts"] == []
            fed, mark = keeper.fed, len(systemd.messages)
            _checks_after(keeper, 3)
            assert keeper.fed >= fed + 3
            assert set(systemd.since(mark)) == {b"WATCHDOG=1"}
