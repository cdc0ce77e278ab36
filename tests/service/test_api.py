"""The HTTP API: REST endpoints through TestClient, SSE through TestClient and a real uvicorn."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import uvicorn
from fastapi.testclient import TestClient

from recal.model.coefficients import CoefficientSet
from recal.sim.simulate import simulate_positions
from service.api import create_app
from service.config import ApiSettings
from service.publish import Publisher
from service.store.records import CalibrationRecord
from service.store.repository import Store

MakeRecord = Callable[..., CalibrationRecord]
TOKEN = "test-token-0123456789abcdef"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture
def publisher(tmp_path: Path) -> Publisher:
    return Publisher(tmp_path / "published" / "coefficients.json")


@pytest.fixture
def client(sqlite_store: Store, publisher: Publisher) -> TestClient:
    return TestClient(create_app(sqlite_store, publisher, health=lambda: {"frames": 12}))


def wait_until(condition: Callable[[], bool], timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def test_health_counts_positions_and_current_version(
    client: TestClient, sqlite_store: Store, make_record: MakeRecord
) -> None:
    assert client.get("/health").json() == {
        "status": "ok",
        "problems": [],
        "positions": 0,
        "current_version": None,
        "sync": {
            "state": "off",
            "url": None,
            "unit": None,
            "backlog": 0,
            "last_contact": None,
            "last_error": None,
            "bytes_today": 0,
            "bytes_per_day": [],
        },  # fmt: skip
        "service": {"frames": 12},
    }
    sid = sqlite_store.add_session("sim")
    sqlite_store.add_positions(sid, simulate_positions(CoefficientSet.seed_truth()).columns)
    version = sqlite_store.add_calibration(make_record())
    body = client.get("/health").json()
    assert body["positions"] == 24 and body["current_version"] == version


def test_coefficients_current_history_and_version(
    client: TestClient, sqlite_store: Store, make_record: MakeRecord, document: dict
) -> None:
    assert client.get("/coefficients").status_code == 404
    v1 = sqlite_store.add_calibration(make_record(positions_used=[4, 5]))
    v2 = sqlite_store.add_calibration(make_record(accepted=False, reasons=["too far"]))

    current = client.get("/coefficients")
    assert current.status_code == 200
    body = current.json()
    assert body["version"] == v1 and body["accepted"] and body["positions_used"] == [4, 5]
    assert body["document"]["coefficients"] == document["coefficients"]

    history = client.get("/coefficients/history", params={"limit": 1}).json()
    assert [r["version"] for r in history] == [v2] and history[0]["reasons"] == ["too far"]
    assert "document" not in history[0] and history[0]["chi2_red"] == document["chi2_red"]
    assert len(client.get("/coefficients/history").json()) == 2
    full = client.get("/coefficients/history", params={"full": True}).json()
    assert [r["version"] for r in full] == [v2, v1] and full[1]["positions_used"] == [4, 5]
    assert client.get(f"/coefficients/{v2}").json()["accepted"] is False
    missing = client.get("/coefficients/999")
    assert missing.status_code == 404 and missing.json() == {"detail": "no calibration version 999"}
    assert client.get("/coefficients/history", params={"limit": 0}).status_code == 422


def test_positions_as_rows(client: TestClient, sqlite_store: Store) -> None:
    cols = dict(simulate_positions(CoefficientSet.seed_truth(), sensors=("gyro",)).columns)
    sid = sqlite_store.add_session("sim")
    ids = sqlite_store.add_positions(sid, cols)
    rows = client.get("/positions", params={"limit": 2, "since_id": ids[0]}).json()
    assert [r["id"] for r in rows] == ids[1:3]
    assert rows[0]["gyro_x"] == cols["gyro_x"][1] and "accel_x" not in rows[0]
    assert len(client.get("/positions").json()) == 24


def test_recalibrate_queues_conflicts_or_is_unavailable(
    sqlite_store: Store, publisher: Publisher
) -> None:
    answers: list[int | None | Exception] = [17, None, RuntimeError("shutting down")]

    def trigger() -> int | None:
        answer = answers.pop(0)
        if isinstance(answer, Exception):
            raise answer
        return answer

    api = ApiSettings(token=TOKEN)
    with TestClient(create_app(sqlite_store, publisher, trigger=trigger, api=api)) as client:
        queued = client.post("/recalibrate", headers=AUTH)
        assert queued.status_code == 202 and queued.json() == {"queued": True, "job": 17}
        busy = client.post("/recalibrate", headers=AUTH)
        assert busy.status_code == 409 and "already running" in busy.json()["detail"]
        refused = client.post("/recalibrate", headers=AUTH)
        assert refused.status_code == 409 and refused.json() == {"detail": "shutting down"}
    without = TestClient(create_app(sqlite_store, publisher, api=api))
    assert without.post("/recalibrate", headers=AUTH).status_code == 503


def test_store_failure_is_503(tmp_path: Path, publisher: Publisher) -> None:
    unprepared = Store(f"sqlite:///{tmp_path / 'no_schema.db'}")  # create_schema never ran
    response = TestClient(create_app(unprepared, publisher)).get("/coefficients")
    assert response.status_code == 503 and "no such table" in response.json()["detail"]


def test_openapi_lists_the_endpoints(client: TestClient) -> None:
    paths = client.get("/openapi.json").json()["paths"]
    assert {"/health", "/coefficients", "/coefficients/{version}", "/events"} <= set(paths)
    assert client.get("/docs").status_code == 200


def test_sse_stream_with_heartbeat_ends_when_publisher_closes(
    sqlite_store: Store, publisher: Publisher, make_record: MakeRecord
) -> None:
    app = create_app(sqlite_store, publisher, heartbeat_s=0.05)

    def publish_then_close() -> None:
        wait_until(lambda: publisher.subscriber_count == 1)
        publisher.publish(make_record(version=1))
        time.sleep(0.3)  # idle: heartbeats
        publisher.publish(make_record(version=2))
        publisher.close()

    thread = threading.Thread(target=publish_then_close)
    thread.start()
    # TestClient buffers the whole body: the stream must end by itself when the publisher closes.
    response = TestClient(app).get("/events")
    thread.join()
    assert response.headers["content-type"].startswith("text/event-stream")
    events = parse_sse(response.text)
    assert [e["data"]["version"] for e in events if e.get("event") == "coefficients"] == [1, 2]
    assert ": heartbeat" in response.text.split("event: coefficients")[1]
    assert publisher.subscriber_count == 0


def parse_sse(text: str) -> list[dict[str, Any]]:
    """Events of an SSE body: field name -> value (``data`` parsed as JSON)."""
    events = []
    for block in text.strip().split("\n\n"):
        fields = dict(
            line.split(": ", 1) for line in block.splitlines() if not line.startswith(":")
        )
        if "data" in fields:
            fields["data"] = json.loads(fields["data"])
        if fields:
            events.append(fields)
    return events


# ---- a real server ------------------------------------------------------------------------


@pytest.fixture
def live_server(
    sqlite_store: Store, publisher: Publisher
) -> Iterator[tuple[str, Publisher, uvicorn.Server]]:
    app = create_app(sqlite_store, publisher, trigger=lambda: 1, api=ApiSettings(token=TOKEN))
    config = uvicorn.Config(app, host="127.0.0.1", port=0, log_level="warning", lifespan="on")
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    wait_until(lambda: server.started)
    port = server.servers[0].sockets[0].getsockname()[1]
    yield f"http://127.0.0.1:{port}", publisher, server
    publisher.close()  # open SSE streams end, so uvicorn's graceful shutdown does not wait
    server.should_exit = True
    thread.join(10)
    assert not thread.is_alive()


def test_real_server_rest_and_sse(
    live_server: tuple[str, Publisher, uvicorn.Server],
    sqlite_store: Store,
    make_record: MakeRecord,
) -> None:
    base, publisher, server = live_server
    with httpx.Client(base_url=base, timeout=5) as http:
        assert http.get("/coefficients").status_code == 404
        version = sqlite_store.add_calibration(make_record())
        assert http.get("/coefficients").json()["version"] == version
        assert http.post("/recalibrate", headers=AUTH).status_code == 202

        with http.stream("GET", "/events") as stream:
            assert stream.headers["content-type"].startswith("text/event-stream")
            lines = stream.iter_lines()
            assert next(lines) == ": subscribed"
            published = publisher.publish(sqlite_store.current())  # type: ignore[arg-type]
            block = []
            for line in lines:
                if line == "" and any(x.startswith("event:") for x in block):
                    break
                if line:
                    block.append(line)
            assert block[0] == "event: coefficients"
            assert json.loads(block[1].removeprefix("data: ")) == published
            assert block[2] == f"id: {version}"
        # The client went away: the server notices and frees the stream's slot.
        wait_until(lambda: server.config.app.state.broadcast.count == 0)


def test_real_server_stream_ends_on_shutdown(
    live_server: tuple[str, Publisher, uvicorn.Server],
) -> None:
    base, publisher, _ = live_server
    with httpx.Client(base_url=base, timeout=5) as http, http.stream("GET", "/events") as stream:
        lines = stream.iter_lines()
        assert next(lines) == ": subscribed"
        publisher.close()
        assert list(lines) == [""]  # the comment's blank line, then the stream ends


# ---- history: summaries with paging, whole records on request ---------------------------------


def test_history_pages_of_summaries_on_both_databases(
    store: Store, publisher: Publisher, make_record: MakeRecord, document: dict
) -> None:
    versions = [
        store.add_calibration(
            make_record(
                accepted=i != 2, reasons=["r"] * (i == 2), positions_used=list(range(i + 3))
            )
        )  # fmt: skip
        for i in range(5)
    ]
    client = TestClient(create_app(store, publisher))
    page = client.get("/coefficients/history", params={"limit": 2}).json()
    assert [s["version"] for s in page] == versions[:-3:-1]
    nxt = client.get(
        "/coefficients/history", params={"limit": 2, "before_version": page[-1]["version"]}
    )
    assert [s["version"] for s in nxt.json()] == versions[2:0:-1]
    summary = nxt.json()[0]
    assert summary == summary | {"accepted": False, "reasons": ["r"], "positions": 5,
                                 "chi2_red": pytest.approx(document["chi2_red"]),
                                 "verdict": document["observability"]["verdict"],
                                 "sensor": document["sensor"], "method": "lm"}  # fmt: skip
    assert "document" not in summary and "positions_used" not in summary
    full = client.get(
        "/coefficients/history", params={"full": True, "limit": 1, "before_version": versions[2]}
    ).json()
    assert [r["version"] for r in full] == [versions[1]] and full[0]["document"] == document
    assert (
        len(client.get("/coefficients/history", params={"full": True, "limit": 1000}).json()) == 5
    )


def test_health_degraded_with_reasons_and_the_log(sqlite_store: Store, tmp_path: Path) -> None:
    parts = {"problems": ["reader: device /dev/ttyUSB0 is not connected"]}
    app = create_app(sqlite_store, Publisher(tmp_path / "c.json"), health=lambda: parts)
    with TestClient(app) as http:
        body = http.get("/health").json()
        assert body["status"] == "degraded" and body["problems"] == parts["problems"]
        sqlite_store.add_event("job", "recalibration 1 not possible: 4 positions", {"job": 1})
        log = http.get("/log", params={"limit": 5}).json()
        assert log[0]["kind"] == "job" and "not possible" in log[0]["message"]
        assert http.get("/log", params={"limit": 0}).status_code == 422
