"""Schemathesis against a real uvicorn serving the API's own OpenAPI: no input gives a 5xx.

Every operation but ``/events`` (an endless stream) is fuzzed, a bounded number of examples
each, on a temporary SQLite store holding positions and calibrations; the write endpoint gets
the bearer token so its body is reached too.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
import schemathesis
import uvicorn
from hypothesis import HealthCheck, given, settings

from recal.model.coefficients import CoefficientSet
from recal.sim.simulate import simulate_positions
from service.api import create_app
from service.config import ApiSettings
from service.publish import Publisher
from service.store.records import CalibrationRecord
from service.store.repository import Store

TOKEN = "fuzz-token-0123456789abcdef"


@pytest.fixture(scope="module")
def fuzz_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    folder = tmp_path_factory.mktemp("fuzz")
    store = Store(f"sqlite:///{folder / 'fuzz.db'}")
    store.create_schema()
    sid = store.add_session("sim")
    store.add_positions(sid, simulate_positions(CoefficientSet.seed_truth()).columns)
    for accepted in (True, False):
        store.add_calibration(CalibrationRecord(trigger="auto", method="lm", accepted=accepted,
                                                document={"chi2_red": 1.0}))  # fmt: skip
    publisher = Publisher(folder / "coefficients.json")
    app = create_app(store, publisher, trigger=lambda: 1, api=ApiSettings(token=TOKEN))
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=0, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 10
    while not server.started:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    port = server.servers[0].sockets[0].getsockname()[1]
    yield f"http://127.0.0.1:{port}"
    publisher.close()
    server.should_exit = True
    thread.join(10)
    store.close()


@pytest.fixture(scope="module")
def api_schema(fuzz_server: str) -> Any:
    return schemathesis.openapi.from_url(f"{fuzz_server}/openapi.json").exclude(path="/events")


def test_no_input_gives_a_server_error(api_schema: Any) -> None:
    # (schemathesis' own pytest loader does not run under pytest 9: one test per operation here)
    operations = [result.ok() for result in api_schema.get_all_operations()]
    assert {op.path for op in operations} >= {
        "/recalibrate",
        "/positions",
        "/coefficients/{version}",
    }
    for operation in operations:
        _fuzz(operation)


def _fuzz(operation: Any) -> None:
    @given(case=operation.as_strategy())
    @settings(
        max_examples=20, deadline=None, suppress_health_check=list(HealthCheck), database=None
    )
    def check(case: Any) -> None:
        response = case.call(headers={"Authorization": f"Bearer {TOKEN}"}, timeout=10)
        assert response.status_code < 500, f"{case.method} {case.formatted_path}: {response.text}"
        case.validate_response(response)

    check()
