"""``recal export``: a calibration in the formats other tools read (docs/export.md).

The files' contents come from :mod:`recal.export` (text, no I/O); this module reads the inputs,
writes each file atomically and says on stderr what the format could not carry and what that
costs. imu_tk has one file per triad: ``-o PREFIX`` writes ``PREFIX_acc.calib`` and
``PREFIX_gyro.calib``, as imu_tk's own example names them.

Only argparse is imported to build the parser; recal is imported by run().
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

FORMATS = ("kalibr", "imucal", "imu_tk", "ros", "px4", "ardupilot")  # recal.export.FORMATS


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "export",
        help="write a calibration (and its noise) in the format of kalibr, imucal, imu_tk, ROS, "
        "PX4 or ArduPilot",
        description="Write COEFFS.json in another tool's format: kalibr (imu.yaml noise keys, "
        "from --noise), imucal (its JSON), imu_tk (its text matrices, one file per triad), ros "
        "(the sensor_msgs/Imu covariances, from --noise), px4 and ardupilot (parameter files, "
        "with their temperature terms). Each file states what the format cannot carry and the "
        "error that costs, in the format's units (docs/export.md).",
    )
    p.add_argument(
        "coefficients",
        metavar="COEFFS.json",
        help="a coefficients file, a `recal calibrate --json` output or the published "
        "coefficients.json",
    )
    p.add_argument("--to", required=True, choices=FORMATS, help="the format to write")
    p.add_argument(
        "--noise",
        metavar="NOISE.json",
        help="`recal noise --json` output (needed by kalibr and ros)",
    )
    p.add_argument(
        "--rate",
        type=float,
        metavar="HZ",
        help="ros: the rate the driver publishes at (default: the rate the noise was measured at)",
    )
    p.add_argument(
        "-o",
        "--output",
        required=True,
        metavar="FILE",
        help="the file to write (imu_tk: a prefix, PREFIX_acc.calib and PREFIX_gyro.calib)",
    )
    p.set_defaults(func=run)
    return p


def output_paths(output: str, parts: list[str]) -> dict[str, Path]:
    """Part name -> path: the output itself for a one-file format, else PREFIX_part.calib."""
    if parts == [""]:
        return {"": Path(output)}
    return {part: Path(f"{output}_{part}.calib") for part in parts}


def run(args: argparse.Namespace) -> int:
    from recal.errors import RecalInputError
    from recal.export import export_calibration
    from recal.model.coefficient_schema import parse_json
    from service.cli.common import atomic_write, load_coefficients, read_text

    if args.rate is not None and not args.rate > 0:
        raise RecalInputError("--rate must be a positive number of Hz")
    coefficients = load_coefficients(args.coefficients)
    noise = None
    if args.noise:
        noise = parse_json(read_text(args.noise, "noise file"), args.noise)
        if not isinstance(noise, dict):
            raise RecalInputError(f"{args.noise}: expected the JSON object of `recal noise --json`")
    exported = export_calibration(coefficients, args.to, noise, args.rate)
    paths = output_paths(args.output, list(exported.files))
    for part, text in exported.files.items():
        atomic_write(paths[part], text)
    for loss in exported.losses:
        print(f"recal export: {loss.line()}", file=sys.stderr)
    written = ", ".join(str(p) for p in paths.values())
    print(f"recal export: wrote {args.to} to {written}", file=sys.stderr)
    return 0
