"""Hostile clients: bearer token on writes, cross-origin and form requests, the SSE stream cap,
documentation that works offline, out-of-range ids."""

from __future__ import annotations

import re
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import uvicorn
from fastapi.testclient import TestClient

from service.api import MAX_DB_INT, create_app
from service.config import ApiSettings, Settings
from service.publish import Publisher
from service.store.repository import Store

TOKEN = "test-token-0123456789abcdef"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
EVIL = "http://evil.example"


@pytest.fixture
def publisher(tmp_path: Path) -> Publisher:
    return Publisher(tmp_path / "published" / "coefficients.json")


@pytest.fixture
def triggers() -> list[int]:
    return []


@pytest.fixture
def make_client(
    sqlite_store: Store, publisher: Publisher, triggers: list[int]
) -> Callable[..., TestClient]:
    def trigger() -> int:
        triggers.append(len(triggers) + 1)
        return triggers[-1]

    def make(**api: Any) -> TestClient:
        app = create_app(sqlite_store, publisher, trigger=trigger, api=ApiSettings(**api))
        return TestClient(app)

    return make


# ---- bearer token ---------------------------------------------------------------------------


def test_writes_need_the_bearer_token(
    make_client: Callable[..., TestClient], triggers: list[int]
) -> None:
    client = make_client(token=TOKEN)
    missing = client.post("/recalibrate")
    assert missing.status_code == 401 and missing.headers["www-authenticate"] == "Bearer"
    for header in (f"Bearer {TOKEN}x", f"Bearer {TOKEN[:-1]}", f"Basic {TOKEN}", TOKEN):
        assert client.post("/recalibrate", headers={"Authorization": header}).status_code == 401
    assert triggers == []
    assert client.post("/recalibrate", headers=AUTH).status_code == 202
    assert triggers == [1]
    assert client.get("/coefficients/history").status_code == 200  # reads need no token


def test_writes_are_disabled_without_a_configured_token(
    make_client: Callable[..., TestClient], triggers: list[int]
) -> None:
    refused = make_client().post("/recalibrate", headers=AUTH)
    assert refused.status_code == 403 and "no [api] token" in refused.json()["detail"]
    assert triggers == []


def test_openapi_declares_the_bearer_scheme(make_client: Callable[..., TestClient]) -> None:
    spec = make_client(token=TOKEN).get("/openapi.json").json()
    assert spec["components"]["securitySchemes"]["HTTPBearer"]["scheme"] == "bearer"
    assert spec["paths"]["/recalibrate"]["post"]["security"] == [{"HTTPBearer": []}]


def test_token_is_secret_in_settings() -> None:
    settings = Settings(api={"token": TOKEN})
    assert settings.api.token is not None and settings.api.token.get_secret_value() == TOKEN
    for text in (repr(settings), str(settings), settings.model_dump_json()):
        assert TOKEN not in text


# ---- browsers: origins and simple requests --------------------------------------------------


def test_cross_origin_simple_post_is_refused(
    make_client: Callable[..., TestClient], triggers: list[int]
) -> None:
    client = make_client(token=TOKEN)
    page = {"Origin": EVIL, "Content-Type": "text/plain"}  # what a <form> or fetch() can send
    refused = client.post("/recalibrate", headers=page, content="x")
    assert refused.status_code == 403 and EVIL in refused.json()["detail"]
    assert client.post("/recalibrate", headers=AUTH | page, content="x").status_code == 403
    assert client.get("/coefficients", headers={"Origin": EVIL}).status_code == 403
    assert client.get("/events", headers={"Origin": EVIL}).status_code == 403
    for media in ("text/plain", "application/x-www-form-urlencoded", "multipart/form-data; b=1"):
        form = client.post("/recalibrate", headers=AUTH | {"Content-Type": media}, content="a=1")
        assert form.status_code == 415, media
    assert triggers == []
    # The /docs page of this very server may post (same origin).
    same = client.post("/recalibrate", headers=AUTH | {"Origin": "http://testserver"})
    assert same.status_code == 202 and triggers == [1]


def test_configured_origin_may_call_the_api(
    make_client: Callable[..., TestClient], triggers: list[int]
) -> None:
    console = "http://bridge-console.local:8080"
    client = make_client(token=TOKEN, allowed_origins=[console])
    preflight = client.options(
        "/recalibrate",
        headers={
            "Origin": console,
            "Access-Control-Request-Method": "POST",
            "Access-Control-Request-Headers": "authorization",
        },
    )
    assert preflight.status_code == 200
    assert preflight.headers["access-control-allow-origin"] == console
    posted = client.post("/recalibrate", headers=AUTH | {"Origin": console})
    assert posted.status_code == 202 and posted.headers["access-control-allow-origin"] == console
    assert client.post("/recalibrate", headers=AUTH | {"Origin": EVIL}).status_code == 403
    assert triggers == [1]


# ---- documentation offline ------------------------------------------------------------------


def test_docs_page_loads_nothing_from_the_internet(make_client: Callable[..., TestClient]) -> None:
    client = make_client()
    page = client.get("/docs")
    assert page.status_code == 200
    assert not re.search(r"(src|href)=['\"]?(https?:)?//", page.text), "an external asset"
    assets = re.findall(r"(?:src|href)=['\"]([^'\"]+)['\"]", page.text)
    assert any(a.endswith("swagger-ui-bundle.js") for a in assets)
    for asset in assets:
        response = client.get(asset)
        assert response.status_code == 200 and len(response.content) > 100, asset
    assert "SwaggerUIBundle" in client.get("/docs-assets/swagger-ui-bundle.js").text
    assert client.get("/redoc").status_code == 404  # ReDoc would need its CDN


# ---- out-of-range integers ------------------------------------------------------------------


@pytest.mark.parametrize(
    ("path", "params"),
    [
        (f"/coefficients/{2**63}", {}),
        (f"/coefficients/{MAX_DB_INT + 1}", {}),
        (f"/coefficients/{2**64 + 5}", {}),
        ("/coefficients/0", {}),
        ("/coefficients/-1", {}),
        ("/positions", {"since_id": 2**63}),
        ("/positions", {"since_id": MAX_DB_INT + 1}),
        ("/positions", {"since_id": -1}),
        ("/positions", {"limit": 2**63}),
        ("/coefficients/history", {"before_version": 2**63}),
        ("/coefficients/history", {"limit": 2**63}),
    ],
)
def test_out_of_range_integers_are_422(
    store: Store, publisher: Publisher, path: str, params: dict[str, int]
) -> None:
    response = TestClient(create_app(store, publisher)).get(path, params=params)
    assert response.status_code == 422, response.text


def test_largest_ids_are_answered(store: Store, publisher: Publisher) -> None:
    client = TestClient(create_app(store, publisher))
    assert client.get(f"/coefficients/{MAX_DB_INT}").status_code == 404
    assert client.get("/positions", params={"since_id": MAX_DB_INT}).json() == []
    history = client.get("/coefficients/history", params={"before_version": MAX_DB_INT})
    assert history.status_code == 200 and history.json() == []


# ---- SSE: a cap, and one shared subscription ------------------------------------------------


@pytest.fixture
def capped_server(sqlite_store: Store, publisher: Publisher) -> Iterator[tuple[str, Any]]:
    app = create_app(sqlite_store, publisher, api=ApiSettings(max_event_streams=2))
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=0, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    _wait(lambda: server.started)
    port = server.servers[0].sockets[0].getsockname()[1]
    yield f"http://127.0.0.1:{port}", app.state.broadcast
    publisher.close()
    server.should_exit = True
    thread.join(10)
    assert not thread.is_alive()


def test_event_streams_are_capped_and_share_one_subscription(
    capped_server: tuple[str, Any], publisher: Publisher, make_record: Callable[..., Any]
) -> None:
    base, broadcast = capped_server
    with httpx.Client(base_url=base, timeout=5) as a, httpx.Client(base_url=base, timeout=5) as b:
        # (keep each line iterator: dropping one closes its response)
        with a.stream("GET", "/events") as first:
            first_lines = first.iter_lines()
            assert next(first_lines) == ": subscribed"
            with b.stream("GET", "/events") as second:
                second_lines = second.iter_lines()
                assert next(second_lines) == ": subscribed"
                assert broadcast.count == 2 and publisher.subscriber_count == 1
                third = httpx.get(f"{base}/events", timeout=5)
                assert third.status_code == 429 and third.headers["retry-after"] == "30"
                assert "2 event streams" in third.json()["detail"]
                publisher.publish(make_record(version=7))  # one subscription feeds both
                for lines in (first_lines, second_lines):
                    assert _next_event(lines)["id"] == "7"
        # Both clients went away: their slots are free again.
        _wait(lambda: broadcast.count == 0)
        with a.stream("GET", "/events") as again:
            lines = again.iter_lines()
            assert again.status_code == 200 and next(lines) == ": subscribed"
            assert broadcast.count == 1
    assert publisher.subscriber_count == 1


def _next_event(lines: Iterator[str]) -> dict[str, str]:
    block: dict[str, str] = {}
    for line in lines:
        if not line and "event" in block:
            return block
        if line and not line.startswith(":"):
            key, value = line.split(": ", 1)
            block[key] = value
    raise AssertionError("the stream ended")


def _wait(condition: Callable[[], bool], timeout: float = 5.0) -> None:
    import time

    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)
