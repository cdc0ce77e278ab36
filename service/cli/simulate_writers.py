"""What ``recal simulate`` writes besides a positions CSV: a session sample by sample as a
device capture (:func:`write_capture`), CSV tables and recordings (:data:`RECORDING_COLUMNS`,
:func:`table_csv`), a vessel's schedule (:func:`schedule_csv`) and the ship's own sensors as
NMEA 0183 lines (:func:`nmea_start`, :func:`nmea_log`)."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from recal.model.coefficients import CoefficientSet
    from recal.model.positions import Positions
    from recal.model.terms import Term
    from recal.sim.simulate import NoiseSpec, TemperatureSpec


def write_capture(
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


def nmea_start(args: argparse.Namespace):
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


def nmea_log(spec, args: argparse.Namespace, utc_start) -> bytes:
    """The ship's sensors over the recording as NMEA 0183 lines at --nmea-rate
    (service.capture_sim.ship_nmea)."""
    from service.capture_sim import ship_nmea

    return ship_nmea(spec, args.latitude, args.longitude, args.height, args.seed,
                     args.nmea_rate, utc_start)  # fmt: skip


def schedule_csv(spec) -> str:
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


def table_csv(table, names: tuple[str, ...], fmt: str) -> str:
    import io

    import numpy as np

    buf = io.StringIO()
    np.savetxt(buf, table, fmt=fmt, delimiter=",", header=",".join(names), comments="")
    return buf.getvalue()
