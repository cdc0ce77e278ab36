"""``recal simulate --berth`` / ``--indexing``: a hull-fixed unit on a vessel sample by sample
(:mod:`recal.sim.vessel`: holds joined by turns or indexing stops, an optional transit),
streamed chunk by chunk to a CSV recording and/or a KVH capture, with its schedule, truth and
the ship's NMEA sentences."""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from pathlib import Path

from service.cli.simulate_args import VESSEL_CHUNK_S
from service.cli.simulate_writers import RECORDING_COLUMNS, nmea_log, nmea_start, schedule_csv


def run_vessel(args: argparse.Namespace) -> int:
    """``--berth`` / ``--indexing``: a hull-fixed unit sample by sample, streamed to disk."""
    import numpy as np

    from recal.errors import RecalInputError
    from recal.model.terms import catalogue_terms
    from recal.nav.alignment import parse_attitude
    from recal.sim.simulate import NoiseSpec
    from recal.sim.vessel import vessel_chunks
    from recal.sim.vessel_spec import SeaState, VesselSpec
    from service.capture_sim import encode_kvh, kvh_like_truth
    from service.cli.common import atomic_stream, atomic_write, load_coefficients, progress_bar

    mode = "--indexing" if args.indexing is not None else "--berth"
    if args.berth and args.indexing is not None:
        raise RecalInputError("--berth and --indexing are different schedules: give one")
    not_here = [flag for flag, given in (
        ("--hidden", args.hidden), ("--sensor", args.sensor != "both"),
        ("--positions", args.positions is not None), ("--window", args.window is not None),
        ("--slew", args.slew is not None), ("--first-hold", args.first_hold is not None),
        ("--temp-swing", args.temp_swing != 0.0), ("--bit-flips", args.bit_flips),
        ("--garbage", args.garbage), ("--drop", args.drop),
    ) if given]  # fmt: skip
    if not_here:
        raise RecalInputError(
            f"{', '.join(not_here)} do(es) not apply to {mode} (a vessel recording: its holds "
            "are --hold long, the capture is undamaged)"
        )
    if args.output and args.recording and args.output != args.recording:
        raise RecalInputError("-o and --recording both name the CSV recording: give one")
    recording = args.recording or args.output
    if recording is None and args.capture is None:
        raise RecalInputError(f"{mode} needs -o OUT.csv (a CSV recording), --capture OUT.bin, "
                              "or both")  # fmt: skip
    for out in (recording, args.capture, args.track, args.truth_out, args.nmea):
        folder = Path(out).parent if out is not None else None
        if folder is not None and str(folder) and not folder.is_dir():
            raise RecalInputError(f"output folder {folder} does not exist")
    if args.rate <= 0 or args.arw < 0 or args.vrw < 0:
        raise RecalInputError("--rate must be positive, --arw and --vrw non-negative")
    amplitudes = {"--roll": args.roll, "--pitch": args.pitch, "--yaw-swing": args.yaw_swing,
                  "--heave": args.heave}  # fmt: skip
    for flag, v in amplitudes.items():
        if v is not None and not (np.isfinite(v) and v >= 0):
            raise RecalInputError(f"{flag} must be a non-negative number, not {v}")
    if not (np.isfinite(args.hold) and args.hold > 0):
        raise RecalInputError(f"--hold must be positive, not {args.hold}")
    lever = parse_triple(args.lever_arm, "--lever-arm")
    utc_start = nmea_start(args) if args.nmea else None
    roll, pitch, yaw = parse_attitude(args.attitude)
    sea = SeaState(
        roll_deg=args.roll,
        roll_period_s=args.roll_period,
        pitch_deg=args.roll / 2.0 if args.pitch is None else args.pitch,
        pitch_period_s=args.pitch_period,
        yaw_swing_deg=args.yaw_swing,
        yaw_period_s=args.yaw_period,
        heave_m=args.heave,
        heave_period_s=args.heave_period,
        lever_arm_m=lever,
    )
    if args.indexing is not None:
        if roll or pitch:
            raise RecalInputError("with --indexing the stops give the IMU's attitude in the hull: "
                                  "--attitude takes only the heading (0,0,YAW)")  # fmt: skip
        if args.transit:
            raise RecalInputError("--transit sails between berths: it needs --berth")
        stops = [parse_triple(stop, "--indexing stop") for stop in args.indexing.split("/")]
        if not (np.isfinite(args.index_s) and args.index_s > 0):
            raise RecalInputError(f"--index-s must be positive, not {args.index_s}")
        spec = VesselSpec.indexing(stops, args.hold, args.index_s, sea, heading0_deg=yaw)
        what = (f"{len(stops)} indexing stops of {args.hold:g} s "
                f"({args.index_s:g} s between stops)")  # fmt: skip
    else:
        if args.holds < 1:
            raise RecalInputError(f"--holds must be at least 1, not {args.holds}")
        if not (np.isfinite(args.turn_s) and np.isfinite(args.turn_deg)):
            raise RecalInputError("--turn-s and --turn-deg must be finite numbers")
        if not (np.isfinite(args.transit) and args.transit >= 0):
            raise RecalInputError(f"--transit must be a duration >= 0 s, not {args.transit}")
        if args.transit and not (np.isfinite(args.transit_kn) and args.transit_kn > 0):
            raise RecalInputError(f"--transit-kn must be a positive speed, not {args.transit_kn}")
        spec = VesselSpec.berth(args.holds, args.hold, args.turn_s, args.turn_deg, sea,
                                heading0_deg=yaw, mount_rpy_deg=(roll, pitch, 0.0),
                                transit_s=args.transit, transit_kn=args.transit_kn)  # fmt: skip
        what = (f"{args.holds} berth holds of {args.hold:g} s joined by {args.turn_deg:g}-degree "
                f"turns of {args.turn_s:g} s")  # fmt: skip
        if args.transit:
            what += f", with a {args.transit:g} s transit at {args.transit_kn:g} kn"

    catalogue = catalogue_terms()
    base = kvh_like_truth(np.random.default_rng(args.seed))
    truth = load_coefficients(args.truth, catalogue) if args.truth else base.copy()
    for name, v in base.values.items():  # a partial truth file keeps the defaults elsewhere
        truth.values.setdefault(name, v)
    noise = NoiseSpec(args.arw, args.vrw)
    n_total = round(spec.duration_s * args.rate)
    chunks = vessel_chunks(truth, spec, args.latitude, args.height, args.rate, noise,
                           args.temp_start, args.seed, chunk_s=VESSEL_CHUNK_S)  # fmt: skip
    fmt = args.capture_format
    config = None
    if args.capture is not None:
        from drivers import DecoderConfig

        config = DecoderConfig(rate_hz=args.rate)
    with contextlib.ExitStack() as stack:
        csv = stack.enter_context(atomic_stream(recording)) if recording else None
        cap = stack.enter_context(atomic_stream(args.capture)) if args.capture else None
        bar = progress_bar(n_total, f"recal simulate {mode}", unit="sample")
        stack.callback(bar.close)
        if csv is not None:
            csv.write((",".join(RECORDING_COLUMNS) + "\n").encode())
        done = 0
        for c in chunks:
            if csv is not None:
                table = np.column_stack([c.time_s, c.gyro_out, c.accel_out, c.temperature_c])
                np.savetxt(csv, table, fmt="%.10g", delimiter=",")
            if cap is not None:
                cap.write(encode_kvh(c.gyro_out, c.accel_out, c.temperature_c, fmt, config,
                                     first_frame=done))  # fmt: skip
            done += len(c.time_s)
            bar.update(len(c.time_s))
    if args.track:
        atomic_write(args.track, schedule_csv(spec))
    if args.truth_out:
        atomic_write(args.truth_out, json.dumps(truth.to_json_dict(catalogue), indent=2) + "\n")
    if args.nmea:
        atomic_write(args.nmea, nmea_log(spec, args, utc_start))
    where = " and ".join(p for p in (recording, args.capture) if p)
    # a CSV log carries no units: the hull detector converts it with the coefficients
    prior = args.truth_out or "COEFFS.json"
    fmt_flag = f"csv --prior {prior}" if recording else f"{fmt} --rate {args.rate:g}"
    first = recording or args.capture
    print(
        f"recal simulate: wrote {what} ({spec.duration_s / 3600:.2f} h at {args.rate:g} Hz, "
        f"{n_total:,} samples; sea: roll {sea.roll_deg:g} deg, pitch {sea.pitch_deg:g} deg, yaw "
        f"swing {sea.yaw_swing_deg:g} deg, heave {sea.heave_m:g} m) to {where}"
        + (f"; schedule to {args.track}" if args.track else "")
        + (f"; the ship's NMEA sentences to {args.nmea}" if args.nmea else "")
        + f"; read it with `recal positions {first} --format {fmt_flag} --motion hull "
        + (f"--nmea {args.nmea}" if args.nmea else f"--latitude {args.latitude:g}")
        + " -o POSITIONS.csv`",
        file=sys.stderr,
    )
    return 0


def parse_triple(text: str, flag: str) -> tuple[float, float, float]:
    """'x,y,z' as three finite numbers; an input error naming ``flag`` otherwise."""
    import math

    from recal.errors import RecalInputError

    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise RecalInputError(f"{flag} {text!r}: expected three numbers X,Y,Z")
    return values  # type: ignore[return-value]
