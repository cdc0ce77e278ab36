"""``recal simulate --trajectory voyage|static``: a vessel's navigation recording for
``recal navigate`` (:mod:`recal.nav.trajectory`) and its true track."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from service.cli.simulate_writers import RECORDING_COLUMNS, table_csv


def run_trajectory(args: argparse.Namespace) -> int:
    """``--trajectory``: a vessel recording for ``recal navigate`` and its true track."""
    import numpy as np

    from recal.errors import RecalInputError
    from recal.model.terms import catalogue_terms
    from recal.nav.alignment import parse_attitude
    from recal.nav.trajectory import VoyageSpec, simulate_voyage
    from recal.sim.simulate import NoiseSpec
    from service.cli.common import atomic_write, load_coefficients

    if args.capture is None and args.recording is None:
        raise RecalInputError("--trajectory needs --capture OUT.bin or --recording OUT.csv")
    if args.output or args.hidden or args.sensor != "both":
        raise RecalInputError(
            "--trajectory writes a recording: -o, --hidden, --sensor do not apply"
        )
    if args.rate <= 0 or args.arw < 0 or args.vrw < 0 or args.moor <= 0 or args.duration <= 0:
        raise RecalInputError("--rate, --moor, --duration must be positive, --arw, --vrw >= 0")
    for out in (args.capture, args.recording, args.track, args.truth_out):
        folder = Path(out).parent if out is not None else None
        if folder is not None and str(folder) and not folder.is_dir():
            raise RecalInputError(f"output folder {folder} does not exist")
    roll, pitch, yaw = parse_attitude(args.attitude)
    if args.trajectory == "static":
        spec = VoyageSpec.static(args.duration, (roll, pitch, yaw))
    else:
        spec = VoyageSpec(moor_s=args.moor, heading0_deg=yaw, mount_rpy_deg=(roll, pitch, 0.0))
    from service.capture_sim import kvh_like_truth

    catalogue = catalogue_terms()
    base = kvh_like_truth(np.random.default_rng(args.seed))
    truth = load_coefficients(args.truth, catalogue) if args.truth else base.copy()
    for name, v in base.values.items():
        truth.values.setdefault(name, v)
    noise = NoiseSpec(args.arw, args.vrw)
    voyage = simulate_voyage(
        truth, spec, args.latitude, args.longitude, args.height, args.rate, noise,
        args.temp_start, args.seed,
    )  # fmt: skip
    s = voyage.session
    if args.capture:
        from drivers import DecoderConfig
        from service.capture_sim import session_to_kvh

        data, info = session_to_kvh(s, args.capture_format, DecoderConfig(rate_hz=args.rate))
        atomic_write(args.capture, data)
    if args.recording:
        table = np.column_stack([s.time_s, s.gyro_out, s.accel_out, s.temperature_c])
        atomic_write(args.recording, table_csv(table, RECORDING_COLUMNS, "%.10g"))
    if args.track:
        cols = voyage.truth_columns()
        every = max(1, round(args.rate / 10.0))  # 10 Hz is plenty for interpolation
        table = np.column_stack([c[::every] for c in cols.values()])
        atomic_write(args.track, table_csv(table, tuple(cols), "%.12g"))
    if args.truth_out:
        atomic_write(args.truth_out, json.dumps(truth.to_json_dict(catalogue), indent=2) + "\n")
    where = ", ".join(p for p in (args.capture, args.recording) if p)
    print(
        f"recal simulate: wrote a {spec.duration_s / 3600:.2f} h {args.trajectory} at "
        f"{args.rate:g} Hz ({len(s)} samples) to {where}"
        + (f"; true track to {args.track}" if args.track else ""),
        file=sys.stderr,
    )
    return 0
