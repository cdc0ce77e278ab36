"""Format declarations, units, sequence and time handling, registry extension."""

from __future__ import annotations

import math

import numpy as np
import pytest
from drivers_testkit import assert_batches_equal, make_frames, stream_decode

import drivers
from drivers.formats import Field, FrameFormat, unregister


@pytest.mark.parametrize("fmt", ["kvh-a", "kvh-b", "kvh-c"])
def test_roundtrip_all_data_formats(fmt: str) -> None:
    data, v = make_frames(300, fmt, seed=1)
    batch, counters = drivers.decode_bulk(data, fmt)
    assert len(batch) == 300 and counters.frames == 300 and counters.bytes_skipped == 0
    assert counters.balanced() and counters.resyncs == 0
    cfg = drivers.DEFAULT_CONFIG
    np.testing.assert_array_equal(batch.gyro_dph, v["gyro"] * cfg.gyro_to_dph)
    np.testing.assert_array_equal(batch.accel_g, v["accel_g"])
    np.testing.assert_array_equal(batch.seq, v["seq"])
    assert batch.valid.all() and (batch.lost_before == 0).all()
    np.testing.assert_allclose(batch.time_s, np.arange(300) / 1000.0, atol=1e-12)
    assert batch.gyro_dph.dtype == np.float64 and batch.seq.dtype == np.int64
    assert batch.status.dtype == np.uint8 and batch.valid.dtype == bool
    assert np.isnan(batch.host_time_s).all()
    assert counters.headers_seen[fmt] == 300


def test_format_c_multiplexed_slot() -> None:
    data, v = make_frames(64, "kvh-c", seed=2)
    batch, _ = drivers.decode_bulk(data, "kvh-c")
    which = batch.seq % 4
    np.testing.assert_array_equal(batch.temperature_c[which == 0], v["temperature_raw"][which == 0])
    assert np.isnan(batch.temperature_c[which != 0]).all()
    for axis in range(3):
        sel = which == axis + 1
        np.testing.assert_array_equal(batch.mag_gauss[sel, axis], v["mag_gauss"][sel, axis])
        assert np.isnan(np.delete(batch.mag_gauss[sel], axis, axis=1)).all()
    assert np.isnan(batch.mag_gauss[which == 0]).all()


def test_format_b_time_from_wrapping_timestamp() -> None:
    data, v = make_frames(20, "kvh-b", seed=3)  # timestamps cross 2**32
    assert (np.diff(v["timestamp_us"]) < 0).any()
    batch, _ = drivers.decode_bulk(data, "kvh-b")
    np.testing.assert_allclose(batch.time_s, np.arange(20) * 1e-3, atol=1e-12)


def test_sequence_wrap_gap_and_time_from_sequence() -> None:
    seq = np.array([125, 126, 127, 0, 1, 5, 6, 6])
    data = drivers.encode_frames("kvh-a", seq=seq)
    cfg = drivers.DecoderConfig(rate_hz=200.0)
    batch, c = drivers.decode_bulk(data, "kvh-a", cfg)
    np.testing.assert_array_equal(batch.lost_before, [0, 0, 0, 0, 0, 3, 0, 127])
    assert c.sequence_gaps == 2 and c.frames_lost == 130
    np.testing.assert_allclose(batch.time_s[:7], np.array([0, 1, 2, 3, 4, 8, 9]) / 200.0)


def test_units_configuration() -> None:
    one = drivers.encode_frames("kvh-a", gyro=np.array([[1.0, -2.0, 0.5]]), temperature_raw=[2345])
    b, _ = drivers.decode_bulk(one, "kvh-a", drivers.DecoderConfig("rate", "deg", "centi"))
    np.testing.assert_allclose(b.gyro_dph[0], [3600.0, -7200.0, 1800.0])
    assert b.temperature_c[0] == pytest.approx(23.45)
    b, _ = drivers.decode_bulk(one, "kvh-a", drivers.DecoderConfig("delta", "deg", rate_hz=100))
    np.testing.assert_allclose(b.gyro_dph[0], [360000.0, -720000.0, 180000.0])
    b, _ = drivers.decode_bulk(one, "kvh-a", drivers.DecoderConfig("rate", "rad"))
    np.testing.assert_allclose(b.gyro_dph[0, 0], 180 / math.pi * 3600)
    cfg = drivers.DecoderConfig(rate_hz=500)
    dph = np.array([[15.04107, -1.0, 100.0]])
    np.testing.assert_allclose(
        drivers.raw_to_physical_gyro(drivers.physical_to_raw_gyro(dph, cfg), cfg), dph
    )
    with pytest.raises(drivers.DriverInputError, match="gyro units"):
        drivers.DecoderConfig(gyro_units="grad")
    with pytest.raises(drivers.DriverInputError, match="data rate"):
        drivers.DecoderConfig(rate_hz=0)


def test_invalid_status_kept_and_flagged() -> None:
    good, _ = make_frames(5, seed=4)
    bad, _ = make_frames(3, seed=5, seq0=5, status=0x73)
    batch, c = drivers.decode_bulk(good + bad)
    assert len(batch) == 8 and c.invalid_status == 3
    assert batch.valid.tolist() == [True] * 5 + [False] * 3
    assert (batch.status[5:] == 0x73).all()


def test_bit_message() -> None:
    bits = np.array([[0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x7F], [1, 2, 3, 4, 5, 6]], dtype=np.uint8)
    data = drivers.encode_frames("kvh-bit", bit_data=bits)
    assert len(data) == 22 and data[:4] == b"\xfe\x81\x00\xaa"
    assert data[10] == sum(data[:10]) % 256
    batch, c = drivers.decode_bulk(data, "kvh-bit")
    assert len(batch) == 2 and c.invalid_status == 0
    np.testing.assert_array_equal(batch.extra["bit_data"], bits)
    corrupted = bytearray(data)
    corrupted[5] ^= 1
    batch, c = drivers.decode_bulk(bytes(corrupted), "kvh-bit")
    assert len(batch) == 1 and c.crc_failures == 1


def test_registry_and_a_second_family() -> None:
    assert drivers.format_names()[:4] == ["kvh-a", "kvh-b", "kvh-c", "kvh-bit"]
    with pytest.raises(drivers.DriverInputError, match="unknown frame format 'xsens'.*kvh-a"):
        drivers.get_format("xsens")
    toy = drivers.register(
        FrameFormat(
            name="toy-test",
            label="Toy",
            family="Test",
            header=b"\xaa\x55",
            length=20,
            check="crc32-mpeg2",
            fields={
                "seq": Field(2, "u1"),
                "status": Field(3, "u1"),
                "accel": Field(4, ">i4", 3),
            },
            accel_scale=1e-6,
        )
    )
    try:
        accel = np.array([[1.0, -0.5, 0.25]] * 4)
        data = drivers.encode_frames(toy, accel_g=accel, seq=[0, 1, 2, 4])
        batch, c = drivers.decode_bulk(data, "toy-test")
        np.testing.assert_allclose(batch.accel_g, accel)
        assert np.isnan(batch.gyro_dph).all() and c.frames_lost == 1
        stream, sc = stream_decode(data, [3, 7, 30], "toy-test")
        assert_batches_equal(batch, stream)
        assert sc == c
        # the KVH decoders now count the new family's headers too
        _, kc = drivers.decode_bulk(data, "kvh-a")
        assert kc.headers_seen["toy-test"] == 4
    finally:
        unregister("toy-test")
    assert "toy-test" not in drivers.format_names()


def test_batch_concat_slice_and_empty() -> None:
    data, _ = make_frames(10)
    b, _ = drivers.decode_bulk(data)
    parts = [b[:3], b[3:3], b[3:]]
    assert_batches_equal(drivers.FrameBatch.concat(parts), b, host_time=True)
    assert len(b[b.seq % 2 == 0]) == 5
    e = drivers.FrameBatch.empty("kvh-a")
    assert len(e) == 0 and e.gyro_dph.shape == (0, 3)
    assert len(drivers.concat_batches([], "kvh-a")) == 0


def test_drivers_import_no_calibration_code() -> None:
    import ast
    from pathlib import Path

    root = Path(drivers.__file__).resolve().parent
    allowed = {"numpy", "serial", "pynmeagps"}  # pynmeagps: the NMEA parser (drivers.nmea)
    for path in root.glob("*.py"):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module or ""]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                assert top not in ("recal", "service"), f"{path.name} imports {name}"
                assert top in allowed or top in __import__("sys").stdlib_module_names, (
                    f"{path.name} imports {name}"
                )
