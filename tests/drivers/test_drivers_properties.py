"""Hypothesis properties: chunking, bit flips, garbage, truncation. Bulk == streaming always."""

from __future__ import annotations

import numpy as np
from drivers_testkit import assert_batches_equal, make_frames, stream_decode
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import drivers

SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
FORMATS = st.sampled_from(["kvh-a", "kvh-b", "kvh-c"])


def _check_both_paths(data: bytes, cuts: list[int], fmt: str):
    bulk, bc = drivers.decode_bulk(data, fmt)
    stream, sc = stream_decode(data, cuts, fmt)
    assert_batches_equal(bulk, stream)
    assert bc == sc
    assert bc.balanced() and bc.bytes_pending == 0
    assert bc.bytes_in == len(data)
    assert bc.headers_seen[fmt] >= bc.frames + bc.crc_failures + bc.truncated
    return bulk, bc


def _recovered_indices(batch, seq0: int = 0) -> list[int]:
    # frames are generated with seq = index % 128 and at most 60 frames, so seq identifies them
    return [int(s) for s in batch.seq]


@SETTINGS
@given(fmt=FORMATS, n=st.integers(0, 40), seed=st.integers(0, 2**16), data=st.data())
def test_random_chunking(fmt: str, n: int, seed: int, data) -> None:
    raw, _ = make_frames(n, fmt, seed=seed)
    cuts = data.draw(st.lists(st.integers(0, max(len(raw), 1)), max_size=30))
    batch, c = _check_both_paths(raw, cuts, fmt)
    assert len(batch) == n and c.bytes_skipped == 0 and c.resyncs == 0


@SETTINGS
@given(fmt=FORMATS, n=st.integers(1, 40), seed=st.integers(0, 2**16), data=st.data())
def test_random_bit_flips(fmt: str, n: int, seed: int, data) -> None:
    raw, _ = make_frames(n, fmt, seed=seed)
    length = drivers.get_format(fmt).length
    nbits = len(raw) * 8
    flips = data.draw(st.lists(st.integers(0, nbits - 1), min_size=1, max_size=12, unique=True))
    buf = bytearray(raw)
    for bit in flips:
        buf[bit // 8] ^= 1 << (bit % 8)
    damaged = {bit // 8 // length for bit in flips}
    cuts = data.draw(st.lists(st.integers(0, len(buf)), max_size=10))
    batch, c = _check_both_paths(bytes(buf), cuts, fmt)
    intact = [i for i in range(n) if i not in damaged]
    assert _recovered_indices(batch) == intact  # every intact frame, and nothing else
    if intact:
        span = intact[-1] - intact[0] + 1
        assert c.frames_lost == span - len(intact)
    assert c.bytes_skipped == len(damaged) * length


@SETTINGS
@given(fmt=FORMATS, n=st.integers(0, 30), seed=st.integers(0, 2**16), data=st.data())
def test_inserted_garbage(fmt: str, n: int, seed: int, data) -> None:
    raw, _ = make_frames(n, fmt, seed=seed)
    length = drivers.get_format(fmt).length
    header = drivers.get_format(fmt).header
    junk_bytes = st.binary(min_size=1, max_size=60) | st.builds(
        lambda pre, post: pre + header + post, st.binary(max_size=5), st.binary(max_size=50)
    )
    inserts = data.draw(st.dictionaries(st.integers(0, n), junk_bytes, max_size=6))
    out = bytearray()
    for i in range(n + 1):
        out += inserts.get(i, b"")
        out += raw[i * length : (i + 1) * length]
    cuts = data.draw(st.lists(st.integers(0, len(out)), max_size=10))
    batch, c = _check_both_paths(bytes(out), cuts, fmt)
    assert _recovered_indices(batch) == list(range(n))
    assert c.bytes_skipped == sum(len(v) for v in inserts.values())
    assert c.resyncs == len(inserts)
    assert c.frames_lost == 0


@SETTINGS
@given(fmt=FORMATS, n=st.integers(1, 30), seed=st.integers(0, 2**16), data=st.data())
def test_truncated_frames(fmt: str, n: int, seed: int, data) -> None:
    raw, _ = make_frames(n, fmt, seed=seed)
    length = drivers.get_format(fmt).length
    cut_frames = data.draw(st.dictionaries(st.integers(0, n - 1), st.integers(1, length - 1)))
    out = bytearray()
    for i in range(n):
        frame = raw[i * length : (i + 1) * length]
        out += frame[: cut_frames[i]] if i in cut_frames else frame
    cuts = data.draw(st.lists(st.integers(0, len(out)), max_size=10))
    batch, c = _check_both_paths(bytes(out), cuts, fmt)
    assert _recovered_indices(batch) == [i for i in range(n) if i not in cut_frames]
    assert c.bytes_skipped == sum(cut_frames.values())
    # a cut frame whose header survives but whose full length runs past the end of the
    # stream is counted as truncated (others are CRC failures)
    starts, pos = [], 0
    for i in range(n):
        kept = cut_frames.get(i, length)
        if i in cut_frames and kept >= 4:
            starts.append(pos)
        pos += kept
    assert c.truncated == sum(1 for p in starts if p + length > len(out))
    # a cut frame that passes its CRC with the next frame's first byte is misaligned
    assert c.crc_failures + c.misaligned == len(starts) - c.truncated


@SETTINGS
@given(junk=st.binary(max_size=400), fmt=FORMATS, data=st.data())
def test_arbitrary_bytes_never_raise(junk: bytes, fmt: str, data) -> None:
    cuts = data.draw(st.lists(st.integers(0, len(junk)), max_size=10))
    _check_both_paths(junk, cuts, fmt)


def _overlapping_pair(corrupt_first: bool) -> bytes:
    """Frame X at 0 with a header at byte 8 of its payload, and a valid frame Y at 8 that
    overlaps X's last 28 bytes (Y's own last 8 bytes follow X)."""
    x = bytearray(drivers.encode_frame("kvh-a", seq=1))
    x[8:12] = drivers.get_format("kvh-a").header
    x[32:] = drivers.crc32_mpeg2(bytes(x[:32])).to_bytes(4, "big")
    y = bytearray(x[8:36]) + bytearray(b"\x00\x01\x02\x03")
    y += drivers.crc32_mpeg2(bytes(y)).to_bytes(4, "big")
    if corrupt_first:
        x[5] ^= 0x10  # outside the overlap: X fails its CRC, Y does not
    tail, _ = make_frames(3, seed=11, seq0=2)
    return bytes(x) + bytes(y[28:]) + tail


def test_overlapping_valid_candidates_resolved_like_the_stream() -> None:
    for corrupt_first, first_seq in ((False, 1), (True, None)):
        data = _overlapping_pair(corrupt_first)
        bulk, bc = drivers.decode_bulk(data)
        assert len(bulk) == 4 and bc.balanced()
        if first_seq is not None:
            assert bulk.seq[0] == first_seq and bc.bytes_skipped == 8 and bc.crc_failures == 0
        else:
            assert bc.crc_failures == 1 and bc.bytes_skipped == 8
        for cuts in ([], [10], [9, 21, 40], list(range(0, len(data), 7))):
            stream, sc = stream_decode(data, cuts)
            assert_batches_equal(bulk, stream)
            assert sc == bc


def test_greedy_overlap_resolution_directly() -> None:
    from drivers.bulk import _greedy

    pos = np.array([0, 10, 36, 40, 72, 100, 108])
    assert pos[_greedy(pos, 36)].tolist() == [0, 36, 72, 108]
