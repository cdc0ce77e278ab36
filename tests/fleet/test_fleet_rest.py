"""The shore's reads (docs/fleet.md, "Shore REST") over real HTTP: the two
fixed endpoints' shapes, the other reads' filters and pages, the published schema."""

from __future__ import annotations

from datetime import datetime
from typing import Any

import pytest

ADMIN = "admin-token-0123456789abcdef"


@pytest.fixture
def loaded(shore: Any, wire: Any) -> dict[str, str]:
    """SN-A (model KVH-1750) with two days of rows, SN-B (DSP-1760) with one, SN-C with none."""
    tokens = {"SN-A": shore.store.add_unit("SN-A", "KVH-1750"),
              "SN-B": shore.store.add_unit("SN-B", "DSP-1760"),
              "SN-C": shore.store.add_unit("SN-C")}  # fmt: skip
    # newest first on the wire: the shore orders by the vessel's numbers, not by arrival
    assert (
        shore.send(tokens["SN-A"], wire.batch("SN-A", wire.rows_of(3, 11, 25))).status_code == 200
    )
    assert shore.send(tokens["SN-A"], wire.batch("SN-A", wire.rows_of(4, 1, 24))).status_code == 200
    assert shore.send(tokens["SN-B"], wire.batch("SN-B", wire.rows_of(2, 1, 26))).status_code == 200
    return tokens


def test_units_has_the_fixed_fields(shore, loaded) -> None:
    r = shore.get(ADMIN, "/fleet/units")
    assert r.status_code == 200 and r.headers["content-type"] == "application/json"
    units = r.json()
    assert [u["unit"] for u in units] == ["SN-A", "SN-B", "SN-C"]
    fixed = {"unit", "versions", "windows", "current_version", "last_contact"}
    assert all(fixed <= set(u) for u in units)
    a, b, c = units
    # versions 1 (accepted), 2 (not), 11 (accepted), 12 (not): the current one is 11
    assert (a["versions"], a["windows"], a["current_version"]) == (4, 7, 11)
    assert (b["versions"], b["windows"], b["current_version"]) == (2, 2, 1)
    assert (c["versions"], c["windows"], c["current_version"], c["last_contact"]) == (
        0,
        0,
        None,
        None,
    )
    for u in (a, b):
        assert u["last_contact"].endswith("Z")
        assert (
            datetime.fromisoformat(u["last_contact"].replace("Z", "+00:00")).utcoffset() is not None
        )


def test_a_units_versions_oldest_first_with_the_vessels_documents(shore, loaded, wire) -> None:
    r = shore.get(loaded["SN-A"], "/fleet/units/SN-A/versions")
    assert r.status_code == 200
    versions = r.json()
    assert [v["version"] for v in versions] == [1, 2, 11, 12]
    first = versions[0]
    assert first["document"] == wire.version_doc(1, True, "2026-11-24T11:00:00Z")
    assert first["document"]["version"] == first["version"]
    assert (first["accepted"], first["trigger"], first["method"]) == (True, "drift", "nafsa")
    assert first["created_at"] == "2026-11-24T11:00:00Z"
    # paging: after the last version seen
    page = shore.get(ADMIN, "/fleet/units/SN-A/versions", limit=2).json()
    assert [v["version"] for v in page] == [1, 2]
    page = shore.get(ADMIN, "/fleet/units/SN-A/versions", limit=2, after=2).json()
    assert [v["version"] for v in page] == [11, 12]
    since = shore.get(ADMIN, "/fleet/units/SN-A/versions", since="2026-11-25T00:00:00Z").json()
    assert [v["version"] for v in since] == [11, 12]


def test_windows_and_events_filter_and_page(shore, loaded) -> None:
    token = loaded["SN-A"]
    windows = shore.get(token, "/fleet/units/SN-A/windows").json()
    assert [w["id"] for w in windows] == [1, 2, 3, 4, 11, 12, 13]
    assert windows[0]["data"] == {"session": 1, "accel_x": 0.0, "gyro_z": 1e-5}
    day = shore.get(token, "/fleet/units/SN-A/windows", since="2026-11-24T00:00:00",
                    until="2026-11-24T11:02:00Z").json()  # fmt: skip
    assert [w["id"] for w in day] == [1, 2]
    assert [
        w["id"] for w in shore.get(token, "/fleet/units/SN-A/windows", after=4, limit=2).json()
    ] == [11, 12]
    events = shore.get(token, "/fleet/units/SN-A/events", kind="published").json()
    assert [(e["id"], e["kind"]) for e in events] == [(1, "published"), (11, "published")]
    assert shore.get(token, "/fleet/units/SN-A/events", kind="other").json() == []
    for bad in ({"limit": 0}, {"limit": 1001}, {"since": "when"}, {"after": -1}):
        assert shore.get(token, "/fleet/units/SN-A/windows", **bad).status_code == 422, bad


def test_one_unit_with_its_link_state(shore, loaded) -> None:
    unit = shore.get(ADMIN, "/fleet/units/SN-A").json()
    assert unit["unit"] == "SN-A" and unit["model"] == "KVH-1750"
    assert unit["rows"] == {"session": 2, "window": 7, "slew": 2, "version": 4, "event": 2}
    (day,) = unit["link"]
    assert day["batches"] == 2 and day["rows"] == day["stored"] == 17
    assert day["compressed_bytes"] > 0 and len(day["day"]) == 10


def test_fleet_versions_across_units(shore, loaded) -> None:
    every = shore.get(ADMIN, "/fleet/versions").json()
    assert len(every) == 6
    assert [v["created_at"] for v in every] == sorted(v["created_at"] for v in every)
    kvh = shore.get(ADMIN, "/fleet/versions", model="KVH-1750", accepted="true").json()
    assert [(v["unit"], v["version"]) for v in kvh] == [("SN-A", 1), ("SN-A", 11)]
    late = shore.get(ADMIN, "/fleet/versions", since="2026-11-26T00:00:00Z").json()
    assert {v["unit"] for v in late} == {"SN-B"}


def test_the_schema_is_published(shore) -> None:
    r = shore.get(None, "/openapi.json")
    assert r.status_code == 200
    paths = r.json()["paths"]
    for path in ("/fleet/ingest", "/fleet/units", "/fleet/units/{unit}",
                 "/fleet/units/{unit}/versions", "/fleet/units/{unit}/windows",
                 "/fleet/units/{unit}/events", "/fleet/versions"):  # fmt: skip
        assert path in paths, path
    assert "413" in paths["/fleet/ingest"]["post"]["responses"]
    assert shore.get(None, "/docs").status_code == 200
