"""``recal simulate``: write a positions CSV, or a byte-level capture, of a simulated session.

Without ``--capture`` the window means are drawn directly (:mod:`recal.sim.simulate`). With
``--capture OUT.bin`` every sample is simulated (:mod:`recal.sim.session`: holds joined by slews) and
written as the frames a KVH sends (:mod:`service.capture_sim`), optionally damaged; ``-o`` then
writes the true window means of the same session's holds. ``--berth`` and ``--indexing`` simulate
a hull-fixed unit on a vessel sample by sample (:mod:`recal.sim.vessel`), streamed to a CSV
recording and/or a KVH capture chunk by chunk, so a week needs no more memory than ten minutes.

The command's parts live beside it (issue 38): its options and their defaults
(:mod:`service.cli.simulate_args`), the files it writes besides positions (the capture, CSV
tables, a schedule, NMEA sentences: :mod:`service.cli.simulate_writers`), the vessel
(:mod:`service.cli.simulate_vessel`) and the navigation recording
(:mod:`service.cli.simulate_trajectory`); this module checks the options and simulates a
calibration session (window means, or a capture of its samples).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from service.cli.simulate_args import (
    CAPTURE_SLEW_S,
    CAPTURE_WINDOW_S,
    DEFAULT_ARW_DEG_RT_H,
    DEFAULT_RATE_HZ,
    TRAJECTORY_RATE_HZ,
    VESSEL_ARW_DEG_RT_H,
    add_arguments,
)
from service.cli.simulate_trajectory import run_trajectory
from service.cli.simulate_vessel import run_vessel
from service.cli.simulate_writers import write_capture


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "simulate",
        help="simulate a static multi-position session and write its positions CSV",
        description="Simulate the window means of a static session (docs/reference.md#positions). "
        "Truth defaults to seed 000 Table 2 (gyro) and the project's accelerometer stand-in. "
        "With --capture, simulate every sample (static holds joined by slews) and write the "
        "bytes a KVH would send (delta angle in rad, accel in g, whole-degC temperature); the "
        "truth then defaults to a unit that outputs physical units (scale ~1).",
    )
    add_arguments(p)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from recal.errors import RecalInputError
    from recal.model.coefficients import CoefficientSet
    from recal.model.terms import catalogue_terms
    from recal.sim.simulate import NoiseSpec, TemperatureSpec, simulate_positions
    from service.cli.common import atomic_write, load_coefficients, parse_effects

    vessel = args.berth or args.indexing is not None
    if args.rate is None:
        args.rate = TRAJECTORY_RATE_HZ if args.trajectory or vessel else DEFAULT_RATE_HZ
    if args.arw is None:
        args.arw = VESSEL_ARW_DEG_RT_H if vessel else DEFAULT_ARW_DEG_RT_H
    if not -90.0 <= args.latitude <= 90.0:  # NaN fails too
        raise RecalInputError(f"--latitude {args.latitude} is outside [-90, 90] deg")
    if not np.isfinite(args.height) or not np.isfinite(args.rate):
        raise RecalInputError("--height and --rate must be finite numbers")
    if args.trajectory and vessel:
        raise RecalInputError("--trajectory and --berth/--indexing are different simulations: "
                              "give one")  # fmt: skip
    if args.trajectory:
        if args.nmea or args.transit:
            raise RecalInputError("--nmea and --transit need --berth (or --indexing for --nmea)")
        return run_trajectory(args)
    if vessel:
        return run_vessel(args)
    if args.recording or args.track:
        raise RecalInputError(
            "--recording and --track need --trajectory voyage|static, --berth or --indexing"
        )
    if args.nmea or args.transit:
        raise RecalInputError("--nmea and --transit need --berth (or --indexing for --nmea)")
    catalogue = catalogue_terms()
    hidden = []
    for name in parse_effects(args.hidden):
        if name not in catalogue:
            raise RecalInputError(f"unknown effect '{name}'; known: {', '.join(catalogue)}")
        hidden.append(catalogue[name])
    if args.output is None and args.capture is None:
        raise RecalInputError("give -o POSITIONS.csv, --capture OUT.bin, or both")
    damage_flags = (args.bit_flips, args.garbage, args.drop)
    if args.capture is None and any(damage_flags):
        raise RecalInputError("--bit-flips, --garbage and --drop damage a capture: add --capture")
    if min(damage_flags) < 0:
        raise RecalInputError("--bit-flips, --garbage and --drop must be >= 0")
    capture = args.capture is not None
    window, slew = args.window, args.slew
    if window is None:
        window = CAPTURE_WINDOW_S if capture else NoiseSpec.window_s
    if slew is None:
        slew = CAPTURE_SLEW_S if capture else NoiseSpec.slew_s
    if window <= 0 or slew <= 0 or args.rate <= 0 or args.arw < 0 or args.vrw < 0:
        raise RecalInputError(
            "--window, --slew and --rate must be positive, --arw and --vrw non-negative"
        )
    if args.first_hold is not None and (not capture or args.first_hold <= 0):
        raise RecalInputError("--first-hold needs --capture and must be positive")
    for out in (args.output, args.capture, args.truth_out):
        # Checked up front: a missing folder must not leave some outputs written and not others.
        folder = Path(out).parent if out is not None else None
        if folder is not None and str(folder) and not folder.is_dir():
            raise RecalInputError(f"output folder {folder} does not exist")
    if capture:
        from service.capture_sim import kvh_like_truth  # the drivers only when asked for

        base = kvh_like_truth(np.random.default_rng(args.seed))
    else:
        base = CoefficientSet.seed_truth()
    truth = load_coefficients(args.truth, catalogue) if args.truth else base.copy()
    for name, v in base.values.items():  # a partial truth file keeps the defaults elsewhere
        truth.values.setdefault(name, v)
    sensors = ("gyro", "accel") if args.sensor == "both" else (args.sensor,)
    noise = NoiseSpec(args.arw, args.vrw, window, slew, rate_hz=args.rate)
    temperature = TemperatureSpec(
        args.temp_start, args.temp_slope, args.temp_swing, args.temp_period
    )
    if capture:
        positions = write_capture(args, truth, noise, temperature, hidden, sensors)
    else:
        positions = simulate_positions(
            truth,
            args.design,
            args.positions,
            args.latitude,
            args.height,
            args.seed,
            sensors,
            noise,
            temperature,
            hidden,
        )
    if args.output is not None:
        atomic_write(args.output, positions.to_csv_text())
    if args.truth_out:
        used = truth.copy()
        for t in hidden:
            used.values.setdefault(t.name, list(t.typical))
        atomic_write(args.truth_out, json.dumps(used.to_json_dict(catalogue), indent=2) + "\n")
    if args.output is not None:
        print(
            f"recal simulate: wrote {len(positions)} positions ({args.design} design, "
            f"seed {args.seed}{'; true means over the static holds' if capture else ''}) to "
            f"{args.output}",
            file=sys.stderr,
        )
        from service.cli.positions import slews_path

        side = slews_path(args.output)
        if side.is_file():  # written by `recal positions` for the file just replaced
            print(f"recal simulate: {side} beside it belongs to the positions file it replaced "
                  "(these positions have no slews); calibrate will ignore it", file=sys.stderr)  # fmt: skip
    return 0
