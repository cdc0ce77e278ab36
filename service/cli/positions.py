"""``recal positions``: find the static windows of a recording and write the positions CSV.

Inputs (:mod:`service.cli.recording`, all streamed in chunks: memory does not grow with the
recording's length): a KVH capture (``--format kvh-a|kvh-b|kvh-c``, decoded by
``drivers.StreamDecoder``; gyro in deg/h, accel in g), an Xsens text pair (``--format
xsens-text``: the acc file and the gyro file, raw counts) or a CSV log (``--format csv``,
docs/reference.md#csv, output units). The detector is ``recal.detect.static_detector``; the CSV columns are
docs/reference.md#positions plus ``frames_lost``, ``frames_invalid`` and ``gyro_still``
(0 for a pose kept for the accelerometer only: the gyro trembled, docs/static.md
"Per-triad stillness"). The
summary on stderr counts the poses (still stretches of the accelerometer) and says why each
rejected stretch was rejected.

Beside the CSV, a third pass keeps the gyro samples of each slew (the motion between two
consecutive windows) as downsampled increments in ``POSITIONS.slews.npz`` (recal.detect.slew_groups), which
``recal calibrate`` uses for the slew invariant. A slew with lost or invalid frames or a
saturated gyro sample is dropped and counted; its windows stay in the CSV.

Only argparse and the light drivers.registry are imported to build the parser; numpy, recal
and the parsers are imported by run().
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from service.cli.ship import add_ship_options, print_lines, read_ship_log

#: Format flags add_kvh_unit_options adds (with their choices), not add_input_options.
KVH_UNIT_FLAGS = ("--gyro-output", "--gyro-units", "--temp-units")
_PROGRESS_MIN_BYTES = 16 << 20  # below this a bar would only flicker
#: Frames per detector feed, counted from the first frame: recal.detect.static_detector.detect_static's slices,
#: so the stream gives the bulk path's windows to the last bit (any chunking agrees to 1e-15).
DETECTOR_BLOCK = 1 << 16


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "positions",
        help="find the static windows of a recording and write the positions CSV",
        description="Find the static windows of an IMU recording (moving variance of accel and "
        "gyro below a threshold, edges trimmed) and write one row per window: start/end, "
        "samples, mean and standard deviation per axis, temperature and its slope. By default "
        "the thresholds are a multiple of the recording's own noise floor, learned in a first "
        "pass over it; they can also be given, or learned from a still period at the start "
        "(--init-still). A pose where only the accelerometer is still (held by hand: the gyro "
        "trembles) is kept for the accelerometer only (column gyro_still 0). The summary counts "
        "the poses and says why each rejected stretch was rejected. The input is streamed: "
        "memory does not grow with its length.",
    )
    add_input_options(p)
    p.add_argument(
        "-o",
        "--output",
        required=True,
        metavar="POSITIONS.csv",
        help="the positions file to write (docs/reference.md#positions): one row per static window",
    )
    p.add_argument(
        "--report",
        metavar="OUT.html",
        help="write an HTML report: moving variance and signals against time, thresholds, the "
        "windows found and the stretches rejected (written even when no window is found)",
    )
    p.add_argument(
        "--no-slews",
        dest="slews",
        action="store_false",
        help="do not keep the slews (the gyro samples between windows) in POSITIONS.slews.npz",
    )
    add_kvh_unit_options(p)
    add_detector_options(p)
    add_ship_options(p)
    p.set_defaults(func=run)
    return p


def add_input_options(p: argparse.ArgumentParser) -> None:
    """INPUT..., --format, --rate and --columns: how a recording is read (positions and noise
    share them; :func:`service.cli.recording.open_recording` takes the parsed values)."""
    p.add_argument(
        "inputs",
        nargs="+",
        metavar="INPUT",
        help="KVH: one capture file, or the consecutive parts of one capture in order (joined "
        "as one byte stream); xsens-text: the acc file and the gyro file (told apart by "
        "'acc'/'gyro' in their names, else in that order); csv: one log with a header row "
        "(time_s, gyro_x..gyro_z, accel_x..accel_z, optional temperature_c; either triad may "
        "be missing)",
    )
    from drivers.registry import describe_formats, input_format_names, input_formats

    p.add_argument(
        "--format",
        required=True,
        choices=input_format_names(),
        help="input format: " + describe_formats(),
    )
    p.add_argument(
        "--rate",
        type=float,
        metavar="HZ",
        help="sample rate; KVH: the device data rate (default 1000, turns delta angles into "
        "rates); xsens-text, csv: overrides the rate derived from the time column (csv "
        "without a time_s column: time = row / HZ)",
    )
    p.add_argument(
        "--columns",
        metavar="NEW=OLD,...",
        help="csv: the file's own column names for the standard ones, e.g. "
        "accel_x=acc_x,accel_y=acc_y,accel_z=acc_z,time_s=t",
    )
    added = {"--rate", "--columns", *KVH_UNIT_FLAGS}
    for fmt in input_formats():  # the other options of the registered formats
        for opt in fmt.options:
            if opt.flag and opt.flag not in added:
                added.add(opt.flag)
                owners = [f.name for f in input_formats() if opt.flag in map(_flag, f.options)]
                p.add_argument(
                    opt.flag,
                    type=opt.parse,
                    metavar=opt.name.upper(),
                    help=f"{', '.join(owners)}: {opt.help}",
                )


def _flag(option) -> str | None:
    return option.flag


def add_detector_options(p: argparse.ArgumentParser) -> None:
    """The static detector's settings (positions and noise share them; see :func:`detector_config`)."""
    d = p.add_argument_group("detector")
    d.add_argument(
        "--init-still",
        type=float,
        metavar="S",
        help="the recording starts with S seconds of stillness: learn the thresholds there",
    )
    d.add_argument(
        "--threshold-k",
        type=float,
        metavar="K",
        help="learned threshold = K x the noise floor, or with --init-still K x the still "
        "period's median moving variance (default 5)",
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
        metavar="S",
        help="moving-variance window (default about 100 frames, between 0.1 and 1 s)",
    )
    d.add_argument(
        "--min-duration",
        type=float,
        metavar="S",
        help="shortest window kept, after trimming (default: the moving window, at least 0.5 s)",
    )
    d.add_argument(
        "--edge-trim",
        type=float,
        metavar="S",
        help="dropped at both ends of each window (default half the moving window)",
    )
    d.add_argument(
        "--max-gap",
        type=int,
        metavar="FRAMES",
        help="longest hole (lost or invalid frames) a window may contain; a longer one splits "
        "it (default: the detector's, a few frames)",
    )
    d.add_argument(
        "--motion",
        choices=("still", "hull"),
        default="still",
        help="still: the unit stands still between moves (a lab, a fixture; moving variance, "
        "default); hull: an IMU bolted to a hull that rolls, pitches, heaves and swings at its "
        "berth and turns now and then: quasi-static windows of minutes, their means corrected "
        "for the waves and their sigmas carrying the rest (docs/static.md, 'A hull that is "
        "never still'); needs outputs in deg/h and g, or --prior",
    )
    d.add_argument(
        "--prior",
        metavar="COEFFS.json",
        help="the unit's coefficients (a previous calibration): turns its outputs into deg/h "
        "and g and bounds how far they may be off for the rest check (default: outputs in "
        "physical units and navigation-class bounds; none for raw counts)",
    )
    d.add_argument(
        "--latitude",
        type=float,
        metavar="DEG",
        help="latitude of the recording, for the gravity the rest check expects (default: "
        "unknown, so gravity anywhere between the equator's and the pole's passes)",
    )
    d.add_argument(
        "--gyro-rate-max",
        type=float,
        metavar="RATE",
        help="reject windows whose mean gyro differs from the still-period mean (or zero) by "
        "more than RATE, gyro units: catches steady turns about the vertical",
    )


def run(args: argparse.Namespace) -> int:
    from recal.errors import RecalInputError
    from service.cli.recording import open_recording

    out = Path(args.output)
    report_path = getattr(args, "report", None)
    for path in (out, *([Path(report_path)] if report_path else [])):
        if not (path.parent if str(path.parent) else Path(".")).is_dir():
            raise RecalInputError(f"output folder {path.parent} does not exist")
    recording = open_recording(args)
    ship = read_ship_log(args)  # --nmea: read (and refused) before anything is detected
    rest = _rest_reference(args)
    motion = getattr(args, "motion", "still")
    if motion == "hull":
        if report_path:
            raise RecalInputError("--report is not available with --motion hull yet")
        windows, report = _detect_hull(recording, rest, args, ship)
    else:
        floor = None
        if not has_thresholds(args):
            floor = learn_noise_floor(recording, args)
        envelope = None
        if report_path:
            from recal.report.positions import RecordingEnvelope

            envelope = RecordingEnvelope()  # bounded: a few thousand buckets, however long
        windows, report = detect_file(recording, detector_config(args, recording, floor), envelope)
        if rest is not None:  # still in physics, not only in variance
            from recal.detect.rest import rest_filter

            kept, reasons = rest_filter(windows, rest)
            report.add_rest_rejections(windows, reasons)
            windows = kept
    joined = None
    if ship is not None:  # the underway rule (recal.detect.underway), as the daemon's
        windows, joined = ship.judge(windows, report, None if rest is None else rest.gyro_scale)
    if report_path:  # before the no-window error: the report shows why there is none
        _write_report(Path(report_path), envelope, report, windows, recording, floor, args)
    if not windows:
        if report_path:
            print(f"recal positions: wrote the report to {report_path}", file=sys.stderr)
        rejected = ", ".join(f"{k} {v}" for k, v in report.rejected.items() if v) or "none"
        raise RecalInputError(
            f"no static window found in {report.frames} frames (rejected: {rejected}): check "
            "the thresholds (--threshold-k, --init-still) and --min-duration"
        )
    # Printed only on success: a failed run prints its one-line error and nothing else.
    for line in recording.notes() + report.summary_lines():
        print(f"recal positions: {line}", file=sys.stderr)
    if ship is not None:
        print_lines(ship.summary(len(windows)))
    if motion == "still":
        if rest is None:
            print(
                "recal positions: no rest check in physics: the outputs are not in deg/h and g "
                "(give --prior to convert them)",
                file=sys.stderr,
            )
        _hint_hull(windows)
    positions = _write(out, windows, recording.triads, ship, joined)
    if _units(args.format) == {"gyro": "deg/h", "accel": "g"}:  # Earth rate, gravity check them
        from recal.detect.plausibility import check_units

        units = "--gyro-output / --gyro-units"
        for line in check_units(positions).problems("--rate", report.sample_rate_hz or 0.0, units):
            print(f"recal positions: warning: {line}", file=sys.stderr)
    durations = [w.duration_s for w in windows]
    print(
        f"recal positions: wrote {len(windows)} windows ({min(durations):.1f}-"
        f"{max(durations):.1f} s long) to {out}",
        file=sys.stderr,
    )
    if report_path:
        print(f"recal positions: wrote the report to {report_path}", file=sys.stderr)
    side = slews_path(out)
    if motion == "hull" and getattr(args, "slews", True):
        print(
            "recal positions: no slews with --motion hull: a slew needs still ends, and a "
            "rocking hull's window ends are off its mean attitude by the wave's angle",
            file=sys.stderr,
        )
    if (
        motion == "still"
        and getattr(args, "slews", True)
        and len(windows) > 1
        and recording.triads == ("gyro", "accel")
    ):
        _write_slews(side, recording, windows, report.sample_rate_hz)
    elif side.exists():
        side.unlink()  # a stale side file would not match the new windows
    return 0


def add_kvh_unit_options(p: argparse.ArgumentParser) -> None:
    """The KVH output settings a recording was made with (positions and navigate share them)."""
    k = p.add_argument_group("KVH device settings (must match the unit's configuration)")
    # No argparse defaults: unset means the device default (drivers.DecoderConfig), and a
    # flag given with another format is an error (service.cli.recording.format_options).
    k.add_argument(
        "--gyro-output",
        choices=("delta", "rate"),
        help="ROTFMT: delta angle per sample (default) or rate",
    )
    k.add_argument("--gyro-units", choices=("rad", "deg"), help="ROTUNITS (default rad)")
    k.add_argument(
        "--temp-units",
        choices=("degC", "centi"),
        help="whole degC (default) or hundredths (C_100)",
    )


def slews_path(positions: Path | str) -> Path:
    """The slews side file of a positions CSV: ``x.csv`` -> ``x.slews.npz``."""
    p = Path(positions)
    return p.with_name(p.stem + ".slews.npz") if p.suffix else p.with_name(p.name + ".slews.npz")


def _write_slews(path: Path, recording, windows, rate_hz: float | None) -> None:
    """Pass 3: the gyro samples between consecutive windows, as recal.detect.slew_groups increments."""
    from recal.detect.slew_collect import SlewCollector
    from service.cli.common import atomic_write

    if not rate_hz:
        return
    collector = SlewCollector(windows, 1.0 / rate_hz, recording.gyro_limits)
    with _ByteProgress(recording.total_bytes, "slews") as bar:
        for frames in recording.frames(bar.update):
            collector.feed(**frames)
    slews = collector.result()
    data = slews.to_npz_bytes()
    atomic_write(path, data)
    dropped = ", ".join(f"{k} {v}" for k, v in slews.dropped.items() if v)
    print(
        f"recal positions: kept {len(slews)} slews ({slews.sums.shape[1]} increments each) in "
        f"{path} ({len(data) / 1024:.0f} kB); dropped {slews.n_dropped}"
        + (f" ({dropped}): they cannot be integrated" if dropped else ""),
        file=sys.stderr,
    )


def has_thresholds(args: argparse.Namespace) -> bool:
    return args.init_still is not None or (
        args.accel_threshold is not None and args.gyro_threshold is not None
    )


def detector_config(args: argparse.Namespace, recording, floor):
    """The detector's settings: what the user gave; recal.detect.static_detector's defaults for the rest."""
    from recal.detect.static_config import DetectorConfig

    given = {
        "window_s": args.window,
        "min_duration_s": args.min_duration,
        "edge_trim_s": args.edge_trim,
        "accel_threshold": args.accel_threshold,
        "gyro_threshold": args.gyro_threshold,
        "init_still_s": args.init_still,
        "threshold_k": args.threshold_k,
        "sample_rate_hz": recording.sample_rate_hz,
        "max_gap_frames": args.max_gap,
        "gyro_rate_max": args.gyro_rate_max,
        "noise_floor": floor,
    }
    return DetectorConfig(**{k: v for k, v in given.items() if v is not None})


def _rest_reference(args: argparse.Namespace):
    """The rest check's reference (recal.detect.rest): from --prior, or nominal for a format whose
    outputs are deg/h and g; None when the outputs cannot be turned into physics."""
    from recal.detect.rest import RestReference

    given = getattr(args, "latitude", None)
    latitude = 45.0 if given is None else float(given)
    if not -90.0 <= latitude <= 90.0:
        from recal.errors import RecalInputError

        raise RecalInputError(f"--latitude {latitude:g}: must be within -90 to 90 degrees")
    prior = getattr(args, "prior", None)
    ref = None
    if prior:
        from service.cli.common import load_coefficients

        ref = RestReference.from_coefficients(load_coefficients(prior), latitude)
    elif _units(args.format) == {"gyro": "deg/h", "accel": "g"}:
        ref = RestReference.nominal(latitude)
    # without a latitude, gravity anywhere from the equator's to the pole's is at rest
    return ref.at_unknown_latitude() if ref is not None and given is None else ref


def _detect_hull(recording, rest, args: argparse.Namespace, ship=None):
    """One pass through the hull detector (recal.detect.hull): quasi-static windows; with the
    ship's log (``--nmea``) its heading gives each window's creep (recal.detect.creep)."""
    from recal.detect.hull import HullDetector
    from recal.errors import RecalInputError

    if rest is None:
        raise RecalInputError(
            "--motion hull judges windows by Earth's rate and gravity: the outputs must be in "
            "deg/h and g (a KVH), or give --prior to convert them"
        )
    if recording.triads != ("gyro", "accel"):
        raise RecalInputError("--motion hull needs both triads: the gyro sees the hull's motion")
    detector = None
    windows = []
    first = None
    with _ByteProgress(recording.total_bytes, "positions") as bar:
        for frames in recording.frames(bar.update):
            if detector is None:
                rate = recording.sample_rate_hz or _rate_of(frames["time_s"])
                detector = HullDetector(rest, rate_hz=rate)
                first = float(frames["time_s"][0])
            psi = None if ship is None else ship.heading_of(frames["time_s"], first)
            windows += detector.feed(
                frames["time_s"], frames["gyro"], frames["accel"],
                frames.get("temperature_c"), frames.get("valid"), heading_deg=psi,
            )  # fmt: skip
    if detector is None:
        raise RecalInputError(f"no frames in {recording.source}")
    windows += detector.flush()
    return [hw.window for hw in windows], detector.report


def _rate_of(time_s) -> float:
    import numpy as np

    from recal.errors import RecalInputError

    steps = np.diff(np.asarray(time_s, float))
    steps = steps[steps > 0]
    if not steps.size:
        raise RecalInputError("--motion hull needs the sample rate: give --rate")
    return 1.0 / float(np.median(steps))


def _hint_hull(windows) -> None:
    """A recording of a rocking hull gives the lulls between waves: say what to do instead."""
    if len(windows) < 20:
        return
    short = sum(1 for w in windows if w.duration_s < 10.0)
    if short >= 0.5 * len(windows):
        print(
            f"recal positions: note: {short} of {len(windows)} windows last less than 10 s: "
            "if the unit is on a hull that rocks, these are the lulls between waves, whose means "
            "carry the wave's phase; use --motion hull",
            file=sys.stderr,
        )


def learn_noise_floor(recording, args: argparse.Namespace):
    """Pass 1: the moving-variance floor of the whole recording (recal.detect.static_detector)."""
    from recal.detect.floor import NoiseFloorEstimator

    given = {"window_s": args.window, "sample_rate_hz": recording.sample_rate_hz}
    estimator = NoiseFloorEstimator(**{k: v for k, v in given.items() if v is not None})
    with _ByteProgress(recording.total_bytes, "noise floor") as bar:
        for frames in recording.frames(bar.update):
            estimator.feed(frames["time_s"], frames["gyro"], frames["accel"], frames["valid"])
    return estimator.result()


def detect_file(recording, config, envelope=None):
    """Pass 2: stream the recording through the incremental detector (and into the report's
    envelope when one is given)."""
    from recal.detect.static_detector import StaticDetector

    detector = StaticDetector(config, on_traces=None if envelope is None else envelope.on_traces)
    windows = []
    with _ByteProgress(recording.total_bytes, "positions") as bar:
        for frames in blocks(recording.frames(bar.update), DETECTOR_BLOCK):
            windows += detector.feed(**frames)
        windows += detector.flush()
    return windows, detector.report


def _write_report(path: Path, envelope, report, windows, recording, floor, args) -> None:
    """The HTML report of the detection (recal.report.positions), atomically."""
    from recal.report.positions import positions_html
    from service.cli.common import atomic_write

    names = " ".join(Path(p).name for p in args.inputs)
    page = positions_html(
        envelope,
        report,
        windows,
        title=f"recal positions {names}",
        triads=recording.triads,
        units=_units(args.format),
        noise_floor=floor,
        notes=recording.notes(),
    )
    atomic_write(path, page)


def _units(fmt: str) -> dict[str, str]:
    """Input units of each triad as the recording gives them (the format's registration)."""
    from drivers.registry import get_input_format

    gyro, accel = get_input_format(fmt).units
    return {"gyro": gyro, "accel": accel}


def _write(out: Path, windows, triads: tuple[str, ...], ship=None, joined=None) -> Any:
    """The positions CSV, atomically (columns of a triad the input lacks are left out; with
    ``--nmea`` the ship's columns, and the transport rate in the gyro sigma); returns the
    :class:`recal.model.positions.Positions` written."""
    from recal.detect.windows import windows_to_columns
    from recal.model.positions import Positions
    from service.cli.common import atomic_write

    missing = tuple(f"{s}_" for s in ("gyro", "accel") if s not in triads)
    columns = windows_to_columns(windows)
    if ship is not None:
        columns = ship.columns(columns, joined)
    columns = {k: v for k, v in columns.items() if not k.startswith(missing)}
    positions = Positions.from_columns(columns, source=str(out))
    atomic_write(out, positions.to_csv_text())
    return positions


def blocks(pieces, size: int):
    """Re-cut a stream of frame dicts into blocks of exactly ``size`` frames (the last shorter).

    Holds at most one block plus one piece.
    """
    held: list[dict] = []
    count = 0
    for piece in pieces:
        held.append(piece)
        count += piece["time_s"].shape[0]
        while count >= size:
            joined = _join(held)
            yield {k: (None if v is None else v[:size]) for k, v in joined.items()}
            rest = {k: (None if v is None else v[size:]) for k, v in joined.items()}
            count -= size
            held = [rest] if count else []
    if count:
        yield _join(held)


def _join(pieces: list[dict]) -> dict:
    import numpy as np

    if len(pieces) == 1:
        return pieces[0]
    return {
        k: (None if pieces[0][k] is None else np.concatenate([p[k] for p in pieces]))
        for k in pieces[0]
    }


class _ByteProgress:
    """A bytes-read progress bar on stderr for long inputs on a terminal (else nothing)."""

    def __init__(self, total: int, desc: str) -> None:
        self._bar = None
        if total >= _PROGRESS_MIN_BYTES and sys.stderr.isatty():
            from service.cli.common import progress_bar

            self._bar = progress_bar(total, desc, unit="B")

    def update(self, n: int) -> None:
        if self._bar is not None:
            self._bar.update(n)

    def __enter__(self) -> _ByteProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._bar.close()
