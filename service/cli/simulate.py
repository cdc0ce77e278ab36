"""``recal simulate``: write a positions CSV from a simulated static session."""

from __future__ import annotations

import argparse
import json
import sys

from recal.coefficients import CoefficientSet
from recal.errors import RecalInputError
from recal.simulate import DESIGNS, NoiseSpec, TemperatureSpec, simulate_positions
from recal.terms import catalogue_terms
from service.cli.common import atomic_write, load_coefficients, parse_effects


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "simulate",
        help="simulate a static multi-position session and write its positions CSV",
        description="Simulate the window means of a static session (conventions section 4). "
        "Truth defaults to seed 000 Table 2 (gyro) and the project's accelerometer stand-in.",
    )
    p.add_argument(
        "--design",
        choices=DESIGNS,
        default="24",
        help="24: seed 002 section 7.1 turntable scheme; random: random orientations; "
        "vessel: hull-fixed, heading-only (default 24)",
    )
    p.add_argument(
        "--positions", type=int, default=None, help="number of positions (random, vessel)"
    )
    p.add_argument(
        "--truth", metavar="FILE", help="truth coefficients JSON (conventions section 5)"
    )
    p.add_argument(
        "--hidden",
        metavar="EFFECT[,EFFECT]",
        help="catalogue effects present in the data but not in the seed model",
    )
    p.add_argument("--sensor", choices=("gyro", "accel", "both"), default="both")
    p.add_argument("--latitude", type=float, default=45.0, help="site latitude, deg (default 45)")
    p.add_argument("--height", type=float, default=0.0, help="site height, m")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--arw",
        type=float,
        default=NoiseSpec.arw_deg_rt_h,
        help="gyro angle random walk, deg/sqrt(h) (default %(default)s)",
    )
    p.add_argument(
        "--vrw",
        type=float,
        default=NoiseSpec.vrw_ug_rt_hz,
        help="accel noise density, micro-g/sqrt(Hz) (default %(default)s)",
    )
    p.add_argument(
        "--window",
        type=float,
        default=NoiseSpec.window_s,
        help="static window length, s (default %(default)s)",
    )
    p.add_argument("--rate", type=float, default=NoiseSpec.rate_hz, help="sample rate, Hz")
    p.add_argument("--temp-start", type=float, default=TemperatureSpec.start_c, help="degC")
    p.add_argument(
        "--temp-slope",
        type=float,
        default=TemperatureSpec.slope_c_per_h,
        help="temperature ramp, degC/h (default %(default)s)",
    )
    p.add_argument("--truth-out", metavar="FILE", help="also write the truth used, as JSON")
    p.add_argument("-o", "--output", required=True, metavar="POSITIONS.csv")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    catalogue = catalogue_terms()
    hidden = []
    for name in parse_effects(args.hidden):
        if name not in catalogue:
            raise RecalInputError(f"unknown effect '{name}'; known: {', '.join(catalogue)}")
        hidden.append(catalogue[name])
    if args.window <= 0 or args.rate <= 0 or args.arw < 0 or args.vrw < 0:
        raise RecalInputError("--window and --rate must be positive, --arw and --vrw non-negative")
    truth = load_coefficients(args.truth, catalogue) if args.truth else CoefficientSet.seed_truth()
    base = CoefficientSet.seed_truth()
    for name, v in base.values.items():  # a partial truth file keeps the defaults elsewhere
        truth.values.setdefault(name, v)
    sensors = ("gyro", "accel") if args.sensor == "both" else (args.sensor,)
    positions = simulate_positions(
        truth,
        args.design,
        args.positions,
        args.latitude,
        args.height,
        args.seed,
        sensors,
        NoiseSpec(args.arw, args.vrw, args.window, rate_hz=args.rate),
        TemperatureSpec(args.temp_start, args.temp_slope),
        hidden,
    )
    atomic_write(args.output, positions.to_csv_text())
    if args.truth_out:
        used = truth.copy()
        for t in hidden:
            used.values.setdefault(t.name, list(t.typical))
        atomic_write(args.truth_out, json.dumps(used.to_json_dict(catalogue), indent=2) + "\n")
    print(
        f"recal simulate: wrote {len(positions)} positions ({args.design} design, "
        f"seed {args.seed}) to {args.output}",
        file=sys.stderr,
    )
    return 0
