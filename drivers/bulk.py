"""Vectorised frame scanning: the one decoding routine behind both the bulk and streaming paths.

The rule (what a byte-at-a-time decoder would do): at position p, if the format's header starts
there, the whole frame is present and its check passes, accept the frame and continue at p + L;
otherwise skip one byte. One exception keeps resynchronisation from losing an intact frame: a
candidate that passes its check but is not followed by a header at p + L, while a frame that
also passes its check starts inside it (p < q < p + L), is "misaligned" and skipped in favour
of that frame. (A frame cut one byte short passes its CRC with the next frame's first byte 1
time in 256 when that byte is 0xFE; accepting it would swallow the next frame's header.)

``scan`` applies the rule to a whole buffer with numpy: it finds every header candidate, checks
all complete candidates at once, settles the rare misaligned ones, and resolves overlaps
greedily from the left. Without ``final`` it stops before the first position it cannot decide
yet (a header whose frame is incomplete, a possible header cut by the buffer end, or a frame
whose misalignment depends on bytes not yet received), so chunked feeding gives the same frames
and counters as one pass over the whole stream.

Lost frames: the 7-bit sequence number says how many frames are missing modulo 128. A longer
loss (an unplug) is counted from the format's timestamp when it has one (in units of the frame
period seen just before the gap), else from the host receive times of the chunks, when given:
the arrival of a frame is the host time of the chunk holding its last byte, less the wire time
of the bytes after it in that chunk at the configured rate. The count keeps the sequence
number's residue modulo 128 and takes the multiple of 128 nearest to what the clock says, so
time_s stays right after the gap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from .config import DEFAULT_CONFIG, DecoderConfig
from .formats import FrameFormat, all_formats, get_format
from .frames import VALID_STATUS, DecoderCounters, FrameBatch

_MAG_AXES = {"mag_x": 0, "mag_y": 1, "mag_z": 2}


@dataclass
class Continuity:
    """What carries over between scans of one stream: sequence/time unwrapping and skip state."""

    started: bool = False
    prev_seq: int = 0
    index: int = 0  # unwrapped sample index of the previous frame (first frame = 0)
    prev_ticks: int = 0
    ticks: int = 0  # accumulated timestamp ticks of the previous frame since the first
    period_ticks: float = math.nan  # timestamp step of the last gap-free pair of frames
    prev_arrival: float = math.nan  # estimated host arrival time of the previous frame
    in_skip: bool = False  # the last decided byte was skipped (a resync run is open)


@dataclass(frozen=True)
class Chunks:
    """Host receive times of the reads that make up a buffer: chunk i is buf[ends[i-1]:ends[i]]
    (ends ascending, the last >= the buffer length) and was received at times[i] (NaN: unknown).
    """

    ends: np.ndarray
    times: np.ndarray

    @staticmethod
    def single(n: int, host_time: float) -> Chunks:
        return Chunks(np.array([n], dtype=np.int64), np.array([host_time], dtype=np.float64))

    @staticmethod
    def from_offsets(n: int, offsets: np.ndarray, times: np.ndarray) -> Chunks:
        """From a side file's chunk start offsets; bytes before the first chunk get NaN."""
        offsets = np.asarray(offsets, dtype=np.int64)
        times = np.asarray(times, dtype=np.float64)
        if offsets.shape[0] == 0:
            return Chunks.single(n, math.nan)
        ends = np.append(offsets[1:], max(n, int(offsets[-1])))
        if offsets[0] > 0:
            ends = np.insert(ends, 0, offsets[0])
            times = np.insert(times, 0, math.nan)
        return Chunks(ends, times)


def _wrapped_loss(lost_seq: np.ndarray, clock_lost: np.ndarray, modulus: int) -> np.ndarray:
    """Frames lost: the sequence residue plus the multiple of ``modulus`` nearest to what a clock
    says (never fewer than the sequence says; NaN clock: the sequence alone)."""
    wraps = np.rint((clock_lost - lost_seq) / modulus)
    wraps = np.where(np.isfinite(wraps) & (wraps > 0), wraps, 0).astype(np.int64)
    return lost_seq + modulus * wraps


def _ffill(values: np.ndarray, mask: np.ndarray, seed: float) -> np.ndarray:
    """For each i: values[j] of the last j < i with mask[j] (seed when none)."""
    k = values.shape[0]
    idx = np.where(mask, np.arange(k), -1)
    last = np.maximum.accumulate(idx)
    out = np.empty(k, dtype=np.float64)
    out[0] = seed
    prev = last[:-1]
    out[1:] = np.where(prev >= 0, values[np.maximum(prev, 0)], seed)
    return out


def _find_all(buf: np.ndarray, headers: list[bytes]) -> list[np.ndarray]:
    """Start positions of each header in buf (whole header inside buf), sharing common prefixes."""
    n = buf.shape[0]
    cache: dict[bytes, np.ndarray] = {}
    out = []
    for h in headers:
        k = 1
        while k < len(h) and h[: k + 1] in cache:
            k += 1
        if h[:k] in cache:
            idx = cache[h[:k]]
        else:
            idx = np.flatnonzero(buf == h[0])
            cache[h[:1]] = idx
        for j in range(k, len(h)):
            idx = idx[idx + j < n]
            idx = idx[buf[idx + j] == h[j]]
            cache[h[: j + 1]] = idx
        out.append(idx[idx + len(h) <= n])
    return out


def _greedy(pos: np.ndarray, length: int) -> np.ndarray:
    """Keep-mask for accepted positions: leftmost first, skipping any inside an accepted frame."""
    keep = np.zeros(pos.shape[0], dtype=bool)
    nxt = -1
    for i, p in enumerate(pos.tolist()):
        if p >= nxt:
            keep[i] = True
            nxt = p + length
    return keep


def _not_covered(pos: np.ndarray, starts: np.ndarray, length: int) -> np.ndarray:
    """Mask of positions the decoder examines: not strictly inside an accepted frame."""
    if starts.shape[0] == 0 or pos.shape[0] == 0:
        return np.ones(pos.shape[0], dtype=bool)
    k = np.searchsorted(starts, pos, side="right") - 1
    s = starts[np.maximum(k, 0)]
    inside = (k >= 0) & (pos > s) & (pos < s + length)
    return ~inside


class Engine:
    """Scanner and unpacker for one format and configuration."""

    def __init__(self, fmt: str | FrameFormat = "kvh-a", config: DecoderConfig = DEFAULT_CONFIG):
        self.fmt = get_format(fmt)
        self.config = config
        self.known = all_formats()
        if self.fmt not in self.known:
            self.known.append(self.fmt)
        self.headers = [f.header for f in self.known]
        self.target_index = self.known.index(self.fmt)
        self.max_header = max(len(h) for h in self.headers)
        self.gyro_factor = config.gyro_to_dph
        self.temp_scale = config.temperature_scale
        self.extra_spec = {
            name: (np.dtype(f.dtype).newbyteorder("=").type, (f.count,) if f.count > 1 else ())
            for name, f in self.fmt.fields.items()
            if name in self.fmt.extra_fields
        }

    def new_counters(self) -> DecoderCounters:
        return DecoderCounters(
            frame_length=self.fmt.length, headers_seen={f.name: 0 for f in self.known}
        )

    def empty(self) -> FrameBatch:
        return FrameBatch.empty(self.fmt.name, self.extra_spec)

    def scan(
        self,
        buf: np.ndarray,
        final: bool,
        state: Continuity,
        counters: DecoderCounters,
        chunks: Chunks | float,
    ) -> tuple[FrameBatch, int, np.ndarray]:
        """Decode what can be decided in ``buf``; returns (frames, bytes decided, frame starts).

        ``chunks``: the host receive times of buf's reads (a float: one time for all of it).
        Updates ``state`` and ``counters`` (all but bytes_in and bytes_pending, which belong to
        the caller).
        """
        fmt = self.fmt
        length = fmt.length
        n = int(buf.shape[0])
        if not isinstance(chunks, Chunks):
            chunks = Chunks.single(n, chunks)
        found = _find_all(buf, self.headers)
        cand = found[self.target_index]
        complete = cand[cand + length <= n]
        if complete.shape[0]:
            rows = sliding_window_view(buf, length)[complete]
            ok = fmt.checker.verify(rows)
            starts = complete[ok]
            rows = rows[ok]
        else:
            ok = np.zeros(0, dtype=bool)
            starts = complete
            rows = np.empty((0, length), dtype=np.uint8)
        rejected = np.zeros(0, dtype=np.int64)
        undecided = np.zeros(0, dtype=np.int64)
        # Misalignment needs a possible header inside a frame: two candidates closer than a
        # frame length, or (not final) a header prefix at the end of buf inside the last frame.
        if starts.shape[0] and (
            bool((cand[1:] - cand[:-1] < length).any())
            or (not final and int(starts[-1]) + length > n - len(fmt.header) + 1)
        ):
            reject, wait = self._misaligned(buf, final, starts, cand)
            if reject.any():
                rejected = starts[reject]
                starts, rows, wait = starts[~reject], rows[~reject], wait[~reject]
            undecided = starts[wait]
        if starts.shape[0] > 1 and bool((np.diff(starts) < length).any()):
            keep = _greedy(starts, length)  # rare: a valid frame overlapping another
            starts, rows = starts[keep], rows[keep]

        end = n
        if undecided.shape[0]:  # never when final
            held = np.isin(starts, undecided)
            if held.any():
                end = int(starts[held][0])
                starts, rows = starts[starts < end], rows[starts < end]
        nf = int(starts.shape[0])
        last_end = int(starts[-1]) + length if nf else 0

        if not final:
            pend = cand[(cand + length > n) & (cand >= last_end)]
            if pend.shape[0]:
                end = min(end, int(pend[0]))
            for q in range(max(last_end, n - self.max_header + 1), end):
                rem = bytes(buf[q:n])
                if any(len(rem) < len(h) and h.startswith(rem) for h in self.headers):
                    end = q
                    break

        # Headers at examined positions (frame starts and skipped bytes) before `end`.
        for f, pos in zip(self.known, found, strict=True):
            pos = pos[pos < end]
            if pos.shape[0]:
                counters.headers_seen[f.name] += int(_not_covered(pos, starts, length).sum())
        failed = complete[~ok]
        failed = failed[failed < end]
        if failed.shape[0]:
            counters.crc_failures += int(_not_covered(failed, starts, length).sum())
        rejected = rejected[rejected < end]
        if rejected.shape[0]:
            counters.misaligned += int(_not_covered(rejected, starts, length).sum())
        if final:
            counters.truncated += int(((cand + length > n) & (cand >= last_end)).sum())

        counters.frames += nf
        counters.bytes_skipped += end - nf * length
        # Resync runs: maximal runs of skipped bytes; one open from the last scan continues.
        if nf:
            gaps = np.empty(nf + 1, dtype=np.int64)
            gaps[0] = starts[0]
            gaps[1:-1] = starts[1:] - starts[:-1] - length
            gaps[-1] = end - last_end
            runs = int((gaps > 0).sum())
            if state.in_skip and gaps[0] > 0:
                runs -= 1
            state.in_skip = bool(gaps[-1] > 0)
        else:
            runs = 1 if (end > 0 and not state.in_skip) else 0
            state.in_skip = state.in_skip or end > 0
        counters.resyncs += runs

        if not nf:
            return self.empty(), end, starts
        last_byte = starts + (length - 1)
        k = np.minimum(np.searchsorted(chunks.ends, last_byte, side="right"), len(chunks.ends) - 1)
        host = chunks.times[k]
        # When the frame's last byte came: its chunk's time less the wire time of what followed.
        arrival = host - (chunks.ends[k] - (last_byte + 1)) / (self.config.rate_hz * length)
        return self._unpack(rows, state, counters, host, arrival), end, starts

    def _misaligned(
        self, buf: np.ndarray, final: bool, starts: np.ndarray, cand: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(reject, wait) masks over the frames at ``starts`` (all of which pass their check).

        Reject: no header of any known format at s + L, and a frame that passes its check
        starts at s < q < s + L. Wait (only when not final): that cannot be told from buf yet.
        Only frames with a possible header inside them are looked at one by one.
        """
        n = int(buf.shape[0])
        length = self.fmt.length
        header = self.fmt.header
        reject = np.zeros(starts.shape[0], dtype=bool)
        wait = np.zeros(starts.shape[0], dtype=bool)
        # possible headers inside each frame: whole ones (then two candidates are closer than
        # a frame length), and (not final) one cut by the end of buf
        if cand.shape[0] > 1 and bool((np.diff(cand) < length).any()):
            k = np.searchsorted(cand, starts, side="right")
            nxt = cand[np.minimum(k, cand.shape[0] - 1)]
            inside = (k < cand.shape[0]) & (nxt < starts + length)
        else:
            inside = np.zeros(starts.shape[0], dtype=bool)
        tail = n
        if not final and int(starts[-1]) + length > n - len(header) + 1:
            for q in range(max(0, n - len(header) + 1), n):
                if header.startswith(bytes(buf[q:n])):
                    tail = q
                    break
            inside |= (starts < tail) & (tail < starts + length)
        if not inside.any():
            return reject, wait
        for i in np.flatnonzero(inside).tolist():
            s = int(starts[i])
            after = s + length
            aligned: bool | None = False
            for h in self.headers:
                got = bytes(buf[after : after + len(h)])
                if got == h:
                    aligned = True
                    break
                if len(got) < len(h) and h.startswith(got) and not final:
                    aligned = None
            if aligned:
                continue
            qs = cand[(cand > s) & (cand < after)]
            whole = qs[qs + length <= n]
            if whole.shape[0] and bool(
                self.fmt.checker.verify(sliding_window_view(buf, length)[whole]).any()
            ):
                if aligned is None:
                    wait[i] = True
                else:
                    reject[i] = True
            elif not final and (whole.shape[0] < qs.shape[0] or s < tail < after):
                wait[i] = True
        return reject, wait

    def _unpack(
        self,
        rows: np.ndarray,
        state: Continuity,
        counters: DecoderCounters,
        host: np.ndarray,
        arrival: np.ndarray,
    ) -> FrameBatch:
        fmt = self.fmt
        fields = fmt.fields
        k = rows.shape[0]
        arr = np.ascontiguousarray(rows).view(fmt.dtype).reshape(k)
        nan3 = np.full((k, 3), np.nan)

        dt = None
        if "timestamp" in fields:
            raw_t = arr["timestamp"].astype(np.int64)
            prev_t = np.empty(k, dtype=np.int64)
            prev_t[0] = state.prev_ticks
            prev_t[1:] = raw_t[:-1]
            dt = (raw_t - prev_t) % fmt.timestamp_modulus
            if not state.started:
                dt[0] = 0
            ticks = state.ticks + np.cumsum(dt)
            state.prev_ticks = int(raw_t[-1])
            state.ticks = int(ticks[-1])

        if "seq" in fields:
            seq = arr["seq"].astype(np.int64)
            prev = np.empty(k, dtype=np.int64)
            prev[0] = state.prev_seq
            prev[1:] = seq[:-1]
            lost = (seq - prev - 1) % fmt.seq_modulus
            if not state.started:
                lost[0] = 0
            lost = self._count_wraps(lost, dt, arrival, state)
            steps = lost + 1
            if not state.started:
                steps[0] = 0
            index = state.index + np.cumsum(steps)
            state.prev_seq = int(seq[-1])
            state.index = int(index[-1])
            counters.sequence_gaps += int(np.count_nonzero(lost))
            counters.frames_lost += int(lost.sum())
        else:
            seq = np.zeros(k, dtype=np.int64)
            lost = np.zeros(k, dtype=np.int64)
            index = None
        state.prev_arrival = float(arrival[-1])

        if dt is not None:
            time_s = ticks / (1.0 / fmt.timestamp_scale_s)
        elif index is not None:
            time_s = index / self.config.rate_hz
        else:
            time_s = np.full(k, np.nan)
        state.started = True

        if "status" in fields:
            status = arr["status"].astype(np.uint8)
            valid = (status & VALID_STATUS) == VALID_STATUS
            counters.invalid_status += int(k - np.count_nonzero(valid))
        else:
            status = np.zeros(k, dtype=np.uint8)
            valid = np.zeros(k, dtype=bool)

        gyro = arr["gyro"].astype(np.float64) * self.gyro_factor if "gyro" in fields else nan3
        accel = arr["accel"].astype(np.float64) * fmt.accel_scale if "accel" in fields else nan3
        if "temperature" in fields:
            temperature = arr["temperature"].astype(np.float64) * self.temp_scale
        else:
            temperature = np.full(k, np.nan)
        mag = np.full((k, 3), np.nan)
        if fmt.mux is not None:
            slot = arr["slot"].astype(np.float64)
            which = seq % fmt.mux.period
            for i, meaning in enumerate(fmt.mux.meanings):
                sel = which == i
                if meaning == "temperature":
                    temperature[sel] = slot[sel] * self.temp_scale
                elif meaning in _MAG_AXES:
                    mag[sel, _MAG_AXES[meaning]] = slot[sel] * fmt.mag_scale

        extra = {name: arr[name].astype(spec[0]) for name, spec in self.extra_spec.items()}
        return FrameBatch(
            format=fmt.name,
            seq=seq,
            time_s=np.asarray(time_s, dtype=np.float64),
            host_time_s=np.asarray(host, dtype=np.float64),
            gyro_dph=gyro,
            accel_g=accel,
            temperature_c=temperature,
            mag_gauss=mag,
            status=status,
            valid=valid,
            lost_before=lost,
            extra=extra,
        )

    def _count_wraps(
        self, lost: np.ndarray, dt: np.ndarray | None, arrival: np.ndarray, state: Continuity
    ) -> np.ndarray:
        """Sequence-gap losses corrected for whole wraps of the sequence number, from the
        timestamp (in frame periods seen before the gap) or else from the arrival times."""
        modulus = self.fmt.seq_modulus
        first_ok = state.started
        if dt is not None:
            # the step between gap-free frames is the device's frame period in ticks
            gap_free = lost == 0
            if not first_ok:
                gap_free[0] = False
            seed = state.period_ticks
            fallback = 1.0 / (self.config.rate_hz * self.fmt.timestamp_scale_s)
            free = np.flatnonzero(gap_free)
            if free.shape[0]:
                state.period_ticks = float(dt[free[-1]])
            # no frame period is shorter than the shortest candidate: if even that shows no
            # extra wrap anywhere, there is none (the usual case, without the forward fill)
            shortest = min(float(dt[free].min()) if free.shape[0] else math.inf, fallback)
            if math.isfinite(seed):
                shortest = min(shortest, seed)
            if shortest > 0 and not bool((dt / shortest - lost >= modulus / 2).any()):
                return lost
            period = _ffill(dt.astype(np.float64), gap_free, seed)
            period = np.where(np.isfinite(period), period, fallback)
            clock_lost = np.rint(dt / period) - 1
        else:
            prev = np.empty(arrival.shape[0], dtype=np.float64)
            prev[0] = state.prev_arrival
            prev[1:] = arrival[:-1]
            clock_lost = np.rint((arrival - prev) * self.config.rate_hz) - 1
        if not first_ok:
            clock_lost[0] = np.nan
        if not bool((clock_lost - lost >= modulus / 2).any()):  # NaN compares False
            return lost
        return _wrapped_loss(lost, clock_lost, modulus)


def decode_bulk_with_offsets(
    data: bytes | bytearray | memoryview | np.ndarray,
    fmt: str | FrameFormat = "kvh-a",
    config: DecoderConfig = DEFAULT_CONFIG,
    chunks: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[FrameBatch, DecoderCounters, np.ndarray]:
    """decode_bulk, plus the byte offset of every frame's first byte.

    chunks: (host_monotonic_s, byte_offset) of the reads that made the capture (its side
    file): each frame gets the host time of the read that held its last byte, and losses of
    128 frames or more are counted from those times (as the streaming decoder fed the same
    reads would).
    """
    engine = Engine(fmt, config)
    buf = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data
    buf = buf.reshape(-1).view(np.uint8)
    n = int(buf.shape[0])
    counters = engine.new_counters()
    counters.bytes_in = n
    marks = Chunks.single(n, math.nan) if chunks is None else Chunks.from_offsets(n, *chunks[::-1])
    batch, _, starts = engine.scan(buf, True, Continuity(), counters, marks)
    return batch, counters, starts


def decode_bulk(
    data: bytes | bytearray | memoryview | np.ndarray,
    fmt: str | FrameFormat = "kvh-a",
    config: DecoderConfig = DEFAULT_CONFIG,
) -> tuple[FrameBatch, DecoderCounters]:
    """Decode a whole capture at once (same frames and counters as streaming then flush()).

    host_time_s is NaN; use drivers.capture.decode_capture to attach a side file's host times.
    """
    batch, counters, _ = decode_bulk_with_offsets(data, fmt, config)
    return batch, counters
