"""``recal simulate``'s options: the defaults the parser shows (repeated from recal.sim so that
building the parser imports no numpy) and the arguments of each kind of simulation (window
means, a byte-level capture, a vessel at its berth or indexing, a navigation recording)."""

from __future__ import annotations

import argparse

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


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``recal simulate``, in the order ``--help`` gives them."""
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
