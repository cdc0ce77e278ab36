"""The API split into one router per resource: the same paths and operations as the single
module had, and each app answering from its own parts (the routers are shared module objects)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from fastapi.testclient import TestClient
from pydantic import SecretStr

from service.api import create_app
from service.config import ApiSettings
from service.publish import Publisher
from service.store.records import CalibrationRecord
from service.store.repository import Store

#: Written down from ``create_app(...).openapi()`` of service/api.py before the split:
#: path -> method -> (operationId, summary, response codes).
PATHS_BEFORE_SPLIT = {
    "/health": {"get": ("get_health_health_get", "Get Health", ["200"])},
    "/log": {"get": ("get_log_log_get", "Get Log", ["200", "422"])},
    "/coefficients": {"get": ("get_current_coefficients_get", "Get Current", ["200", "404"])},
    "/coefficients/history": {
        "get": ("get_history_coefficients_history_get", "Get History", ["200", "422"])
    },
    "/coefficients/{version}": {
        "get": ("get_version_coefficients__version__get", "Get Version", ["200", "404", "422"])
    },
    "/positions": {"get": ("get_positions_positions_get", "Get Positions", ["200", "422"])},
    "/recalibrate": {
        "post": (
            "post_recalibrate_recalibrate_post",
            "Post Recalibrate",
            ["202", "401", "403", "409", "415", "503"],
        )
    },
    "/events": {"get": ("get_events_events_get", "Get Events", ["200", "429"])},
}
#: Operations whose docstring is their OpenAPI description (the others have none).
DESCRIBED = {
    "/health": "``ok``, or ``degraded``",
    "/log": "The service's events, newest first",
    "/coefficients/history": "Calibrations, accepted or not, newest first",
    "/positions": "Stored positions in id order",
    "/recalibrate": "Queue a recalibration on the stored positions",
    "/events": "Server-Sent Events: ``event: coefficients``",
}


def _app(tmp_path: Path, name: str, **kwargs: object) -> tuple[TestClient, Store]:
    store = Store(f"sqlite:///{tmp_path / name}.db")
    store.create_schema()
    app = create_app(store, Publisher(tmp_path / f"{name}.json"), **kwargs)  # type: ignore[arg-type]
    return TestClient(app), store


def test_openapi_paths_and_operations_are_those_before_the_split(tmp_path: Path) -> None:
    client, _ = _app(tmp_path, "a")
    schema = client.get("/openapi.json").json()
    assert set(schema["paths"]) == set(PATHS_BEFORE_SPLIT)
    for path, ops in PATHS_BEFORE_SPLIT.items():
        assert set(schema["paths"][path]) == set(ops), path
        for method, (operation_id, summary, codes) in ops.items():
            op = schema["paths"][path][method]
            assert (op["operationId"], op["summary"]) == (operation_id, summary)
            assert sorted(op["responses"]) == codes, path
            assert op.get("description", "").startswith(DESCRIBED.get(path, "")), path
            assert ("description" in op) == (path in DESCRIBED), path
    assert schema["paths"]["/recalibrate"]["post"]["security"] == [{"HTTPBearer": []}]
    assert schema["components"]["securitySchemes"]["HTTPBearer"]["scheme"] == "bearer"


def test_pages_outside_the_schema_still_answer(tmp_path: Path) -> None:
    client, _ = _app(tmp_path, "a")
    docs = client.get("/docs")
    assert docs.status_code == 200 and "/docs-assets/swagger-ui-bundle.js" in docs.text
    assert "/openapi.json" in docs.text
    assert client.get("/docs-assets/swagger-ui.css").status_code == 200
    assert client.get("/").status_code == 200  # the dashboard


def test_two_apps_in_one_process_answer_from_their_own_parts(
    tmp_path: Path, make_record: Callable[..., CalibrationRecord]
) -> None:
    token = "token-of-app-a-0123456789"
    calls: list[str] = []
    a, store_a = _app(
        tmp_path,
        "a",
        trigger=lambda: calls.append("a") or 7,
        health=lambda: {"who": "a"},
        api=ApiSettings(token=SecretStr(token)),
    )
    b, _ = _app(tmp_path, "b", health=lambda: {"who": "b"})
    version = store_a.add_calibration(make_record())

    assert a.get("/coefficients").json()["version"] == version
    assert b.get("/coefficients").status_code == 404
    assert a.get("/health").json()["service"] == {"who": "a"}
    assert b.get("/health").json()["service"] == {"who": "b"}

    auth = {"Authorization": f"Bearer {token}"}
    queued = a.post("/recalibrate", headers=auth)
    assert (queued.status_code, queued.json()) == (202, {"queued": True, "job": 7})
    refused = b.post("/recalibrate", headers=auth)  # b has no token configured: no writes
    assert refused.status_code == 403 and "no [api] token" in refused.json()["detail"]
    assert calls == ["a"]
    assert a.app.state.broadcast is not b.app.state.broadcast  # type: ignore[attr-defined]
