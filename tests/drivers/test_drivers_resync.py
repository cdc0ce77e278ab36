"""Issue 8 item 8: resynchronisation never loses an intact frame, and lost frames are counted
across wraps of the 7-bit sequence number (from Format B time or the host clock)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from drivers_testkit import assert_batches_equal, make_frames, stream_decode
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import drivers
from drivers.bulk import decode_bulk_with_offsets
from drivers.capture import SIDE_HEADER, decode_capture, side_path

SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
FORMATS = ["kvh-a", "kvh-b", "kvh-c"]


def fe_ending_frame(fmt: str, seq: int, seed: int = 0) -> bytes:
    """A valid frame whose last byte (the end of its CRC) is 0xFE, the first byte of a header:
    cut one byte short, it passes its CRC with the next frame's first byte."""
    rng = np.random.default_rng(seed)
    n = 4096
    gyro = np.repeat(rng.normal(0, 2e-5, (1, 3)), n, axis=0)
    gyro[:, 2] += np.arange(n) * 1e-9  # vary one field until the CRC ends in FE
    kw = {"timestamp_us": np.full(n, 1000 * seq)} if fmt == "kvh-b" else {}
    rows = drivers.encode_frames(fmt, gyro=gyro, seq=np.full(n, seq), **kw)
    length = drivers.get_format(fmt).length
    frames = np.frombuffer(rows, dtype=np.uint8).reshape(n, length)
    pick = np.flatnonzero(frames[:, -1] == 0xFE)
    assert pick.shape[0]
    return frames[pick[0]].tobytes()


def stream_with_fe_frames(fmt: str, n: int, fe_at: set[int], seed: int = 0) -> list[bytes]:
    raw, _ = make_frames(n, fmt, seed=seed)
    length = drivers.get_format(fmt).length
    frames = [raw[i * length : (i + 1) * length] for i in range(n)]
    for i in fe_at:
        frame = fe_ending_frame(fmt, i, seed + i)
        if fmt == "kvh-b":  # keep the stream's own timestamps
            frame = frames[i][:28] + frame[28:32] + frames[i][32:]
            frame = drivers.encode_frames(
                fmt,
                gyro=np.frombuffer(frame[4:16], ">f4")[None].astype(float),
                accel_g=np.frombuffer(frames[i][16:28], ">f4")[None].astype(float),
                seq=[i],
                timestamp_us=[int.from_bytes(frames[i][28:32], "big")],
                temperature_raw=[int.from_bytes(frames[i][34:36], "big", signed=True)],
            )
            if frame[-1] != 0xFE:
                frame = fe_ending_frame(fmt, i, seed + i)
        frames[i] = frame
    return frames


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_frame_cut_one_byte_short_never_costs_the_next_frame(fmt: str) -> None:
    # Every position of the cut frame in the stream (first, middle, last), and every chunking
    # boundary around it: before the fix the cut frame passed its CRC with the next frame's
    # 0xFE and swallowed that frame's header, losing an intact frame.
    n = 8
    length = drivers.get_format(fmt).length
    for i in range(n):
        frames = stream_with_fe_frames(fmt, n, {i}, seed=3)
        assert frames[i][-1] == 0xFE and frames[(i + 1) % n][0] == 0xFE
        data = b"".join(f[:-1] if j == i else f for j, f in enumerate(frames))
        bulk, c = drivers.decode_bulk(data, fmt)
        assert bulk.seq.tolist() == [j for j in range(n) if j != i], i
        assert c.bytes_skipped == length - 1 and c.balanced()
        assert c.misaligned == (1 if i < n - 1 else 0)  # the last one is only truncated
        assert c.frames_lost == (1 if 0 < i < n - 1 else 0)
        lo = i * length
        for cut in range(max(0, lo - 2), min(len(data), lo + 2 * length + 6)):
            stream, sc = stream_decode(data, [cut], fmt)
            assert_batches_equal(bulk, stream)
            assert sc == c
        stream, sc = stream_decode(data, list(range(0, len(data), 5)), fmt)
        assert_batches_equal(bulk, stream)
        assert sc == c


@pytest.mark.parametrize("fmt", FORMATS)
def test_dropping_any_byte_of_a_frame_keeps_every_intact_frame(fmt: str) -> None:
    n = 6
    length = drivers.get_format(fmt).length
    frames = stream_with_fe_frames(fmt, n, {2}, seed=5)
    for k in range(length):
        damaged = frames[2][:k] + frames[2][k + 1 :]
        data = b"".join(frames[:2]) + damaged + b"".join(frames[3:])
        bulk, c = drivers.decode_bulk(data, fmt)
        assert bulk.seq.tolist() == [0, 1, 3, 4, 5], k
        stream, sc = stream_decode(data, list(range(3, len(data), 17)), fmt)
        assert_batches_equal(bulk, stream)
        assert sc == c


def test_a_header_lining_up_keeps_the_frame() -> None:
    # An intact frame ending in FE followed by a frame that lost its first byte: the bytes are
    # the same as a cut frame followed by an intact one, and both readings agree on the rule
    # (the frame followed by a header is kept); with a BIT reply after it, it is kept as well.
    frames = stream_with_fe_frames("kvh-a", 4, {1}, seed=7)
    bit = drivers.encode_frame("kvh-bit", bit_data=np.arange(6))
    data = frames[0] + frames[1] + bit + frames[2] + frames[3]
    bulk, c = drivers.decode_bulk(data)
    assert bulk.seq.tolist() == [0, 1, 2, 3] and c.misaligned == 0


def _cut_stream(fmt: str, n: int, seed: int, draw) -> tuple[bytes, dict[int, int], list[bytes]]:
    length = drivers.get_format(fmt).length
    fe_at = set(draw(st.sets(st.integers(0, n - 1), max_size=4)))
    frames = stream_with_fe_frames(fmt, n, fe_at, seed=seed)
    cut = draw(st.dictionaries(st.integers(0, n - 1), st.integers(1, length - 1), max_size=4))
    out = bytearray()
    for i, f in enumerate(frames):
        out += f[: length - cut[i]] if i in cut else f
    return bytes(out), cut, frames


@SETTINGS
@given(fmt=st.sampled_from(FORMATS), n=st.integers(1, 20), seed=st.integers(0, 999), data=st.data())
def test_cut_frames_with_fe_endings_any_chunking(fmt: str, n: int, seed: int, data) -> None:
    raw, cut, frames = _cut_stream(fmt, n, seed, data.draw)
    bulk, c = drivers.decode_bulk(raw, fmt)
    got = bulk.seq.tolist()
    assert set(range(n)) - set(cut) <= set(got) and got == sorted(got)  # every intact frame
    # and a cut frame only when its check proves its content whole: one byte short, that
    # byte a 0xFE, and the next frame not intact (else that frame would win)
    for i in set(got) & set(cut):
        assert cut[i] == 1 and frames[i][-1] == 0xFE and i + 1 in cut
    cuts = data.draw(st.lists(st.integers(0, len(raw)), max_size=12))
    stream, sc = stream_decode(raw, cuts, fmt)
    assert_batches_equal(bulk, stream)
    assert sc == c and c.balanced()
    assert sc.bytes_pending == 0


def test_pending_stays_below_two_frames() -> None:
    frames = stream_with_fe_frames("kvh-a", 40, set(range(0, 40, 3)), seed=1)
    data = b"".join(f[:-1] if i % 6 == 0 else f for i, f in enumerate(frames))
    dec = drivers.StreamDecoder()
    for i in range(len(data)):
        dec.feed(data[i : i + 1], host_time=math.nan)
        assert dec.pending < 2 * 36 and dec.counters.balanced()


# --- lost frames across a wrap of the sequence number -------------------------------------


def _unplugged(fmt: str, rate: float, before: int, away: int, after: int):
    """Frames 0..before-1, then ``away`` frames never received, then ``after`` frames."""
    k = np.r_[np.arange(before), np.arange(before + away, before + away + after)]
    kw = {"timestamp_us": (k * round(1e6 / rate) + 4_294_000_000) % 2**32}
    raw = drivers.encode_frames(fmt, seq=k, **(kw if fmt == "kvh-b" else {}))
    return raw, k


def _chunked_feed(dec, raw: bytes, k: np.ndarray, length: int, rate: float, per: int, t0=50.0):
    """Feed ``per`` frames per read, each read stamped when its last frame would have come."""
    parts = []
    offsets, times = [], []
    for i in range(0, len(k), per):
        j = min(i + per, len(k)) - 1
        t = round(t0 + k[j] / rate + 0.004, 6)  # a few ms of USB/OS latency; as in a side file
        offsets.append(i * length)
        times.append(t)
        parts.append(dec.feed(raw[i * length : (j + 1) * length], host_time=t))
    parts.append(dec.flush())
    return drivers.FrameBatch.concat(parts), np.array(offsets), np.array(times)


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_1000_frame_unplug_is_counted_in_full(fmt: str, tmp_path) -> None:
    # The case: 200 Hz, 1,000 frames away. Before: 104 counted (1000 mod 128) and
    # Format A device time 4.48 s behind. Format B counts from its timestamp (across the uint32
    # wrap at 4295 s), A and C from the host receive times of the reads.
    rate = 200.0
    config = drivers.DecoderConfig(rate_hz=rate)
    length = drivers.get_format(fmt).length
    raw, k = _unplugged(fmt, rate, 300, 1000, 300)
    dec = drivers.StreamDecoder(fmt, config)
    batch, offsets, times = _chunked_feed(dec, raw, k, length, rate, per=10)
    c = dec.counters
    assert c.frames == 600 and c.sequence_gaps == 1 and c.frames_lost == 1000
    assert batch.lost_before[300] == 1000
    np.testing.assert_allclose(batch.time_s, k / rate, atol=1e-9)
    # the same capture decoded at once with its side file gives the same frames and counts
    path = tmp_path / "cap.bin"
    path.write_bytes(raw)
    side = "".join(f"{t:.6f},{o},{length * 10}\n" for t, o in zip(times, offsets, strict=True))
    side_path(path).write_text(f"# test\n{SIDE_HEADER}\n{side}", encoding="utf-8")
    captured, cc = decode_capture(path, fmt, config)
    assert_batches_equal(batch, captured, host_time=True)
    assert cc == c
    # without host times only Format B can tell
    bulk, bc = drivers.decode_bulk(raw, fmt, config)
    assert bc.frames_lost == (1000 if fmt == "kvh-b" else 1000 % 128)


@pytest.mark.parametrize("away", [1, 50, 127, 128, 129, 255, 256, 1000, 5000])
def test_loss_counts_from_format_b_timestamps(away: int) -> None:
    raw, k = _unplugged("kvh-b", 1000.0, 100, away, 100)
    for rate in (1000.0, 250.0):  # the period comes from the timestamps, not the setting
        batch, c = drivers.decode_bulk(raw, "kvh-b", drivers.DecoderConfig(rate_hz=rate))
        assert c.frames_lost == away and batch.lost_before[100] == away
        np.testing.assert_allclose(batch.time_s, k / 1000.0, atol=1e-9)


@pytest.mark.parametrize("away", [1, 60, 127, 128, 200, 1000, 3000])
def test_loss_counts_from_host_times_at_1khz(away: int) -> None:
    raw, k = _unplugged("kvh-a", 1000.0, 500, away, 500)
    dec = drivers.StreamDecoder("kvh-a")
    batch, _, _ = _chunked_feed(dec, raw, k, 36, 1000.0, per=50)
    assert dec.counters.frames_lost == away
    np.testing.assert_allclose(batch.time_s, k / 1000.0, atol=1e-9)


def test_host_clock_jitter_adds_no_false_losses() -> None:
    # Reads stamped up to 40 ms late (a busy machine) and irregular read sizes: the host clock
    # must never invent a wrap, and a real short gap is still counted from the sequence.
    rng = np.random.default_rng(4)
    raw, k = _unplugged("kvh-a", 1000.0, 3000, 40, 3000)
    dec = drivers.StreamDecoder("kvh-a")
    i = 0
    while i < len(k):
        per = int(rng.integers(1, 120))
        j = min(i + per, len(k)) - 1
        dec.feed(raw[i * 36 : (j + 1) * 36], host_time=k[j] / 1000.0 + rng.uniform(0, 0.04))
        i = j + 1
    dec.flush()
    assert dec.counters.frames_lost == 40 and dec.counters.sequence_gaps == 1


@SETTINGS
@given(
    fmt=st.sampled_from(FORMATS),
    away=st.integers(0, 700),
    data=st.data(),
)
def test_bulk_with_side_times_equals_streaming_for_any_chunking(fmt: str, away: int, data) -> None:
    rate = 1000.0
    length = drivers.get_format(fmt).length
    raw, k = _unplugged(fmt, rate, 60, away, 60)
    # some damage, so held-back bytes and host times interact
    buf = bytearray(raw)
    for pos in data.draw(st.lists(st.integers(0, len(buf) - 1), max_size=3)):
        buf[pos] ^= 0x5A
    raw = bytes(buf)
    cuts = sorted(set(data.draw(st.lists(st.integers(1, len(raw) - 1), max_size=25))))
    bounds = [0, *cuts, len(raw)]
    dec = drivers.StreamDecoder(fmt, drivers.DecoderConfig(rate_hz=rate))
    parts, times = [], []
    for a, b in zip(bounds, bounds[1:], strict=False):
        frame_end = min(b // length, len(k) - 1)
        t = 10.0 + k[frame_end] / rate + 0.002
        times.append(t)
        parts.append(dec.feed(raw[a:b], host_time=t))
    parts.append(dec.flush())
    stream = drivers.FrameBatch.concat(parts)
    bulk, bc, _ = decode_bulk_with_offsets(
        raw,
        fmt,
        drivers.DecoderConfig(rate_hz=rate),
        chunks=(np.array(times), np.array(bounds[:-1])),
    )
    assert_batches_equal(bulk, stream, host_time=True)
    assert bc == dec.counters
