"""A simulated ship under way (recal.sim.vessel ``transit``) and its own sensors (issue 36): the
gyro sees Earth's rate at the latitude reached plus the transport rate, the accelerometers the
Coriolis and Eotvos accelerations; `recal simulate --berth --nmea` writes GGA/RMC/VTG/HDT."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.nmea import read_log
from recal.detect.underway import EARTH_RADIUS_M
from recal.model.reference import OMEGA_IE_RAD_S, normal_gravity_g
from recal.sim.simulate import NoiseSpec
from recal.sim.vessel import ship_track, simulate_vessel
from recal.sim.vessel_spec import SeaState, Segment, VesselSpec
from service.capture_sim import kvh_like_truth
from service.cli.main import main

KN = 1852.0 / 3600.0
DPH = math.degrees(1.0) * 3600.0


@pytest.mark.parametrize("heading", [0.0, 90.0])
def test_a_transit_carries_transport_rate_earth_rate_and_coriolis(heading) -> None:
    """A calm, noise-free 12 kn transit from 45 deg: in the steady part the inputs are the
    navigation frame's inertial rate at the latitude reached and (2 w_ie + w_en) x v."""
    spec = VesselSpec((Segment("hold", 60.0), Segment("transit", 600.0, speed_kn=12.0),
                       Segment("hold", 60.0)), heading0_deg=heading, sea=SeaState.calm())  # fmt: skip
    rec = simulate_vessel(kvh_like_truth(1), spec, 45.0, rate_hz=10.0, noise=NoiseSpec(0, 0))
    s = rec.session
    t = s.time_s + 0.05  # the inputs are at the middle of each sample interval
    track = ship_track(spec, t, 45.0)
    steady = (t > 200.0) & (t < 500.0)
    lat = np.radians(track["latitude_deg"][steady])
    v = 12.0 * KN
    vn, ve = v * math.cos(math.radians(heading)), v * math.sin(math.radians(heading))
    # body = NED (level, mount 0) rotated by the heading: check in NED
    w_n = np.column_stack([OMEGA_IE_RAD_S * np.cos(lat) + ve / EARTH_RADIUS_M,
                           np.full(lat.size, -vn / EARTH_RADIUS_M),
                           -OMEGA_IE_RAD_S * np.sin(lat) - ve * np.tan(lat) / EARTH_RADIUS_M])  # fmt: skip
    psi = math.radians(heading)
    C_bn = np.array([[math.cos(psi), math.sin(psi), 0], [-math.sin(psi), math.cos(psi), 0],
                     [0, 0, 1]])  # fmt: skip
    np.testing.assert_allclose(s.gyro_in_dph[steady], w_n @ C_bn.T * DPH, atol=2e-6)
    transport = np.hypot(vn, ve) / EARTH_RADIUS_M * DPH
    assert transport == pytest.approx(0.1996, abs=1e-4)  # 12 kn: 0.2 deg/h
    # Coriolis: 2 w_ie x v; north-going, its east part is -2 Omega v sin(lat)
    f = s.accel_in_g[steady] @ C_bn  # body -> NED
    if heading == 0.0:
        expected = -2 * OMEGA_IE_RAD_S * v * np.sin(lat) / 9.80665
        np.testing.assert_allclose(f[:, 1], expected, atol=1e-9)
        assert abs(expected.mean()) == pytest.approx(64.9e-6, rel=1e-2)
    else:  # east-going, at 45 deg throughout: the Eotvos effect lightens by 2 Omega v cos + v^2/R
        lift = f[:, 2] + normal_gravity_g(45.0)  # the down acceleration, g
        eotvos = 2 * OMEGA_IE_RAD_S * v * math.cos(math.radians(45.0)) + v**2 / EARTH_RADIUS_M
        np.testing.assert_allclose(lift, eotvos / 9.80665, atol=1e-9)
        assert eotvos / 9.80665 == pytest.approx(65.5e-6, rel=1e-2)  # 12 kn east at 45 deg


def test_ship_track_sails_the_transit() -> None:
    spec = VesselSpec.berth(holds=2, hold_s=100.0, turn_deg=0.0, transit_s=400.0, transit_kn=10.0)
    assert [s.kind for s in spec.segments] == ["hold", "transit", "turn", "hold"]
    t = np.arange(0.0, spec.duration_s, 1.0)
    tr = ship_track(spec, t, 10.0, 170.0)
    sailed = 10.0 * KN * (400.0 - spec.speed_ramp_s)  # ramps of 60 s: half their time at speed
    assert math.radians(tr["latitude_deg"][-1] - 10.0) * EARTH_RADIUS_M == pytest.approx(sailed)
    assert tr["sog_kn"].max() == pytest.approx(10.0) and tr["sog_kn"][0] == 0.0
    assert np.all(tr["sog_kn"][t >= 500.0] == 0.0) and np.all(tr["cog_deg"] == 0.0)


@pytest.mark.slow
def test_simulate_writes_the_ships_nmea_alongside(tmp_path, capsys) -> None:
    out, nmea = tmp_path / "b.bin", tmp_path / "b.nmea"
    argv = ["simulate", "--berth", "--holds", "2", "--hold", "130", "--rate", "10", "--transit",
            "200", "--transit-kn", "8", "--latitude", "-33.9", "--longitude", "151.2",
            "--attitude", "0,0,90", "--capture", str(out), "--nmea", str(nmea),
            "--nmea-rate", "2"]  # fmt: skip
    assert main(argv) == 0
    assert "--nmea " + str(nmea) in capsys.readouterr().err
    lines = nmea.read_bytes().splitlines()
    duration = 130 + 200 + 60 + 130
    assert len(lines) == 4 * 2 * duration
    assert [ln[:6] for ln in lines[:4]] == [b"$GPGGA", b"$GPRMC", b"$GPVTG", b"$HEHDT"]
    log = read_log(nmea.read_bytes(), "b.nmea")
    assert log.counters.skipped == 0 and log.utc_start.isoformat() == "2026-03-01T00:00:00+00:00"
    track = log.track
    np.testing.assert_allclose(np.unique(track.time_s)[:3], [0.0, 0.5, 1.0], atol=1e-9)
    assert track.lat[0] == pytest.approx(-33.9, abs=1e-6) and track.lon[0] == pytest.approx(151.2)
    assert np.nanmax(track.sog_kn) == pytest.approx(8.0, abs=0.05)
    east = track.window(150.0, 300.0)  # under way due east
    assert east.sog_kn > 6 and east.displacement_east_m > 400 and abs(east.heading_deg - 90) < 1


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--indexing", "0,0,0/0,0,90", "--transit", "100"], "--transit sails between berths"),
        (["--berth", "--nmea-rate", "50", "--nmea", "x.nmea"], "0.1 to 10 fixes/s"),
        (["--berth", "--utc-start", "noon", "--nmea", "x.nmea"], "--utc-start 'noon'"),
        (["--berth", "--transit", "60"], "shorter than its two 60 s speed ramps"),
        (["--nmea", "x.nmea"], "--nmea and --transit need --berth"),
    ],
)
def test_bad_transit_or_nmea_options_are_exit_2(tmp_path, capsys, extra, message) -> None:
    argv = ["simulate", *extra, "--capture", str(tmp_path / "c.bin")]
    argv = [a if a != "x.nmea" else str(tmp_path / "x.nmea") for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err
    assert not (tmp_path / "x.nmea").exists()
