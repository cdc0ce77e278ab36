"""``recal positions``: find the static windows of a recording and write the positions CSV.

Inputs: a KVH capture (``--format kvh-a|kvh-b|kvh-c``, decoded by ``drivers.decode_bulk``; gyro in
deg/h, accel in g) or an Xsens text pair (``--format xsens-text``: the acc file and the gyro file,
raw counts). The detector is ``recal.static``; the CSV columns are conventions section 4 plus
``frames_lost`` and ``frames_invalid``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from recal.errors import RecalInputError
from recal.positions import Positions
from recal.static import DetectorConfig, StaticDetector, Window, windows_to_columns
from service.cli.common import atomic_write, progress_bar, read_bytes

FORMATS = ("kvh-a", "kvh-b", "kvh-c", "xsens-text")
_CHUNK = 1 << 16  # frames per detector feed: the unit of the progress bar
_PROGRESS_MIN_FRAMES = 4 * _CHUNK  # below this a bar would only flicker


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "positions",
        help="find the static windows of a recording and write the positions CSV",
        description="Find the static windows of an IMU recording (moving variance of accel and "
        "gyro below a threshold, edges trimmed) and write one row per window: start/end, "
        "samples, mean and standard deviation per axis, temperature and its slope. Thresholds "
        "are given, or learned from a still period at the start (--init-still).",
    )
    p.add_argument(
        "inputs",
        nargs="+",
        metavar="INPUT",
        help="KVH: one capture file, or the consecutive parts of one capture in order (joined "
        "as one byte stream); xsens-text: the acc file and the gyro file (told apart by "
        "'acc'/'gyro' in their names, else in that order)",
    )
    p.add_argument("--format", required=True, choices=FORMATS, help="input format")
    p.add_argument(
        "--rate",
        type=float,
        metavar="HZ",
        help="sample rate; KVH: the device data rate (default 1000, turns delta angles into "
        "rates); xsens-text: overrides the rate derived from the time column",
    )
    p.add_argument("-o", "--output", required=True, metavar="POSITIONS.csv")
    k = p.add_argument_group("KVH device settings (must match the unit's configuration)")
    k.add_argument(
        "--gyro-output",
        choices=("delta", "rate"),
        default="delta",
        help="ROTFMT: delta angle per sample (default) or rate",
    )
    k.add_argument(
        "--gyro-units", choices=("rad", "deg"), default="rad", help="ROTUNITS (default rad)"
    )
    k.add_argument(
        "--temp-units",
        choices=("degC", "centi"),
        default="degC",
        help="whole degC (default) or hundredths (C_100)",
    )
    d = p.add_argument_group("detector")
    defaults = DetectorConfig(accel_threshold=0.0, gyro_threshold=0.0)
    d.add_argument(
        "--init-still",
        type=float,
        metavar="S",
        help="the recording starts with S seconds of stillness: learn the thresholds there",
    )
    d.add_argument(
        "--threshold-k",
        type=float,
        default=defaults.threshold_k,
        metavar="K",
        help="learned threshold = K x the still period's median moving variance "
        "(default %(default)s)",
    )
    d.add_argument(
        "--accel-threshold",
        type=float,
        metavar="VAR",
        help="explicit limit on the accel moving-variance trace, (input units)^2",
    )
    d.add_argument(
        "--gyro-threshold",
        type=float,
        metavar="VAR",
        help="explicit limit on the gyro moving-variance trace, (input units)^2",
    )
    d.add_argument(
        "--window",
        type=float,
        default=defaults.window_s,
        metavar="S",
        help="moving-variance window (default %(default)s s)",
    )
    d.add_argument(
        "--min-duration",
        type=float,
        default=defaults.min_duration_s,
        metavar="S",
        help="shortest window kept, after trimming (default %(default)s s)",
    )
    d.add_argument(
        "--edge-trim",
        type=float,
        default=defaults.edge_trim_s,
        metavar="S",
        help="dropped at both ends of each window (default %(default)s s)",
    )
    d.add_argument(
        "--max-gap",
        type=int,
        default=defaults.max_gap_frames,
        metavar="FRAMES",
        help="longest hole (lost or invalid frames) a window may contain; a longer one splits "
        "it (default %(default)s)",
    )
    d.add_argument(
        "--gyro-rate-max",
        type=float,
        metavar="RATE",
        help="reject windows whose mean gyro differs from the still-period mean (or zero) by "
        "more than RATE, gyro units: catches steady turns about the vertical",
    )
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    if not _has_thresholds(args):
        raise RecalInputError(
            "give --init-still S (the recording starts still for S seconds; the thresholds are "
            "learned there) or both --accel-threshold and --gyro-threshold"
        )
    config = DetectorConfig(
        window_s=args.window,
        min_duration_s=args.min_duration,
        edge_trim_s=args.edge_trim,
        accel_threshold=args.accel_threshold,
        gyro_threshold=args.gyro_threshold,
        init_still_s=args.init_still,
        threshold_k=args.threshold_k,
        sample_rate_hz=args.rate if args.format == "xsens-text" else None,
        max_gap_frames=args.max_gap,
        gyro_rate_max=args.gyro_rate_max,
    )
    out = Path(args.output)
    if not (out.parent if str(out.parent) else Path(".")).is_dir():
        raise RecalInputError(f"output folder {out.parent} does not exist")
    if args.format == "xsens-text":
        frames, notes = _read_xsens(args.inputs)
    else:
        frames, notes = _read_kvh(args.inputs, args.format, args.rate, args)
    detector = StaticDetector(config)
    windows = _detect(detector, frames)
    report = detector.report
    if not windows:
        rejected = ", ".join(f"{k} {v}" for k, v in report.rejected.items() if v) or "none"
        raise RecalInputError(
            f"no static window found in {report.frames} frames (rejected: {rejected}): check "
            "the thresholds (--init-still, --threshold-k) and --min-duration"
        )
    # Printed only on success: a failed run prints its one-line error and nothing else.
    for line in notes + report.summary_lines():
        print(f"recal positions: {line}", file=sys.stderr)
    table = Positions.from_columns(windows_to_columns(windows), source=str(out))
    atomic_write(out, table.to_csv_text())
    durations = np.array([w.duration_s for w in windows])
    print(
        f"recal positions: wrote {len(windows)} windows ({durations.min():.1f}-"
        f"{durations.max():.1f} s long) to {out}",
        file=sys.stderr,
    )
    return 0


def _has_thresholds(args: argparse.Namespace) -> bool:
    return args.init_still is not None or (
        args.accel_threshold is not None and args.gyro_threshold is not None
    )


def _detect(detector: StaticDetector, frames: dict[str, np.ndarray | None]) -> list[Window]:
    """Feed the detector in chunks, with a progress bar for long recordings on a terminal."""
    n = frames["time_s"].shape[0]
    bar = progress_bar(n, "positions") if n >= _PROGRESS_MIN_FRAMES else None
    if bar is not None:
        bar.unit = "frame"  # the shared helper counts runs
        bar.refresh()
    windows: list[Window] = []
    try:
        for lo in range(0, n, _CHUNK):
            part = {k: (None if v is None else v[lo : lo + _CHUNK]) for k, v in frames.items()}
            windows += detector.feed(**part)
            if bar is not None:
                bar.update(part["time_s"].shape[0])
        windows += detector.flush()
    finally:
        if bar is not None:
            bar.close()
    return windows


def _read_xsens(inputs: list[str]) -> tuple[dict[str, np.ndarray | None], list[str]]:
    from drivers.xsens_text import load_xsens_pair

    if len(inputs) != 2:
        raise RecalInputError(
            f"xsens-text takes two inputs, the acc file and the gyro file; got {len(inputs)}"
        )
    acc_path, gyro_path = _order_pair(inputs)
    data = load_xsens_pair(acc_path, gyro_path)
    t = data["time_s"]
    # The text has no sequence number: a time step of about k sample periods means k - 1 frames
    # were lost there (timestamp jitter of a fraction of a period rounds away).
    lost = np.zeros(t.shape[0], dtype=np.int64)
    if t.shape[0] > 2:
        steps = np.diff(t)
        lost[1:] = np.maximum(np.rint(steps / np.median(steps)) - 1, 0)
    frames = {
        "time_s": t,
        "gyro": data["gyro_counts"],
        "accel": data["accel_counts"],
        "temperature_c": None,
        "valid": None,
        "lost_before": lost,
    }
    return frames, [f"xsens-text: accel {acc_path}, gyro {gyro_path} (raw counts)"]


def _order_pair(inputs: list[str]) -> tuple[str, str]:
    """(acc, gyro): by 'acc' / 'gyro' in the file names when that is unambiguous, else as given."""
    names = [Path(p).name.lower() for p in inputs]
    acc = [i for i, name in enumerate(names) if "acc" in name]
    gyro = [i for i, name in enumerate(names) if "gyr" in name]
    if acc in ([1], []) and gyro in ([0], []) and (acc or gyro):
        return inputs[1], inputs[0]
    return inputs[0], inputs[1]


def _read_kvh(
    inputs: list[str], fmt: str, rate: float | None, args: argparse.Namespace
) -> tuple[dict[str, np.ndarray | None], list[str]]:
    # Imported here: the Xsens path and --help need none of the KVH machinery.
    from drivers import DecoderConfig, decode_bulk, require_frames

    parts = [read_bytes(name, "input file") for name in inputs]
    data = b"".join(parts)  # consecutive parts of one stream: frames may straddle the joins
    path = Path(inputs[0]) if len(inputs) == 1 else Path(f"{inputs[0]} (+{len(inputs) - 1} parts)")
    config = DecoderConfig(
        gyro_output=args.gyro_output,
        gyro_units=args.gyro_units,
        temperature_units=args.temp_units,
        **({} if rate is None else {"rate_hz": rate}),
    )
    batch, counters = decode_bulk(data, fmt, config)
    require_frames(counters, fmt, source=str(path))
    frames = {
        "time_s": batch.time_s,
        "gyro": batch.gyro_dph,
        "accel": batch.accel_g,
        "temperature_c": batch.temperature_c,
        "valid": batch.valid,
        "lost_before": batch.lost_before,
    }
    note = (
        f"{fmt}: {counters.frames} frames decoded, {counters.crc_failures} CRC failures, "
        f"{counters.sequence_gaps} sequence gaps ({counters.frames_lost} frames lost), "
        f"{counters.invalid_status} invalid status; gyro deg/h, accel g"
    )
    return frames, [note]
