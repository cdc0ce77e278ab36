"""The fleet dashboard in a real browser: Debian's chromium driven by playwright (as
tests/service/test_dashboard_browser.py), on a real shore seeded through POST /fleet/ingest.
Skipped without chromium or playwright, except under CI (CI set), where it must run."""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any

import pytest

ADMIN = "admin-token-0123456789abcdef"


@pytest.fixture(params=["sqlite"])
def fleet_url(request: pytest.FixtureRequest, tmp_path: Any) -> Iterator[str]:
    """SQLite only: the page reads the same API either way (test_overview covers both)."""
    yield f"sqlite:///{tmp_path / 'fleet.db'}"


@pytest.fixture()
def seeded(shore: Any, wire: Any, simulated_fleet: Any) -> dict[str, Any]:
    """Five KVH-1750 over two years (one ageing ten times faster) and a unit with a rejected
    version, as the vessels sent them."""
    sim = simulated_fleet(units=5, seed=4)
    for serial, rows in sim["units"].items():
        token = shore.store.add_unit(serial, "KVH-1750")
        rows = rows + [r for r in wire.rows_of(3, 1, 25) if r["kind"] in ("session", "window")]
        assert shore.send(token, {**wire.batch(serial, rows), "backlog": 2}).status_code == 200
    token = shore.store.add_unit("DSP-1760-SN0201", "DSP-1760")
    assert (
        shore.send(token, wire.batch("DSP-1760-SN0201", wire.rows_of(3, 1, 26))).status_code == 200
    )
    # each batch with accepted versions started a recompute of the prior in the background
    assert shore.priors.wait_idle(60)
    return sim


def test_the_fleet_dashboard_shows_every_unit_and_a_units_history(shore, seeded, page, tmp_path):
    from playwright.sync_api import expect

    problems: list[str] = []  # script errors and CSP violations (reported as console errors)
    page.on("pageerror", lambda exc: problems.append(str(exc)))
    page.on("console", lambda m: problems.append(m.text) if m.type == "error" else None)
    page.goto(f"{shore.url}/fleet/dashboard")
    # without a token the page asks for one
    expect(page.locator("#status")).to_have_text("token needed")
    expect(page.locator("#problems")).to_contain_text("token")
    page.fill("#token", ADMIN)
    page.click("#load")

    # every unit, the one with a rejected version first, then the outlier
    rows = page.locator("#units tbody tr")
    expect(rows).to_have_count(6)
    assert rows.nth(0).get_attribute("data-unit") == "DSP-1760-SN0201"
    expect(rows.nth(0)).to_contain_text("rejected")
    (outlier,) = seeded["outliers"]
    assert rows.nth(1).get_attribute("data-unit") == outlier
    expect(rows.nth(1)).to_contain_text("outlier")
    expect(page.locator("#totals")).to_contain_text("need attention")
    # a version per batch that changed it (the recompute runs while batches arrive)
    expect(page.locator("#models")).to_have_text(
        re.compile(r"KVH-1750: fleet prior v\d+ \(1 outlier\)")
    )
    assert page.evaluate("() => sessionStorage.getItem('recal-fleet-token')") == ADMIN

    # sorting by a column reorders the rows
    page.click("#units th[data-key='unit']")
    assert rows.nth(0).get_attribute("data-unit") == "DSP-1760-SN0201"
    page.click("#units th[data-key='unit']")
    assert rows.nth(0).get_attribute("data-unit") == "KVH-1750-SN0004"

    # the drill-down: the unit's versions drawn by plotly, its events and link traffic
    page.click(f"#units tbody tr[data-unit='{outlier}']")
    expect(page.locator("#unit-name")).to_have_text(outlier)
    page.wait_for_selector("#unit-chart .scatterlayer .point")
    n = len(seeded["units"][outlier])
    assert page.locator("#unit-chart .scatterlayer .trace").first.locator(".point").count() == n
    page.select_option("#unit-coef", "accel.bias.bz")
    expect(page.locator("#unit-chart .ytitle")).to_contain_text("accel bz")
    page.wait_for_selector("#link-chart .barlayer .point")
    page.click("#units tbody tr[data-unit='DSP-1760-SN0201']")
    expect(page.locator("#events tbody tr")).to_have_count(1)
    expect(page.locator("#events")).to_contain_text("published")
    page.wait_for_selector("#unit-chart .scatterlayer .point")
    page.screenshot(path=str(tmp_path / "fleet-dashboard.png"), full_page=True)
    # the first load without a token is the only failed request
    assert problems == ["Failed to load resource: the server responded with a status of 401 "
                        "(Unauthorized)"], problems  # fmt: skip
