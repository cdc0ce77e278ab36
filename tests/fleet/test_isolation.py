"""Isolation by construction (issue 37): every route of the shore's OpenAPI schema, asked with
unit A's token, shows nothing of unit B (its serial, rows, statistics, that it is an outlier),
and B's paths answer 404 (or 403) to A.

The routes come from ``app.openapi()``: a new route has no entry in ``REQUESTS`` and fails
here until it says which requests A makes of it. The fleet: eight units of one model ageing
over two years, one of them (B) an outlier of the fleet prior; A and B also send windows and
events whose values are theirs alone.
"""

from __future__ import annotations

import json
from typing import Any

import httpx
import pytest

from service.fleet.api import create_app

ADMIN = "admin-token-0123456789abcdef"  # tests/fleet/conftest.py's
MODEL = "KVH-1750"
#: {unit} of a path: the caller's own serial, or B's
OWN, OTHER = "own", "other"

#: what A asks of each route: (the {unit} of its path, if any; query parameters). A route of
#: the schema without an entry fails the test.
REQUESTS: dict[tuple[str, str], list[tuple[str | None, dict[str, Any]]]] = {
    ("POST", "/fleet/ingest"): [(None, {})],  # a batch of A's own, then one that claims B
    ("GET", "/fleet/units"): [(None, {})],
    ("GET", "/fleet/units/{unit}"): [(OWN, {}), (OTHER, {})],
    ("GET", "/fleet/units/{unit}/versions"): [
        (OWN, {}),
        (OTHER, {}),
        (OTHER, {"since": "2020-01-01T00:00:00Z", "limit": 1000}),
    ],
    ("GET", "/fleet/units/{unit}/windows"): [(OWN, {}), (OTHER, {}), (OTHER, {"after": 0})],
    ("GET", "/fleet/units/{unit}/events"): [
        (OWN, {}),
        (OTHER, {}),
        (OTHER, {"kind": "published"}),
    ],
    ("GET", "/fleet/versions"): [
        (None, {}),
        (None, {"model": MODEL}),
        (None, {"accepted": "true", "limit": 1000}),
        (None, {"accepted": "false", "since": "2020-01-01T00:00:00Z"}),
    ],
    ("GET", "/fleet/overview"): [(None, {})],
    ("GET", "/fleet/prior"): [(None, {}), (None, {"model": MODEL})],
    ("GET", "/fleet/outliers"): [(None, {"model": MODEL})],
}
#: routes outside the schema: the docs and the dashboard's own files (no data of any unit)
UNLISTED = ("/openapi.json", "/docs", "/fleet/dashboard")


def _extra_rows(marker: str, value: float) -> list[dict[str, Any]]:
    """A session, two windows and two events, their values the unit's own."""
    at = "2026-11-20T10:00:00Z"
    return [
        {
            "kind": "session",
            "id": 500,
            "at": at,
            "data": {"source": f"loop://{marker}", "meta": {}, "started_at": at},
        },  # fmt: skip
        *(
            {
                "kind": "window",
                "id": 500 + i,
                "at": at,
                "data": {"session": 500, "accel_x": value + i, "note": f"{marker}-window"},
            }
            for i in range(2)
        ),  # fmt: skip
        *(
            {
                "kind": "event",
                "id": 500 + i,
                "at": at,
                "data": {"kind": "published", "message": f"{marker}-event-{i}", "data": {}},
            }
            for i in range(2)
        ),  # fmt: skip
    ]


@pytest.fixture
def fleet(shore: Any, wire: Any, simulated_fleet: Any) -> dict[str, Any]:
    sim = simulated_fleet()
    (b,) = sim["outliers"]
    a = next(s for s in sim["units"] if s != b)
    tokens = {}
    for serial, rows in sim["units"].items():
        tokens[serial] = shore.store.add_unit(serial, MODEL)
        extra = {a: _extra_rows("a-only", 0.1357924680), b: _extra_rows("b-only", 0.8642097531)}
        reply = shore.send(tokens[serial], wire.batch(serial, rows + extra.get(serial, [])))
        assert reply.status_code == 200, reply.text
    assert shore.priors.wait_idle(60)
    return {"a": a, "b": b, "tokens": tokens, "units": sim["units"]}


def _secrets(shore: Any, fleet: dict[str, Any]) -> list[str]:
    """Text that only B's data holds (and every other unit's serial), as the admin reads it."""
    a, b = fleet["a"], fleet["b"]
    out = [s for s in fleet["tokens"] if s != a]
    out += ["b-only", json.dumps(0.8642097531)[:10]]
    flagged = shore.get(ADMIN, "/fleet/outliers", model=MODEL).json()["outliers"]
    (mine,) = [o for o in flagged if o["unit"] == b]  # the admin sees B flagged
    out.append(json.dumps(mine["statistic"]))
    first = fleet["units"][b][0]["data"]["document"]["coefficients"]
    out += [json.dumps(v) for v in first["gyro"]["bias"] if v]  # B's own coefficients
    return out


def _outlier_claims(body: Any, a: str, a_flagged: bool, where: str) -> None:
    """Every ``outliers`` in an answer to A: a list of A alone, or a count of A alone."""
    if isinstance(body, dict):
        for key, value in body.items():
            if key == "outliers":
                if isinstance(value, list):
                    assert all(o.get("unit") == a for o in value), where
                else:
                    assert value == int(a_flagged), where
            _outlier_claims(value, a, a_flagged, where)
    elif isinstance(body, list):
        for value in body:
            _outlier_claims(value, a, a_flagged, where)


def test_nothing_of_another_unit_reaches_a_unit(shore, fleet, wire) -> None:
    a, b, token = fleet["a"], fleet["b"], fleet["tokens"][fleet["a"]]
    secrets = _secrets(shore, fleet)
    app = create_app(shore.store)
    schema_routes = {(m.upper(), p) for p, ops in app.openapi()["paths"].items() for m in ops}
    assert schema_routes - set(REQUESTS) == set(), "a route without an entry in REQUESTS"
    assert set(REQUESTS) - schema_routes == set(), "REQUESTS names a route that is gone"
    unlisted = {r.path for r in app.routes if getattr(r, "include_in_schema", True) is False}
    assert all(p.startswith(UNLISTED) for p in unlisted), unlisted

    admin_b = shore.get(ADMIN, f"/fleet/units/{b}").json()["rows"]
    answers: list[tuple[str, httpx.Response]] = []
    walked = 0
    for (method, path), requests in sorted(REQUESTS.items()):
        walked += 1
        for unit, query in requests:
            if method == "POST":
                own = wire.batch(a, [{"kind": "event", "id": 900, "at": "2026-11-27T00:00:00Z",
                                      "data": {"kind": "note", "message": "mine"}}])  # fmt: skip
                claims_b = wire.batch(b, _extra_rows("a-as-b", 0.5))
                assert shore.send(token, own).status_code == 200
                refused = shore.send(token, claims_b)
                assert refused.status_code == 403, refused.text
                answers += [(f"POST {path} as B", refused)]
                continue
            serial = {OWN: a, OTHER: b, None: None}[unit]
            url = path.replace("{unit}", serial) if serial else path
            reply = shore.get(token, url, **query)
            where = f"{method} {url} {query}"
            if unit == OTHER:
                assert reply.status_code in (403, 404), f"{where}: {reply.status_code}"
                assert reply.json() == shore.get(token, url.replace(b, "SN-NOBODY"), **query).json()
            else:
                assert reply.status_code == 200, f"{where}: {reply.text}"
            answers.append((where, reply))
    for path in sorted(unlisted):
        if "{" not in path:
            answers.append((f"GET {path}", shore.get(token, path)))
    assert walked == len(schema_routes) == 10

    for where, reply in answers:
        text = reply.text + json.dumps(dict(reply.headers))
        for secret in secrets:
            assert secret not in text, f"{where} shows {secret!r}"
        if not where.startswith("GET /openapi.json"):  # (the schema names the keys)
            if reply.headers.get("content-type", "").startswith("application/json"):
                _outlier_claims(reply.json(), a, False, where)
    # A saw its own rows, and B's are as they were (the batch claiming B stored nothing)
    assert any("a-only" in r.text for _, r in answers)
    assert shore.get(ADMIN, f"/fleet/units/{b}").json()["rows"] == admin_b


def test_a_unit_sees_the_prior_of_its_model_and_itself_alone(shore, fleet) -> None:
    a, b, tokens = fleet["a"], fleet["b"], fleet["tokens"]
    full = shore.get(ADMIN, "/fleet/prior", model=MODEL).json()
    assert [o["unit"] for o in full["outliers"]] == [b]  # the administrator sees every unit
    for serial, outliers in ((a, []), (b, full["outliers"])):
        mine = shore.get(tokens[serial], "/fleet/prior").json()
        # the model's aggregate as the administrator reads it, and its own outlier status
        assert mine == {**full, "outliers": outliers}
        seen = shore.get(tokens[serial], "/fleet/outliers", model=MODEL).json()["outliers"]
        assert seen == outliers
        row = shore.get(tokens[serial], "/fleet/overview").json()
        assert row["models"][MODEL]["outliers"] == len(outliers)
    assert shore.get(ADMIN, "/fleet/overview").json()["models"][MODEL]["outliers"] == 1
