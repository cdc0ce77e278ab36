"""`recal demo --fleet`: a shore on SQLite and three simulated vessels whose daemons sync to it.
Every vessel's rows arrive exactly once (the shore's counts are the vessel's), one unit ages and
has a version rejected, and the dashboard's URL is printed."""

import re

import pytest
from sqlalchemy import create_engine, text

from service.cli.demo_fleet import VESSEL_TABLES, VESSELS, vessel_counts
from service.cli.main import main


@pytest.mark.slow
def test_demo_fleet_syncs_every_vessel_once(tmp_path, capsys):
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
