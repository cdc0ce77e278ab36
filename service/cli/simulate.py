"""``recal simulate``: write a positions CSV, or a byte-level capture, of a simulated session.

Without ``--capture`` the window means are drawn directly (:mod:`recal.sim.simulate`). With
``--capture OUT.bin`` every sample is simulated (:mod:`recal.sim.session`: holds joined by slews) and
written as the frames a KVH sends (:mod:`service.capture_sim`), optionally damaged; ``-o`` then
writes the true window means of the same session's holds. ``--berth`` and ``--indexing`` simulate
a hull-fixed unit on a vessel sample by sample (:mod:`recal.sim.vessel`), streamed to a CSV
recording and/or a KVH capture chunk by chunk, so a week needs no more memory than ten minutes.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from recal.model.coefficients import CoefficientSet
    from recal.model.positions import Positions
    from recal.model.terms import Term
    from recal.sim.simulate import NoiseSpec, TemperatureSpec

#: recal.sim.simulate.DESIGNS and the NoiseSpec / TemperatureSpec defaults, repeated here so that
#: building the parser imports no numpy (a test checks they match).
DESIGNS = ("24", "random", "vessel")
DEFAULT_ARW_DEG_RT_H = 0.0005
DEFAULT_VRW_UG_RT_HZ = 20.0
DEFAULT_WINDOW_S = 100.0
DEFAULT_SLEW_S = 30.0
DEFAULT_RATE_HZ = 1000.0
DEFAULT_TEMP_START_C = 20.0
DEFAULT_TEMP_SLOPE_C_PER_H = 2.0

#: Hold and slew lengths of a capture when not given: a sample-level session is held in memory,
#: so shorter than the window-mean defaults (100 s windows, 30 s between them).
CAPTURE_WINDOW_S = 20.0
CAPTURE_SLEW_S = 5.0
#: Sample rate of a simulated trajectory when not given: hours of samples are held in memory.
TRAJECTORY_RATE_HZ = 100.0
TRAJECTORIES = ("voyage", "static")

#: recal.sim.vessel defaults (VesselSpec.berth, VesselSpec.indexing, SeaState), repeated here so
#: that building the parser imports no numpy (tests/test_cli_simulate_vessel.py checks they match):
#: the issue-25 scenario, 12 holds of 10 min joined by 30-degree turns of 60 s in a 0.3-degree sea,
#: sampled by a KVH 1750-class FOG at 100 Hz.
VESSEL_HOLDS = 12
VESSEL_HOLD_S = 600.0
VESSEL_TURN_DEG = 30.0
VESSEL_TURN_S = 60.0
VESSEL_INDEX_S = 20.0
VESSEL_ROLL_DEG = 0.3
VESSEL_ROLL_PERIOD_S = 8.0
VESSEL_PITCH_PERIOD_S = 6.0
VESSEL_YAW_SWING_DEG = 0.1
VESSEL_YAW_PERIOD_S = 180.0
VESSEL_HEAVE_PERIOD_S = 8.0
VESSEL_ARW_DEG_RT_H = 0.012
#: A transit's speed (VesselSpec.berth's transit_kn), and the UTC of the ship's first NMEA
#: sentence when not given.
VESSEL_TRANSIT_KN = 12.0
VESSEL_UTC_START = "2026-03-01T00:00:00Z"
#: Seconds of samples simulated and written at a time.
VESSEL_CHUNK_S = 600.0


def _capture_formats() -> list[str]:
    from drivers.registry import kvh_format_names  # light: no numpy

    return kvh_format_names()


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
    p.add_argument(
        "--design",
        choices=DESIGNS,
        default="24",
        help="24: seed 002 section 7.1 turntable scheme; random: random orientations; "
        "vessel: hull-fixed, heading-only (default 24)",
    )
    p.add_argument(
        "--positions",
        type=int,
        default=None,
        metavar="N",
        help="number of positions: random and vessel designs (default 24); the 24 design has 24",
    )
    p.add_argument(
        "--truth", metavar="FILE", help="truth coefficients JSON (docs/reference.md#coefficients)"
    )
    p.add_argument(
        "--hidden",
        metavar="EFFECT[,EFFECT]",
        help="catalogue effects present in the data but not in the seed model",
    )
    p.add_argument(
        "--sensor",
        choices=("gyro", "accel", "both"),
        default="both",
        help="triads whose columns are written (default both)",
    )
    p.add_argument("--latitude", type=float, default=45.0, help="site latitude, deg (default 45)")
    p.add_argument(
        "--height", type=float, default=0.0, help="site height above the ellipsoid, m (default 0)"
    )
    p.add_argument(
        "--seed",
        type=int,
        default=0,
        help="random seed of the orientations and the noise; the same seed gives the same file "
        "(default 0)",
    )
    p.add_argument(
        "--arw",
        type=float,
        default=None,
        help=f"gyro angle random walk, deg/sqrt(h) (default {DEFAULT_ARW_DEG_RT_H:g}; "
        f"{VESSEL_ARW_DEG_RT_H:g}, a KVH 1750-class FOG, with --berth or --indexing)",
    )
    p.add_argument(
        "--vrw",
        type=float,
        default=DEFAULT_VRW_UG_RT_HZ,
        help="accel noise density, micro-g/sqrt(Hz) (default %(default)s)",
    )
    p.add_argument(
        "--window",
        type=float,
        default=None,
        help=f"static window length, s (default {DEFAULT_WINDOW_S:g}; "
        f"{CAPTURE_WINDOW_S:g} with --capture)",
    )
    p.add_argument(
        "--slew",
        type=float,
        default=None,
        help=f"time between windows (the slew), s (default {DEFAULT_SLEW_S:g}; "
        f"{CAPTURE_SLEW_S:g} with --capture)",
    )
    p.add_argument(
        "--rate",
        type=float,
        default=None,
        help=f"sample rate, Hz; with --capture the device's data rate (default "
        f"{DEFAULT_RATE_HZ:g}; {TRAJECTORY_RATE_HZ:g} with --trajectory, --berth or --indexing)",
    )
    p.add_argument(
        "--temp-start",
        type=float,
        default=DEFAULT_TEMP_START_C,
        help=f"temperature at the start of the session, degC; --berth and --indexing keep it "
        f"constant (default {DEFAULT_TEMP_START_C:g})",
    )
    p.add_argument(
        "--temp-slope",
        type=float,
        default=DEFAULT_TEMP_SLOPE_C_PER_H,
        help="temperature ramp, degC/h (default %(default)s)",
    )
    p.add_argument(
        "--temp-swing",
        type=float,
        default=0.0,
        help="amplitude of a sinusoidal temperature swing, degC (default 0): separates "
        "temperature effects from drift in time",
    )
    p.add_argument(
        "--temp-period", type=float, default=1.0, help="period of the swing, h (default 1)"
    )
    p.add_argument("--truth-out", metavar="FILE", help="also write the truth used, as JSON")
    p.add_argument(
        "-o",
        "--output",
        metavar="POSITIONS.csv",
        help="positions CSV (with --capture: the true means over each static hold; with "
        "--berth or --indexing: the CSV recording, as --recording)",
    )
    c = p.add_argument_group("byte-level capture")
    c.add_argument(
        "--capture",
        metavar="OUT.bin",
        help="write the session sample by sample as a device capture (for `recal positions`)",
    )
    c.add_argument(
        "--capture-format",
        choices=_capture_formats(),
        default="kvh-a",
        help="frame format of the capture (default %(default)s)",
    )
    c.add_argument(
        "--first-hold",
        type=float,
        metavar="S",
        help="length of the first hold, s (default: the window); make it longer than the "
        "--init-still period `recal positions` learns its thresholds from",
    )
    c.add_argument(
        "--bit-flips", type=int, default=0, metavar="N", help="frames with one flipped bit"
    )
    c.add_argument(
        "--garbage", type=int, default=0, metavar="N", help="runs of random bytes inserted"
    )
    c.add_argument("--drop", type=int, default=0, metavar="N", help="frames dropped entirely")
    v = p.add_argument_group(
        "hull-fixed vessel, sample by sample (recal.sim.vessel; shared/spec/vessel.md)"
    )
    v.add_argument(
        "--berth",
        action="store_true",
        help="simulate a FOG bolted to a moored hull: --holds holds of --hold s joined by "
        "steady --turn-deg turns of --turn-s, in a sea of --roll, --pitch, --yaw-swing and "
        "--heave; written sample by sample as a CSV recording (-o or --recording, "
        "docs/reference.md#csv) and/or a KVH capture (--capture), streamed in chunks; the "
        "truth with --truth-out, the schedule with --track. Defaults: the issue-25 scenario "
        f"({VESSEL_HOLDS} holds of {VESSEL_HOLD_S / 60:g} min, {VESSEL_TURN_DEG:g}-degree turns "
        f"of {VESSEL_TURN_S:g} s, roll {VESSEL_ROLL_DEG:g} deg, ARW {VESSEL_ARW_DEG_RT_H:g} "
        f"deg/sqrt(h), {TRAJECTORY_RATE_HZ:g} Hz). Read it with `recal positions ... --motion "
        "hull`. (--design vessel is the window-means version: positions only)",
    )
    v.add_argument(
        "--indexing",
        metavar="STOPS",
        help="instead of --berth: an IMU on an indexing (rotation-modulation) mechanism in a "
        "hull that keeps its heading, held at each stop for --hold s and turned between stops "
        "in --index-s s; STOPS are roll,pitch,yaw of the IMU in the hull in deg, separated by "
        "'/', e.g. 0,0,0/0,0,90/0,0,180/0,0,270 (whole-turn indexing about the vertical) or "
        "0,0,0/90,0,0/0,90,0 (tilted stops)",
    )
    v.add_argument(
        "--holds",
        type=int,
        default=VESSEL_HOLDS,
        metavar="N",
        help="--berth: number of holds (default %(default)s)",
    )
    v.add_argument(
        "--hold",
        type=float,
        default=VESSEL_HOLD_S,
        metavar="S",
        help="length of each hold (each stop with --indexing), s (default %(default)g)",
    )
    v.add_argument(
        "--turn-deg",
        type=float,
        default=VESSEL_TURN_DEG,
        metavar="DEG",
        help="--berth: heading change of each turn between holds, deg (default %(default)g)",
    )
    v.add_argument(
        "--turn-s",
        type=float,
        default=VESSEL_TURN_S,
        metavar="S",
        help="--berth: length of each turn, s; steady rate with 5 s ramps (default %(default)g)",
    )
    v.add_argument(
        "--index-s",
        type=float,
        default=VESSEL_INDEX_S,
        metavar="S",
        help="--indexing: time the mechanism takes between stops, s (default %(default)g)",
    )
    v.add_argument(
        "--roll",
        type=float,
        default=VESSEL_ROLL_DEG,
        metavar="DEG",
        help="peak roll of the hull, deg (default %(default)g; 0 with --pitch 0 --yaw-swing 0 "
        "is a still hull)",
    )
    v.add_argument(
        "--roll-period",
        type=float,
        default=VESSEL_ROLL_PERIOD_S,
        metavar="S",
        help="roll period, s (default %(default)g)",
    )
    v.add_argument(
        "--pitch",
        type=float,
        default=None,
        metavar="DEG",
        help="peak pitch of the hull, deg (default half the roll)",
    )
    v.add_argument(
        "--pitch-period",
        type=float,
        default=VESSEL_PITCH_PERIOD_S,
        metavar="S",
        help="pitch period, s (default %(default)g)",
    )
    v.add_argument(
        "--yaw-swing",
        type=float,
        default=VESSEL_YAW_SWING_DEG,
        metavar="DEG",
        help="peak slow heading swing at the berth, deg (default %(default)g)",
    )
    v.add_argument(
        "--yaw-period",
        type=float,
        default=VESSEL_YAW_PERIOD_S,
        metavar="S",
        help="period of the heading swing, s (default %(default)g)",
    )
    v.add_argument(
        "--heave",
        type=float,
        default=0.0,
        metavar="M",
        help="peak heave, m (default %(default)g)",
    )
    v.add_argument(
        "--heave-period",
        type=float,
        default=VESSEL_HEAVE_PERIOD_S,
        metavar="S",
        help="heave period, s (default %(default)g)",
    )
    v.add_argument(
        "--transit",
        type=float,
        default=0.0,
        metavar="S",
        help="--berth: after the first half of the holds the ship sails this long at "
        "--transit-kn on its heading (speed ramps of 60 s in and out included) to another berth, "
        "where it holds the rest; the gyro and accelerometer see the transport rate, Earth's "
        "rate at the latitude reached, and the Coriolis and Eotvos accelerations (default 0: "
        "no transit)",
    )
    v.add_argument(
        "--transit-kn",
        type=float,
        default=VESSEL_TRANSIT_KN,
        metavar="KN",
        help="--transit: speed over ground, kn (default %(default)g)",
    )
    v.add_argument(
        "--nmea",
        metavar="OUT.nmea",
        help="also write the ship's own sensors as NMEA 0183 lines (GGA, RMC, VTG from a GNSS, "
        "HDT from a gyrocompass; docs/service.md) at --nmea-rate, from the simulated "
        "position, speed, course and heading; its first sentence is the recording's first "
        "sample (read it with recal positions ... --nmea OUT.nmea)",
    )
    v.add_argument(
        "--nmea-rate",
        type=float,
        default=1.0,
        metavar="HZ",
        help="--nmea: fixes per second, 0.1 to 10 (default %(default)g)",
    )
    v.add_argument(
        "--utc-start",
        metavar="ISO8601",
        default=VESSEL_UTC_START,
        help="--nmea: the UTC of the first sample (the sentences' time and date; default "
        "%(default)s)",
    )
    v.add_argument(
        "--lever-arm",
        metavar="X,Y,Z",
        default="0,0,0",
        help="the IMU's position from the hull's centre of rotation, forward,right,down in m "
        "(default 0,0,0); e.g. 0,0,-5 is 5 m above it",
    )
    t = p.add_argument_group("navigation recording (recal navigate)")
    t.add_argument(
        "--trajectory",
        choices=TRAJECTORIES,
        help="simulate a vessel instead of a calibration session: 'voyage' moors still for "
        "--moor s (to align), then sails legs with speed and heading changes and wave roll; "
        "'static' stays at rest for --duration s. Written with --capture (KVH) or --recording "
        "(csv, docs/reference.md#csv); --track writes the true trajectory",
    )
    t.add_argument(
        "--recording",
        metavar="OUT.csv",
        help="write the samples as a CSV recording (also with --berth or --indexing)",
    )
    t.add_argument(
        "--track",
        metavar="TRUTH.csv",
        help="write the true trajectory (for --truth); with --berth or --indexing the schedule, "
        "one row per segment (hold, turn, index) with its start and end time and heading",
    )
    t.add_argument("--moor", type=float, default=900.0, metavar="S", help="voyage: still start, s")
    t.add_argument("--duration", type=float, default=3600.0, metavar="S", help="static: length, s")
    t.add_argument("--longitude", type=float, default=0.0, help="start longitude, deg")
    t.add_argument(
        "--attitude",
        metavar="R,P,Y",
        default="0,0,0",
        help="static: roll,pitch,yaw in NED, deg; voyage and --berth: the IMU's roll,pitch in "
        "the hull and the starting heading; --indexing: yaw is the hull's heading (default "
        "0,0,0)",
    )
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
        return _run_trajectory(args)
    if vessel:
        return _run_vessel(args)
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
        positions = _write_capture(args, truth, noise, temperature, hidden, sensors)
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


def _write_capture(
    args: argparse.Namespace,
    truth: CoefficientSet,
    noise: NoiseSpec,
    temperature: TemperatureSpec,
    hidden: list[Term],
    sensors: tuple[str, ...],
) -> Positions:
    """Simulate the session sample by sample, write the capture; return the true hold means."""
    import numpy as np

    from drivers import DecoderConfig
    from recal.errors import RecalInputError
    from recal.sim.session import session_positions, simulate_session
    from service.capture_sim import Damage, session_to_kvh
    from service.cli.common import atomic_write

    session = simulate_session(
        truth,
        args.design,
        args.positions,
        args.latitude,
        args.height,
        args.seed,
        rate_hz=args.rate,
        window_s=noise.window_s,
        slew_s=noise.slew_s,
        first_hold_s=args.first_hold,
        noise=noise,
        temperature=temperature,
        hidden=hidden,
    )
    damage = Damage(bit_flips=args.bit_flips, garbage=args.garbage, drops=args.drop)
    if damage.frames > len(session) - 1:
        raise RecalInputError(
            f"--bit-flips, --garbage and --drop touch {damage.frames} frames; "
            f"the session has only {len(session)}"
        )
    # The damage draws from its own stream, so adding damage leaves the session unchanged.
    data, info = session_to_kvh(
        session,
        args.capture_format,
        DecoderConfig(rate_hz=args.rate),
        damage,
        np.random.default_rng((args.seed, 1)),
    )
    atomic_write(args.capture, data)
    rate_flag = "" if args.rate == 1000 else f" --rate {args.rate:g}"  # the decoder's default
    print(
        f"recal simulate: wrote {info.frames - info.dropped.shape[0]} {info.format} frames "
        f"({info.bytes} bytes, {session.n_holds} static holds, {len(session) / args.rate:.1f} s "
        f"at {args.rate:g} Hz; damage: {info.bit_flips.shape[0]} bit flips, "
        f"{info.garbage.shape[0]} garbage runs, {info.dropped.shape[0]} frames dropped) to "
        f"{args.capture}; read it with `recal positions {args.capture} --format "
        f"{info.format}{rate_flag} -o POSITIONS.csv`",
        file=sys.stderr,
    )
    return session_positions(session, sensors)


def _run_trajectory(args: argparse.Namespace) -> int:
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
        atomic_write(args.recording, _csv(table, RECORDING_COLUMNS, "%.10g"))
    if args.track:
        cols = voyage.truth_columns()
        every = max(1, round(args.rate / 10.0))  # 10 Hz is plenty for interpolation
        table = np.column_stack([c[::every] for c in cols.values()])
        atomic_write(args.track, _csv(table, tuple(cols), "%.12g"))
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


def _run_vessel(args: argparse.Namespace) -> int:
    """``--berth`` / ``--indexing``: a hull-fixed unit sample by sample, streamed to disk."""
    import numpy as np

    from recal.errors import RecalInputError
    from recal.model.terms import catalogue_terms
    from recal.nav.alignment import parse_attitude
    from recal.sim.simulate import NoiseSpec
    from recal.sim.vessel import SeaState, VesselSpec, vessel_chunks
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
    lever = _triple(args.lever_arm, "--lever-arm")
    utc_start = _nmea_start(args) if args.nmea else None
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
        stops = [_triple(stop, "--indexing stop") for stop in args.indexing.split("/")]
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
        atomic_write(args.track, _schedule_csv(spec))
    if args.truth_out:
        atomic_write(args.truth_out, json.dumps(truth.to_json_dict(catalogue), indent=2) + "\n")
    if args.nmea:
        atomic_write(args.nmea, _nmea_log(spec, args, utc_start))
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


def _triple(text: str, flag: str) -> tuple[float, float, float]:
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


def _nmea_start(args: argparse.Namespace):
    """``--utc-start`` as a UTC datetime; ``--nmea-rate`` checked."""
    import datetime as dt
    import math

    from recal.errors import RecalInputError

    if not (math.isfinite(args.nmea_rate) and 0.1 <= args.nmea_rate <= 10.0):
        raise RecalInputError(f"--nmea-rate {args.nmea_rate}: a talker sends 0.1 to 10 fixes/s")
    try:
        start = dt.datetime.fromisoformat(args.utc_start.strip().replace("Z", "+00:00"))
    except ValueError:
        raise RecalInputError(
            f"--utc-start {args.utc_start!r}: expected an ISO 8601 time, e.g. 2026-03-01T12:00:00Z"
        ) from None
    return (start if start.tzinfo else start.replace(tzinfo=dt.UTC)).astimezone(dt.UTC)


def _nmea_log(spec, args: argparse.Namespace, utc_start) -> bytes:
    """The ship's sensors over the recording as NMEA 0183 lines at --nmea-rate
    (service.capture_sim.ship_nmea)."""
    from service.capture_sim import ship_nmea

    return ship_nmea(spec, args.latitude, args.longitude, args.height, args.seed,
                     args.nmea_rate, utc_start)  # fmt: skip


def _schedule_csv(spec) -> str:
    """One row per segment of a vessel schedule: what it is, when, the heading it turns to and
    a transit's speed."""
    rows = ["segment,kind,start_s,end_s,heading_start_deg,heading_end_deg,mount_roll_deg,"
            "mount_pitch_deg,mount_yaw_deg,speed_kn"]  # fmt: skip
    t, heading, mount = 0.0, spec.heading0_deg, spec.mount_rpy_deg
    for k, seg in enumerate(spec.segments):
        end = heading + (seg.heading_change_deg if seg.kind == "turn" else 0.0)
        if seg.kind == "index" and seg.mount_rpy_deg is not None:
            mount = seg.mount_rpy_deg
        rows.append(f"{k},{seg.kind},{t:.6g},{t + seg.duration_s:.6g},{heading:.6g},{end:.6g},"
                    + ",".join(f"{m:g}" for m in mount) + f",{seg.speed_kn:g}")  # fmt: skip
        t += seg.duration_s
        heading = end
    return "\n".join(rows) + "\n"


RECORDING_COLUMNS = (
    "time_s", "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z", "temperature_c",
)  # fmt: skip


def _csv(table, names: tuple[str, ...], fmt: str) -> str:
    import io

    import numpy as np

    buf = io.StringIO()
    np.savetxt(buf, table, fmt=fmt, delimiter=",", header=",".join(names), comments="")
    return buf.getvalue()
