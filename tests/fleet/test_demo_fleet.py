"""`recal demo --fleet`: a shore on SQLite and three simulated vessels whose daemons sync to it.
Every vessel's rows arrive exactly once (the shore's counts are the vessel's), one unit ages and
has a version rejected, and the dashboard's URL is printed; the demo's shore, served again as
``--serve`` would keep it, shows them on the fleet dashboard in a real browser."""

import re
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import create_engine, text

from service.cli.demo_fleet import VESSEL_TABLES, VESSELS, vessel_counts
from service.cli.main import main


@pytest.mark.slow
def test_demo_fleet_syncs_every_vessel_once(tmp_path, capsys, request, run_server):
    folder = tmp_path / "fleet"
    assert main(["demo", "--fleet", "--dir", str(folder)]) == 0
    out = capsys.readouterr().out
    assert re.search(
        r"3 units, \d+ versions \(1 rejected\), \d+ rows synced, every outbox empty", out
    ), out
    assert re.search(r"fleet dashboard: http://127\.0\.0\.1:\d+/fleet/dashboard", out), out
    # after the demo: what each vessel's database holds, the shore holds once
    engine = create_engine(f"sqlite:///{folder / 'fleet.db'}")
    try:
        with engine.connect() as conn:
            for v in VESSELS:
                mine = vessel_counts(f"sqlite:///{folder / f'{v.serial}.db'}")
                assert mine["window"] >= 24 and mine["version"] >= 1, (v.serial, mine)
                for kind, n in mine.items():
                    table = "fleet_" + {"window": "windows"}.get(kind, kind + "s")
                    shore = conn.execute(
                        text(f"SELECT count(*), count(DISTINCT vessel_id) FROM {table} t "
                             "JOIN fleet_units u ON u.id = t.unit_id WHERE u.serial = :s"),
                        {"s": v.serial},
                    ).one()  # fmt: skip
                    assert tuple(shore) == (n, n), (v.serial, kind, n, tuple(shore))
            rejected = conn.execute(
                text("SELECT u.serial FROM fleet_versions v JOIN fleet_units u ON u.id = v.unit_id "
                     "WHERE NOT v.accepted")
            ).scalars().all()  # fmt: skip
    finally:
        engine.dispose()
    assert rejected == [next(v.serial for v in VESSELS if v.ages)]
    assert set(VESSEL_TABLES) == {"session", "window", "slew", "version", "event"}
    line = next(ln for ln in out.splitlines() if ln.startswith(rejected[0]))
    assert "drift" in line and line.split()[-6] == "yes:", line

    # the dashboard the demo points at, in Debian's chromium (skipped without it, except
    # under CI): the demo's shore database served again, as --serve keeps it up
    admin = re.search(r"administrator's token: (\S+)\)", out).group(1)
    browser = request.getfixturevalue("browser")
    _dashboard_shows_the_demo(browser, run_server, folder, admin, rejected[0])


def _dashboard_shows_the_demo(
    browser: Any, run_server: Any, folder: Path, admin: str, aged: str
) -> None:
    from playwright.sync_api import expect

    from service.fleet.config import ShoreApiSettings, ShoreSettings
    from service.fleet.server import make_server, open_store

    settings = ShoreSettings(database_url=f"sqlite:///{folder / 'fleet.db'}",
                             api=ShoreApiSettings(host="127.0.0.1", port=0, token=admin))  # fmt: skip
    store = open_store(settings)
    page = browser.new_page(viewport={"width": 1600, "height": 1000})
    try:
        with run_server(make_server(settings, store, log_level="warning")) as port:
            errors: list[str] = []
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            page.goto(f"http://127.0.0.1:{port}/fleet/dashboard")
            page.fill("#token", admin)
            page.click("#load")
            rows = page.locator("#units tbody tr")
            expect(rows).to_have_count(len(VESSELS))
            # the unit that aged and had a version rejected needs attention first
            assert rows.nth(0).get_attribute("data-unit") == aged
            expect(rows.nth(0)).to_contain_text("rejected")
            expect(page.locator("#totals")).to_contain_text("need attention")
            page.click(f"#units tbody tr[data-unit='{aged}']")
            expect(page.locator("#unit-name")).to_have_text(aged)
            page.wait_for_selector("#unit-chart .scatterlayer .point")
            page.screenshot(path=str(folder / "fleet-dashboard.png"), full_page=True)
            assert errors == [], errors
    finally:
        page.close()
        store.close()
