"""``recal apply``: calibrated rates and specific forces from a recording's raw outputs.

The recording is read as by ``recal positions`` / ``noise`` (any registered format, streamed in
chunks by :func:`service.cli.recording.open_recording`: memory stays flat however long it is);
each chunk goes through :class:`recal.model.apply.Applier` (docs/apply.md: the model's inverse,
temperature and quadratic terms included) and is written to the CSV as it comes. The units are
chosen by ``--out-units`` and stated in the column names; a progress bar on stderr counts the
bytes read when the input is large and stderr is a terminal.

Only argparse is imported to build the parser; numpy, recal and drivers are imported by run().
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

#: Significant digits written: float64 round-trips to ~1e-12 relative, far below any sensor's
#: resolution, at two thirds of the file size of full precision.
DIGITS = 12
_PROGRESS_MIN_BYTES = 16 << 20  # below this a bar would only flicker
#: Column suffix of each unit (a CSV header cannot hold '/' or '^' portably).
UNIT_SUFFIX = {"deg/h": "deg_per_h", "deg/s": "deg_per_s", "rad/s": "rad_per_s", "g": "g",
               "m/s^2": "m_per_s2"}  # fmt: skip
DEFAULT_UNITS = {"gyro": "deg/h", "accel": "g"}


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    from service.cli.positions import add_input_options, add_kvh_unit_options

    p = sub.add_parser(
        "apply",
        help="apply a coefficients file to a recording: calibrated rates and specific forces "
        "as CSV",
        description="Invert the error model of COEFFS.json (docs/apply.md: scale, bias, "
        "misalignment, the accelerometer's quadratic term and the temperature, temperature-rate, "
        "g-sensitivity and drift effects it carries) on every sample of a recording and write "
        "the calibrated angular rates and specific forces, one row per sample. The input is "
        "streamed: memory does not grow with its length.",
    )
    p.add_argument(
        "coefficients",
        metavar="COEFFS.json",
        help="a coefficients file, a `recal calibrate --json` output or the daemon's published "
        "coefficients.json",
    )
    add_input_options(p)
    p.add_argument(
        "-o",
        "--output",
        required=True,
        metavar="OUT.csv",
        help="the CSV to write: time_s, gyro_x_UNIT..., accel_x_UNIT..., temperature_c (when "
        "the recording has it), valid (when the format flags frames)",
    )
    p.add_argument(
        "--out-units",
        metavar="TRIAD=UNIT,...",
        help="units of the calibrated output: gyro=deg/h|deg/s|rad/s, accel=g|m/s^2 (default "
        "gyro=deg/h,accel=g, the model's own)",
    )
    p.add_argument(
        "--plugin",
        metavar="FILE.py",
        help="the plugin file of an effect the coefficients carry that is not in the catalogue",
    )
    add_kvh_unit_options(p)
    p.set_defaults(func=run)
    return p


def parse_out_units(text: str | None) -> dict[str, str]:
    """``gyro=deg/s,accel=m/s^2`` -> {"gyro": ..., "accel": ...}; unset triads keep the
    model's units."""
    from recal.errors import RecalInputError
    from recal.model.apply import ACCEL_UNITS, GYRO_UNITS

    units = dict(DEFAULT_UNITS)
    for item in filter(None, (text or "").split(",")):
        triad, _, unit = (s.strip() for s in item.partition("="))
        known = {"gyro": GYRO_UNITS, "accel": ACCEL_UNITS}.get(triad)
        if known is None or unit not in known:
            raise RecalInputError(
                f"--out-units: {item!r} is not gyro=({'|'.join(GYRO_UNITS)}) or "
                f"accel=({'|'.join(ACCEL_UNITS)})"
            )
        units[triad] = unit
    return units


def header(sensors: tuple[str, ...], units: dict[str, str], temperature: bool, valid: bool):
    """The output's column names: the unit is in each name (``gyro_x_deg_per_s``)."""
    cols = ["time_s"]
    for s in sensors:
        cols += [f"{s}_{a}_{UNIT_SUFFIX[units[s]]}" for a in "xyz"]
    return cols + (["temperature_c"] if temperature else []) + (["valid"] if valid else [])


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from recal.errors import RecalInputError
    from recal.model.apply import Applier
    from service.cli.common import atomic_stream, load_coefficients, load_plugin, progress_bar
    from service.cli.recording import open_recording

    units = parse_out_units(args.out_units)
    terms = {t.name: t for t in load_plugin(args.plugin)} if args.plugin else None
    coeffs = load_coefficients(args.coefficients, terms)
    applier = Applier(coeffs, units["gyro"], units["accel"], terms)
    recording = open_recording(args)
    sensors = tuple(s for s in applier.sensors if s in recording.triads)
    if not sensors:
        raise RecalInputError(
            f"the coefficients calibrate {' and '.join(applier.sensors)}, which the recording "
            f"({', '.join(recording.triads)}) lacks"
        )
    skipped = [s for s in applier.sensors if s not in sensors]
    has_valid = recording.format.has_status
    bar = None
    if recording.total_bytes >= _PROGRESS_MIN_BYTES:
        bar = progress_bar(recording.total_bytes, "applying", unit="B")
    rows = 0
    has_temp: bool | None = None
    try:
        with atomic_stream(args.output) as fh:
            for frames in recording.frames(bar.update if bar else None):
                if has_temp is None:
                    has_temp = frames["temperature_c"] is not None
                    names = header(sensors, units, has_temp, has_valid)
                    fh.write((",".join(names) + "\n").encode())
                    line = ",".join([f"%.{DIGITS}g"] * len(names)) + "\n"
                out = applier(
                    frames["time_s"],
                    frames["gyro"] if "gyro" in sensors else None,
                    frames["accel"] if "accel" in sensors else None,
                    frames["temperature_c"],
                )
                cols: list[Any] = [np.asarray(frames["time_s"], float)[:, None]]
                cols += [getattr(out, s) for s in sensors]
                if has_temp:
                    cols.append(np.asarray(frames["temperature_c"], float)[:, None])
                if has_valid:
                    valid = frames["valid"]
                    n = cols[0].shape[0]
                    cols.append(
                        np.ones((n, 1)) if valid is None else np.asarray(valid, float)[:, None]
                    )
                table = np.hstack(cols)
                # one %-format per row on Python floats: ~3 us a row, a third of np.savetxt's
                fh.write("".join(map(line.__mod__, map(tuple, table.tolist()))).encode())
                rows += table.shape[0]
            if has_temp is None:
                raise RecalInputError(f"{recording.source}: the recording has no frames")
    finally:
        if bar is not None:
            bar.close()
    note = f" ({', '.join(skipped)} not in the recording)" if skipped else ""
    print(
        f"recal apply: wrote {rows} calibrated samples of {' and '.join(sensors)}{note} to "
        f"{args.output} ({', '.join(f'{s} in {units[s]}' for s in sensors)})",
        file=sys.stderr,
    )
    return 0
