"""The ship's NMEA 0183 sentences (drivers.nmea): any talker, bad lines counted and skipped,
the track's window means, a whole log dated by its UTC, sentences written by pynmeagps."""

from __future__ import annotations

import datetime as dt
import math

import numpy as np
import pytest

from drivers.errors import DriverInputError
from drivers.nmea import (
    KNOT_M_S,
    NavFix,
    NavTrack,
    NmeaParser,
    circular_mean_deg,
    epoch_sentences,
    read_log,
)
from drivers.registry import input_format_names


def _checksum(body: bytes) -> bytes:
    """``$body*hh`` CR LF, hh the XOR of the bytes between $ and * (NMEA 0183)."""
    c = 0
    for b in body:
        c ^= b
    return b"$" + body + b"*%02X\r\n" % c


# Sentences as talkers send them (GGA and VTG as printed in the NMEA literature, checksums too).
GP_GGA = b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n"
GN_RMC = _checksum(b"GNRMC,123520.00,A,4807.040,N,01131.002,E,0.3,084.4,230394,,,A")
GP_VTG = b"$GPVTG,054.7,T,034.4,M,005.5,N,010.2,K*48\r\n"
HE_HDT = _checksum(b"HEHDT,274.07,T")
IN_THS = _checksum(b"INTHS,123.4,A")
#: HE_HDT with its checksum changed
BAD_SUM = HE_HDT[:-4] + (b"00" if HE_HDT[-4:-2] != b"00" else b"01") + b"\r\n"


def test_every_talker_gives_typed_fixes() -> None:
    p = NmeaParser()
    fixes = p.feed(GP_GGA + GN_RMC + GP_VTG + HE_HDT + IN_THS, host_time=12.5)
    assert [(f.talker, f.sentence) for f in fixes] == [
        ("GP", "GGA"), ("GN", "RMC"), ("GP", "VTG"), ("HE", "HDT"), ("IN", "THS")]  # fmt: skip
    gga, rmc, vtg, hdt, ths = fixes
    assert all(f.time_s == 12.5 for f in fixes)  # the caller's clock, not the sentence's
    assert gga.lat == pytest.approx(48 + 7.038 / 60) and gga.lon == pytest.approx(11 + 31 / 60)
    assert gga.height == pytest.approx(545.4 + 46.9)  # above the ellipsoid: altitude + geoid
    assert gga.utc == dt.time(12, 35, 19) and gga.date is None and math.isnan(gga.sog_kn)
    assert rmc.sog_kn == 0.3 and rmc.cog == 84.4 and rmc.date == dt.date(1994, 3, 23)
    assert vtg.sog_kn == 5.5 and vtg.cog == 54.7 and math.isnan(vtg.lat)
    assert hdt.heading_deg == 274.07 and ths.heading_deg == 123.4
    assert p.counters.fixes == 5 and p.counters.skipped == 0


def test_south_and_west_are_negative() -> None:
    fix = NmeaParser().feed_line(
        _checksum(b"GPGGA,000001,3351.000,S,15112.000,W,2,9,1.0,3.0,M,,M,,")
    )
    assert fix.lat == pytest.approx(-(33 + 51 / 60)) and fix.lon == pytest.approx(-(151 + 12 / 60))
    assert fix.height == 3.0  # no geoid separation given


def test_bad_lines_are_counted_and_skipped_never_fatal() -> None:
    p = NmeaParser()
    lines = [
        GP_GGA, BAD_SUM, b"\x00\xff\xfe garbage\r\n", b"$GPHDT,274.07,T\r\n",  # no checksum
        _checksum(b"GPGSV,3,1,11,03,03,111,00"), _checksum(b"PGRME,15.0,M,45.0,M,25.0,M"),
        b"!AIVDM,1,1,,B,177KQJ5000G?tO`K>RA1wUbN0TKH,0*5C\r\n",
        _checksum(b"GNGGA,,,,,,0,00,99.99,,,,,,"), _checksum(b"GPRMC,123520,V,,,,,,,230394,,,N"),
        _checksum(b"INTHS,,V"), b"$GPGGA,12*\r\n", IN_THS,
    ]  # fmt: skip
    fixes = p.feed(b"".join(lines), host_time=1.0)
    assert [f.sentence for f in fixes] == ["GGA", "THS"]
    c = p.counters
    assert (c.lines, c.fixes, c.bad_checksum, c.ignored, c.no_fix) == (12, 2, 2, 3, 3)
    assert c.garbage == 2 and c.skipped == 4  # '$GPGGA,12*': an empty checksum
    assert "nmea: 12 line(s), 2 fix(es)" in p.notes()[0]


def test_bytes_cut_anywhere_give_the_same_fixes() -> None:
    data = GP_GGA + GN_RMC + HE_HDT + IN_THS
    whole = NmeaParser().feed(data, 0.0)
    rng = np.random.default_rng(1)
    for _ in range(20):
        p = NmeaParser()
        cuts = sorted(rng.integers(1, len(data), 6).tolist())
        got = []
        for a, b in zip([0, *cuts], [*cuts, len(data)]):
            got += p.feed(data[a:b], 0.0)
        assert got == whole
    p = NmeaParser()
    assert p.feed(GP_GGA[:-2], 0.0) == [] and len(p.flush(0.0)) == 1  # last line, no CR LF
    p.feed(b"$GPGGA,1235", 0.0)
    p.drop()  # a cut link: the partial line is forgotten, not glued to the next
    assert len(p.feed(HE_HDT, 0.0)) == 1 and p.counters.garbage == 0


def test_written_sentences_read_back() -> None:
    utc = dt.datetime(2026, 3, 1, 23, 59, 59, 250000, tzinfo=dt.UTC)
    data = epoch_sentences(utc, -33.123456, -70.5, 12.34, 11.96, 359.97, 359.996, talker="GN",
                           heading_talker="IN", sentences=("GGA", "RMC", "VTG", "HDT", "THS"))  # fmt: skip
    fixes = NmeaParser().feed(data, 3.0)
    assert [(f.talker, f.sentence) for f in fixes] == [
        ("GN", "GGA"), ("GN", "RMC"), ("GN", "VTG"), ("IN", "HDT"), ("IN", "THS")]  # fmt: skip
    gga, rmc, vtg, hdt, ths = fixes
    assert abs(gga.lat + 33.123456) < 1e-6 and abs(gga.lon + 70.5) < 1e-6
    assert gga.height == 12.34 and gga.utc == dt.time(23, 59, 59, 250000)
    assert rmc.date == dt.date(2026, 3, 1) and rmc.sog_kn == 12.0 and vtg.sog_kn == 12.0
    assert rmc.cog == 0.0 and hdt.heading_deg == 0.0 == ths.heading_deg  # 359.97 rounds to 0
    with pytest.raises(DriverInputError, match="cannot write sentence 'GSV'"):
        epoch_sentences(utc, 0, 0, 0, 0, 0, 0, sentences=("GSV",))


def test_nmea_is_not_an_imu_format() -> None:
    assert "nmea" not in input_format_names()  # [nav] url, --nmea: a second stream


def _fix(t, lat=math.nan, lon=math.nan, sog=math.nan, heading=math.nan) -> NavFix:
    return NavFix(t, "GP", "X", lat=lat, lon=lon, height=5.0, sog_kn=sog, heading_deg=heading)


def test_window_means_and_displacement_of_a_transit() -> None:
    """12 kn due north-east for 10 min at 1 Hz: the window's displacement is 12 kn x 600 s along
    045, latitude the mean, heading the circular mean of 358 and 2."""
    v = 12.0 * KNOT_M_S
    t = np.arange(0.0, 601.0)
    lat0 = 57.0
    north = east = v * t / math.sqrt(2)
    e2, s2 = 6.69437999014e-3, math.sin(math.radians(lat0)) ** 2  # WGS-84 radii of curvature
    meridian, prime = 6378137.0 * (1 - e2) / (1 - e2 * s2) ** 1.5, 6378137.0 / (1 - e2 * s2) ** 0.5
    lat = lat0 + np.degrees(north / meridian)
    lon = 11.0 + np.degrees(east / (prime * math.cos(math.radians(lat0))))
    track = NavTrack()
    track.add(_fix(tk, la, lo, sog=12.0) for tk, la, lo in zip(t, lat, lon))
    track.add(_fix(tk, heading=358.0 if k % 2 else 2.0) for k, tk in enumerate(t[:-1]))
    track.add([])  # nothing
    w = track.window(0.0, 600.0)
    assert w.fixes == 601 and w.duration_s == 600.0
    assert w.latitude_deg == pytest.approx(np.mean(lat), abs=1e-12)
    assert w.sog_kn == pytest.approx(12.0) and w.heading_deg == pytest.approx(0.0, abs=1e-9)
    assert w.displacement_m == pytest.approx(v * 600.0, rel=2e-3)
    assert w.displacement_north_m == pytest.approx(w.displacement_east_m, rel=2e-3)
    # a window the fixes do not cover: nothing before it, or a gap of more than 30 s inside
    assert track.window(700.0, 800.0) is None
    assert track.window(-40.0, 100.0) is None
    assert track.window(-20.0, 100.0) is not None
    # shorter than the fixes' interval (a capture replayed fast): the fixes around it
    short = track.window(10.2, 10.4)
    assert short.fixes == 2 and lat[10] < short.latitude_deg < lat[11]
    assert short.sog_kn == 12.0 and short.displacement_m == pytest.approx(v * 0.2, rel=2e-3)


def test_window_without_sog_uses_the_positions_and_wraps_longitude() -> None:
    """Across the antimeridian, no SOG sentence: the speed comes from the fitted line."""
    t = np.arange(0.0, 121.0)
    lon = (179.99 + 1e-4 * t + 180.0) % 360.0 - 180.0  # eastward through 180
    track = NavTrack()
    track.add(_fix(tk, 0.0, lo) for tk, lo in zip(t, lon))
    w = track.window(0.0, 120.0)
    metres = math.radians(1e-4) * 6378137.0  # per second
    assert w.displacement_east_m == pytest.approx(metres * 120.0, rel=1e-6)
    assert w.sog_kn == pytest.approx(metres / KNOT_M_S, rel=1e-6)
    assert abs(w.longitude_deg) > 179.99 and math.isnan(w.heading_deg)


def test_track_is_bounded() -> None:
    track = NavTrack(max_age_s=10.0, max_rows=50)
    for k in range(200):
        track.add([_fix(float(k), 1.0, 2.0)])
    assert len(track) <= 50 and track.total == 200
    assert track.time_s[-1] == 199.0 and track.time_s[0] >= 199.0 - 50
    assert track.latest_position() == (199.0, 1.0, 2.0, 5.0)


def test_circular_mean() -> None:
    assert circular_mean_deg(np.array([350.0, 10.0])) == pytest.approx(0.0, abs=1e-12)
    assert circular_mean_deg(np.array([90.0, 180.0])) == pytest.approx(135.0)
    assert math.isnan(circular_mean_deg(np.array([])))


def test_a_log_is_dated_by_its_utc_across_midnight() -> None:
    """Epochs of GGA, RMC, VTG, HDT at 1 Hz over midnight: times from the first sentence, the
    untimed sentences at their epoch's time, the log's UTC start from the RMC date."""
    start = dt.datetime(2026, 3, 1, 23, 59, 58, tzinfo=dt.UTC)
    lines = b"junk before\r\n" + b"".join(
        epoch_sentences(start + dt.timedelta(seconds=k), 57.7, 11.9, 0.0, 0.2, 10.0, 20.0 + k)
        for k in range(5)
    )
    log = read_log(lines, "ship.nmea")
    t = log.track.time_s
    assert t.tolist() == [float(k) for k in range(5) for _ in range(4)]
    assert log.utc_start == start and log.duration_s == 4.0
    assert log.counters.garbage == 1 and log.counters.fixes == 20
    assert log.track.heading_deg[3::4].tolist() == [20.0, 21.0, 22.0, 23.0, 24.0]


def test_unusable_logs_are_clear_errors() -> None:
    with pytest.raises(DriverInputError, match=r"empty.nmea has no GGA.*\(0 line\(s\)\)"):
        read_log(b"", "empty.nmea")
    with pytest.raises(DriverInputError, match="1 with a bad checksum"):
        read_log(BAD_SUM + b"hello\r\n", "bad.nmea")
    with pytest.raises(DriverInputError, match="no sentence that carries UTC time"):
        read_log(HE_HDT + IN_THS, "heading-only.nmea")
