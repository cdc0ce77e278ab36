"""`recal positions ... --nmea LOG` (issue 36): the ship's sensors from a log beside the
recording. A simulated berth with a 15-minute transit at 12 kn between two berths (`recal
simulate --berth --transit --nmea`): the windows taken under way are rejected as `underway`,
none is kept in the transit, and the windows at either berth carry its latitude."""

from __future__ import annotations

import csv
import inspect
from pathlib import Path

import numpy as np
import pytest

from drivers.nmea import circular_mean_deg
from recal.detect.underway import DEFAULT_MAX_SOG_KN
from recal.sim.vessel import ship_track
from recal.sim.vessel_spec import VesselSpec
from service.cli import ship as ship_cli
from service.cli import simulate_args
from service.cli.main import main
from service.config import NavSettings

LAT, LON = 57.7, 11.9
SIM = ["--berth", "--holds", "4", "--hold", "300", "--rate", "20", "--seed", "2",
       "--transit", "900", "--latitude", str(LAT), "--longitude", str(LON)]  # fmt: skip


def _sentence(body: bytes) -> bytes:
    c = 0
    for b in body:
        c ^= b
    return b"$" + body + b"*%02X\r\n" % c


RMC = _sentence(b"GPRMC,120000.00,A,5742.000,N,01154.000,E,0.1,10.0,010326,,,A")


def _rows(path: Path) -> list[dict]:
    """A CSV's rows, numbers as floats."""

    def cell(v: str):
        try:
            return float(v)
        except ValueError:
            return v

    with path.open() as fh:
        return [{k: cell(v) for k, v in r.items()} for r in csv.DictReader(fh)]


@pytest.fixture(scope="module")
def transit(tmp_path_factory):
    """4 holds of 5 min in a 0.3-degree sea at 20 Hz, a 900 s transit at 12 kn after the second
    (on heading 30), the ship's NMEA log at 1 Hz, and the schedule."""
    d = tmp_path_factory.mktemp("transit")
    argv = [*SIM, "--capture", str(d / "t.bin"), "--track", str(d / "sched.csv"),
            "--nmea", str(d / "t.nmea")]  # fmt: skip
    assert main(["simulate", *argv]) == 0
    return d


def _positions(d: Path, out: Path, *extra: str) -> int:
    return main(["positions", str(d / "t.bin"), "--format", "kvh-a", "--rate", "20",
                 "--motion", "hull", "--nmea", str(d / "t.nmea"), *extra, "-o", str(out)])  # fmt: skip


def test_defaults_repeated_for_the_parsers_match() -> None:
    assert ship_cli.MAX_SOG_KN == DEFAULT_MAX_SOG_KN == NavSettings().max_sog_kn
    berth = inspect.signature(VesselSpec.berth).parameters
    assert simulate_args.VESSEL_TRANSIT_KN == berth["transit_kn"].default


@pytest.mark.slow
def test_a_transit_at_12_kn_is_rejected_as_underway_and_the_berths_keep_their_latitude(
    transit, tmp_path, capsys
) -> None:
    d = transit
    capsys.readouterr()
    out = tmp_path / "p.csv"
    assert _positions(d, out) == 0
    err = capsys.readouterr().err
    sched = {int(r["segment"]): r for r in _rows(d / "sched.csv")}
    t0, t1 = sched[3]["start_s"], sched[3]["end_s"]
    assert sched[3]["speed_kn"] == 12.0 and (t0, t1) == (660.0, 1560.0)
    rows = _rows(out)
    # windows rejected as underway, counted in the summary; none kept overlaps the transit
    underway = int(err.split("underway: ")[1].split(" window")[0])
    assert underway >= 1 and "nmea: 9120 line(s), 9120 fix(es)" in err
    assert all(r["end_s"] <= t0 or r["start_s"] >= t1 for r in rows), rows
    assert any(r["end_s"] <= t0 for r in rows) and any(r["start_s"] >= t1 for r in rows)
    # each kept window's latitude is the simulated ship's over it (the second berth is 4.5 km
    # further north: 0.04 deg)
    spec = VesselSpec.berth(4, 300.0, transit_s=900.0)
    for r in rows:
        t = np.arange(r["start_s"], r["end_s"], 1.0)
        truth = ship_track(spec, t, LAT, LON, seed=2)
        assert abs(r["latitude_deg"] - truth["latitude_deg"].mean()) < 1e-3
        heading = circular_mean_deg(truth["heading_deg"])
        assert r["sog_kn"] < 0.05 and abs((r["heading_deg"] - heading + 180) % 360 - 180) < 0.1
    lats = sorted({round(r["latitude_deg"], 3) for r in rows})
    assert lats == [LAT, round(LAT + 0.04034, 3)]
    # a ship at its berth has no net displacement: the gyro sigma is the detector's, grown only
    # along the vertical by the 1-sigma of the heading creep the log's heading measures (the
    # window's vertical rate then stays a measurement; without the log it is none:
    # recal.detect.creep)
    plain = tmp_path / "plain.csv"
    assert main(["positions", str(d / "t.bin"), "--format", "kvh-a", "--rate", "20", "--motion",
                 "hull", "--latitude", str(LAT), "-o", str(plain)]) == 0  # fmt: skip
    by_start = {r["start_s"]: r for r in _rows(plain)}
    for r in rows:
        p = by_start[r["start_s"]]
        assert r["gyro_x_sem"] == pytest.approx(p["gyro_x_sem"], rel=1e-3)
        assert r["gyro_z_sem"] >= p["gyro_z_sem"] and p["gyro_vertical"] == 0
        # the window's mean yaw rate (the berth's yaw swing over the window: up to 2 deg/h) from
        # the log's heading, as the gyro's vertical excess estimates it without the log
        assert r.get("gyro_vertical", 1) == 1 and abs(r["creep_dph"] - p["creep_dph"]) < 0.2
    # a threshold above the transit's speed keeps the transit's windows, their gyro sigma grown
    # by the transport rate of 12 kn: 0.2 deg/h x (1 + tan 57.7) = 0.52 deg/h
    fast = tmp_path / "fast.csv"
    assert _positions(d, fast, "--max-sog", "20") == 0
    moving = [r for r in _rows(fast) if r["sog_kn"] > 11.0]
    assert moving and all(min(r[f"gyro_{a}_sem"] for a in "xyz") > 0.5 for r in moving)


@pytest.mark.slow
def test_the_log_is_aligned_by_utc_when_both_carry_it(transit, tmp_path, capsys) -> None:
    """The simulated log starts at 2026-03-01T00:00:00Z, the recording's first sample."""
    d = transit
    same, late = tmp_path / "same.csv", tmp_path / "late.csv"
    assert _positions(d, same, "--utc-start", "2026-03-01T00:00:00Z") == 0
    assert "aligned by UTC: the log starts at +0.0 s" in capsys.readouterr().err
    assert sorted({round(r["latitude_deg"], 3) for r in _rows(same)}) == [LAT, 57.74]
    # a recording said to start an hour later: its windows are past the log's end
    assert _positions(d, late, "--utc-start", "2026-03-01T01:00:00Z") == 0
    err = capsys.readouterr().err
    assert "0 of 5 window(s) covered; underway: 0" in err and "covers none of the windows" in err
    assert "latitude_deg" not in late.read_text().splitlines()[0]


@pytest.mark.parametrize(
    "log, extra, message",
    [
        (None, [], "NMEA log {missing} does not exist"),
        (b"", [], "has no GGA, RMC, VTG, HDT or THS sentence with data (0 line(s))"),
        (b"hello\r\n$GPGGA,1,2*00\r\n", [], "1 with a bad checksum, 1 unreadable"),
        (_sentence(b"HEHDT,274.07,T"), [], "no sentence that carries UTC time"),
        (b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n",
         ["--utc-start", "2026-03-01T00:00:00Z"], "carries no date (no RMC sentence)"),
        (RMC, ["--utc-start", "yesterday"], "--utc-start 'yesterday': expected an ISO 8601"),
    ],
)  # fmt: skip
def test_an_unusable_log_is_exit_2_and_nothing_is_written(
    tmp_path, capsys, log, extra, message
) -> None:
    rec = tmp_path / "r.csv"
    rec.write_text("time_s,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z\n0,0,0,15,0,0,1\n")
    path = tmp_path / "ship.nmea"
    if log is not None:
        path.write_bytes(log)
    out = tmp_path / "p.csv"
    argv = ["positions", str(rec), "--format", "csv", "--nmea", str(path), *extra, "-o", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("recal positions: error: ") and err.count("\n") == 1
    assert message.format(missing=path) in err, err
    assert not out.exists()


def test_ship_options_need_nmea(tmp_path, capsys) -> None:
    rec = tmp_path / "r.csv"
    rec.write_text("time_s,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z\n0,0,0,15,0,0,1\n")
    argv = ["positions", str(rec), "--format", "csv", "--max-sog", "3", "-o", str(tmp_path / "p")]
    assert main(argv) == 2
    assert "--max-sog needs --nmea LOG" in capsys.readouterr().err
