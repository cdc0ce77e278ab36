"""POST /fleet/ingest over real HTTP (docs/fleet.md#wire-format-format-1): gzip batches stored
once, whatever the retries; tokens bound to their unit; a bad batch stores nothing."""

from __future__ import annotations

import gzip
import json
import threading
from typing import Any

import pytest


def counts(shore: Any, token: str, unit: str) -> dict[str, Any]:
    r = shore.get(token, f"/fleet/units/{unit}")
    assert r.status_code == 200, r.text
    return r.json()["rows"]


@pytest.fixture
def units(shore: Any) -> dict[str, str]:
    return {s: shore.store.add_unit(s, "KVH-1750") for s in ("SN-A", "SN-B")}


def test_a_gzip_batch_is_stored_and_a_replay_changes_nothing(shore, units, wire) -> None:
    rows = wire.rows_of(3)
    r = shore.send(units["SN-A"], wire.batch("SN-A", rows))
    assert r.status_code == 200, r.text
    assert r.json() == {"stored": len(rows), "duplicates": 0, "conflicts": 0}
    before = counts(shore, units["SN-A"], "SN-A")
    assert before == {"session": 1, "window": 3, "slew": 1, "version": 2, "event": 1}
    versions = shore.get(units["SN-A"], "/fleet/units/SN-A/versions").json()
    # the same batch again (an acknowledgement lost): nothing new, all counted as duplicates
    r = shore.send(units["SN-A"], wire.batch("SN-A", rows))
    assert r.json() == {"stored": 0, "duplicates": len(rows), "conflicts": 0}
    assert counts(shore, units["SN-A"], "SN-A") == before
    assert shore.get(units["SN-A"], "/fleet/units/SN-A/versions").json() == versions
    # a retry that overlaps: only the new rows are stored
    more = wire.rows_of(5)
    r = shore.send(units["SN-A"], wire.batch("SN-A", more))
    assert r.json() == {"stored": 2, "duplicates": len(more) - 2, "conflicts": 0}
    assert counts(shore, units["SN-A"], "SN-A")["window"] == 5
    unit = shore.get(units["SN-A"], "/fleet/units/SN-A").json()
    assert unit["last_contact"] is not None
    (day,) = unit["link"]
    assert day["batches"] == 3 and day["rows"] == 2 * len(rows) + len(more)
    assert day["stored"] == len(rows) + 2 and day["compressed_bytes"] > 0


def test_without_a_known_token_nothing_is_stored(shore, units, wire) -> None:
    body = gzip.compress(json.dumps(wire.batch("SN-A", wire.rows_of(1))).encode())
    for token in (None, "not-a-token", units["SN-A"] + "x"):
        r = shore.post(token, body)
        assert r.status_code == 401, r.text
        assert r.headers["www-authenticate"] == "Bearer"
    for path in ("/fleet/units", "/fleet/units/SN-A", "/fleet/units/SN-A/versions",
                 "/fleet/versions"):  # fmt: skip
        assert shore.get(None, path).status_code == 401
        assert shore.get("wrong", path).status_code == 401
    assert counts(shore, units["SN-A"], "SN-A")["window"] == 0


def test_a_unit_token_writes_and_reads_its_own_unit_only(shore, units, wire) -> None:
    a, b = units["SN-A"], units["SN-B"]
    assert shore.send(b, wire.batch("SN-B", wire.rows_of(2))).status_code == 200
    # A's token, B's batch: refused, nothing stored for either
    r = shore.send(a, wire.batch("SN-B", wire.rows_of(4, first=100)))
    assert r.status_code == 403, r.text
    assert r.json()["detail"] == "the batch's unit is not this token's"  # B's serial not echoed
    assert counts(shore, b, "SN-B")["window"] == 2
    assert counts(shore, a, "SN-A")["window"] == 0
    # A's token reads A, and B answers 404 as if absent (the same as an unknown serial)
    for path in ("", "/versions", "/windows", "/events"):
        assert shore.get(a, f"/fleet/units/SN-A{path}").status_code == 200
        other = shore.get(a, f"/fleet/units/SN-B{path}")
        absent = shore.get(a, f"/fleet/units/SN-Z{path}")
        assert other.status_code == absent.status_code == 404
        assert other.json() == absent.json() == {"detail": "no such unit"}
    assert [u["unit"] for u in shore.get(a, "/fleet/units").json()] == ["SN-A"]
    assert shore.get(a, "/fleet/versions").json() == []
    assert {v["unit"] for v in shore.get(b, "/fleet/versions").json()} == {"SN-B"}
    # the administrator reads everything, and sends nothing
    assert [
        u["unit"] for u in shore.get("admin-token-0123456789abcdef", "/fleet/units").json()
    ] == [
        "SN-A",
        "SN-B",
    ]
    r = shore.send("admin-token-0123456789abcdef", wire.batch("SN-A", wire.rows_of(1)))
    assert r.status_code == 403


def _append(kind: str, ident: int):
    return lambda rows: rows.append({"kind": kind, "id": ident, "at": "2026-11-26T00:00:00Z",
                                     "data": {}})  # fmt: skip


#: (what is wrong with a batch's rows, what the 422 says): one bad row refuses the whole batch
MALFORMED = [
    (_append("window", 0), "rows[8]: id 0 is not a vessel row id"),
    (_append("windw", 9), "rows[8]: kind 'windw' is not one of"),
    (lambda rows: rows[2].update(at="yesterday"), "rows[2] (window 2): at"),
    (lambda rows: rows[2].update(at="2026-11-26T00:00:00"), "no UTC offset"),
    (lambda rows: rows[6]["data"].update(accepted="yes"), "data.accepted"),
    (lambda rows: rows[6]["data"].update(version=99), "not the row's id"),
    (lambda rows: rows[7]["data"].pop("kind"), "rows[7] (event 1): data.kind"),
    (lambda rows: rows[3].update(data=[1, 2]), "data must be an object"),
    (lambda rows: rows[3].update(id=True), "id True is not a vessel row id"),
]


def test_a_malformed_batch_stores_nothing(shore, units, wire) -> None:
    for mangle, says in MALFORMED:
        rows = wire.rows_of(3)
        mangle(rows)
        r = shore.send(units["SN-A"], wire.batch("SN-A", rows))
        assert r.status_code == 422, r.text
        assert says in r.json()["detail"], (says, r.text)
        assert "\n" not in r.json()["detail"]
    assert sum(counts(shore, units["SN-A"], "SN-A").values()) == 0
    assert shore.get(units["SN-A"], "/fleet/units/SN-A").json()["last_contact"] is None


def test_bodies_that_are_not_a_batch(shore, units, wire) -> None:
    token = units["SN-A"]
    good = json.dumps(wire.batch("SN-A", wire.rows_of(2))).encode()
    cases = [
        (gzip.compress(good)[:-20], True, 422, "gzip"),  # cut mid-body
        (good, True, 422, "gzip"),  # says gzip, is not
        (gzip.compress(b"{not json"), True, 422, "not JSON"),
        (gzip.compress(b"[1, 2]"), True, 422, "JSON object"),
        (gzip.compress(good.replace(b'"format": 1', b'"format": 2')), True, 422, "format"),
        (gzip.compress(good.replace(b"0.01", b"NaN")), True, 422, "NaN"),
        (gzip.compress(good.replace(b"0.01", b"1e400")), True, 422, "out of range"),  # inf
        (b"x" * (65 * 1024), True, 413, "over"),  # compressed body over the limit
        (gzip.compress(b" " * (1 << 20) + good), True, 413, "decompressed"),  # a small bomb
    ]
    for body, gzipped, status, says in cases:
        r = shore.post(token, body, gzipped=gzipped)
        assert (r.status_code, says in r.json()["detail"]) == (status, True), (says, r.text)
    assert sum(counts(shore, token, "SN-A").values()) == 0
    # plain JSON (no Content-Encoding) is read as well
    assert shore.post(token, good, gzipped=False).json() == {
        "stored": 7,
        "duplicates": 0,
        "conflicts": 0,
    }


def test_concurrent_and_repeated_batches_store_each_row_once(shore, units, wire) -> None:
    """Six senders at once, overlapping batches of two units: each key stored once."""
    results: list[Any] = []

    def send(unit: str, first: int) -> None:
        results.append(shore.send(units[unit], wire.batch(unit, wire.rows_of(20, first=first))))

    threads = [threading.Thread(target=send, args=(u, f)) for u in units for f in (1, 11, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert [r.status_code for r in results] == [200] * 6
    total = sum(r.json()["stored"] for r in results)
    per_unit = {"session": 2, "window": 30, "slew": 2, "version": 4, "event": 2}
    assert total == 2 * sum(per_unit.values())
    for unit, token in units.items():
        assert counts(shore, token, unit) == per_unit
