"""Schemathesis against a real shore (uvicorn) serving its own OpenAPI: every check, with the
administrator's token and with a unit's, positive and negative cases, gives no failure.

The shore's contract (issue 37): every answer a route gives is documented with its body (401,
403, 404, 413, 422, 503 as ``ErrorOut``; a bad query parameter's 422 as FastAPI's validation
error), the ingest body is the wire format's schema (so ``{}`` is a documented 422), and query
parameters are taken exactly as documented (``until=0.5`` is no time). As
tests/service/test_api_fuzz.py does for the vessel's API, the library is called (not its
pytest plugin), a bounded number of examples each, derandomised so that a run is repeatable.
"""

from __future__ import annotations

from typing import Any

import schemathesis
import uvicorn
from hypothesis import HealthCheck, given, settings
from hypothesis.errors import Unsatisfiable
from schemathesis import GenerationMode
from schemathesis.checks import CHECKS, load_all_checks

from service.fleet.api import create_app
from service.fleet.config import ShoreApiSettings
from service.fleet.store import FleetStore

ADMIN = "fuzz-admin-token-0123456789"
MODEL = "KVH-1750"
#: examples per operation, token and generation mode (10 operations, 2 tokens, 2 modes)
EXAMPLES = 12


def test_the_shore_keeps_its_contract(tmp_path, simulated_fleet, wire, run_server) -> None:
    store = FleetStore(f"sqlite:///{tmp_path / 'fleet.db'}")
    store.create_schema()
    app = create_app(store, ShoreApiSettings(token=ADMIN))
    config = uvicorn.Config(app, host="127.0.0.1", port=0, log_level="warning")
    try:
        with run_server(uvicorn.Server(config)) as port:
            url = f"http://127.0.0.1:{port}"
            unit_token = _seed(url, store, app, simulated_fleet, wire)
            schema = schemathesis.openapi.from_url(f"{url}/openapi.json")
            operations = [result.ok() for result in schema.get_all_operations()]
            assert len(operations) == len(app.openapi()["paths"]) == 10
            load_all_checks()
            checks = list(CHECKS.get_all())
            failures: list[str] = []
            for operation in operations:
                for token in (ADMIN, unit_token):
                    for mode in GenerationMode:
                        failures += _fuzz(operation, token, mode, checks)
    finally:
        store.close()
    assert not failures, f"{len(failures)} failures:\n" + "\n".join(failures)


def test_what_schemathesis_cli_found(shore, wire) -> None:
    """Cases of schemathesis' coverage phase (its CLI, not run here) that failed once."""
    token = shore.store.add_unit("SN-1", MODEL)
    row = {"kind": {}, "id": 1, "at": "2000-01-01T00:00:00Z", "data": {"kind": "0"}}
    reply = shore.send(token, wire.batch("SN-1", [row]))  # was a 500 (an unhashable kind)
    assert reply.status_code == 422 and "kind {} is not one of" in reply.json()["detail"]


def _seed(url: str, store: FleetStore, app: Any, simulated_fleet: Any, wire: Any) -> str:
    """Eight units of one model with versions (a prior, an outlier), windows and events; the
    token of the first."""
    import httpx

    tokens = {}
    with httpx.Client(base_url=url, timeout=30) as client:
        for serial, rows in simulated_fleet()["units"].items():
            tokens[serial] = store.add_unit(serial, MODEL)
            extra = [r for r in wire.rows_of(3, 100) if r["kind"] != "version"]
            reply = client.post("/fleet/ingest", json=wire.batch(serial, rows + extra),
                                headers={"Authorization": f"Bearer {tokens[serial]}"})  # fmt: skip
            assert reply.status_code == 200, reply.text
    assert app.state.fleet_priors.wait_idle(60)
    return next(iter(tokens.values()))


def _fuzz(operation: Any, token: str, mode: GenerationMode, checks: list[Any]) -> list[str]:
    """The failures of ``EXAMPLES`` cases of ``operation`` (each kept going: all are reported)."""
    found: list[str] = []
    headers = {"Authorization": f"Bearer {token}"}

    # the token is given, not generated: a negative case is negative in what it asks
    @given(case=operation.as_strategy(generation_mode=mode, headers=headers))
    @settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
              suppress_health_check=list(HealthCheck))  # fmt: skip
    def check(case: Any) -> None:
        response = case.call(timeout=10)
        try:
            case.validate_response(response, checks=checks, headers=headers)
        except (AssertionError, BaseExceptionGroup) as exc:  # a failure, or a group of them
            who = "admin" if token == ADMIN else "unit"
            found.append(f"{who} {mode.value} {case.method} {case.formatted_path} "
                         f"{case.query or ''} {str(case.body)[:200]}: {exc}"[:1500])  # fmt: skip

    try:
        check()
    except Unsatisfiable:  # nothing of the operation but the token to make negative
        assert mode is GenerationMode.NEGATIVE and not operation.query and not operation.body
    return found
