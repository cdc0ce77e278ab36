"""``recal navigate``: free-inertial navigation of a recording with one or more coefficient sets.

The recording is streamed (:func:`service.cli.recording.open_recording`) and averaged down to
``--nav-rate`` (default 10 Hz, :class:`recal.nav.navigation.Decimator`), corrected with each
``--coefficients`` set, aligned on its first ``--align`` seconds (levelling + gyrocompassing,
:mod:`recal.nav.alignment`) unless ``--attitude`` gives the initial attitude, and navigated
(:func:`recal.nav.navigation.navigate`, all sets in one loop). The error is against the start
position (a static recording) or against ``--truth TRUTH.csv`` (columns time_s, latitude_deg,
longitude_deg on the recording's clock, as ``recal simulate --trajectory voyage`` writes).

Only argparse is imported to build the parser; numpy, recal and drivers are imported by run().
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

DEFAULT_ALIGN_S = 300.0
DEFAULT_NAV_RATE_HZ = 10.0  # recal.nav.navigation.DEFAULT_RATE_HZ (no numpy to build the parser)
DEFAULT_STEP_S = 1.0
_PROGRESS_MIN_BYTES = 16 << 20
_CURVE_POINTS = 1500  # error-curve points kept in the JSON output


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "navigate",
        help="navigate a recording free-inertially with coefficient sets; report position error",
        description="Free-inertial strapdown navigation (WGS-84, Earth rate, transport rate, "
        "height held) of a recording corrected with each coefficient set. Aligns on the first "
        "--align seconds (the recording must start at rest) unless --attitude is given. "
        "Reports the horizontal position error against the start position (static recording) "
        "or --truth, per coefficient set, best first.",
    )
    p.add_argument("inputs", nargs="+", metavar="RECORDING", help="as for `recal positions`")
    from drivers.registry import input_format_names

    p.add_argument("--format", required=True, choices=input_format_names(), help="input format")
    p.add_argument(
        "--rate", type=float, metavar="HZ", help="sample rate (as for `recal positions`)"
    )
    p.add_argument("--columns", metavar="NEW=OLD,...", help="csv: the file's own column names")
    p.add_argument(
        "--coefficients",
        action="append",
        required=True,
        metavar="COEFFS.json",
        help="coefficient set (docs/reference.md#coefficients); repeat to compare several",
    )
    p.add_argument("--latitude", type=float, required=True, help="start latitude, deg")
    p.add_argument("--longitude", type=float, default=0.0, help="start longitude, deg")
    p.add_argument("--height", type=float, default=0.0, help="height (held), m")
    p.add_argument(
        "--attitude",
        metavar="R,P,Y",
        help="initial roll,pitch,yaw in deg (body in NED, yaw-pitch-roll order): skip alignment",
    )
    p.add_argument(
        "--align",
        type=float,
        default=DEFAULT_ALIGN_S,
        metavar="S",
        help="alignment period at the start, s (default %(default)g); navigation starts after it",
    )
    p.add_argument("--duration", type=float, metavar="S", help="navigate at most S seconds")
    p.add_argument("--truth", metavar="TRUTH.csv", help="true trajectory to compare against")
    p.add_argument(
        "--nav-rate",
        type=float,
        default=DEFAULT_NAV_RATE_HZ,
        metavar="HZ",
        help="average the recording down to this rate first (default %(default)g)",
    )
    p.add_argument(
        "--step",
        type=float,
        default=DEFAULT_STEP_S,
        metavar="S",
        help="slow-loop step of the mechanization, s (default %(default)g)",
    )
    p.add_argument("--report", metavar="OUT.html", help="write an HTML report with error curves")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    from service.cli.positions import add_kvh_unit_options

    add_kvh_unit_options(p)
    p.set_defaults(func=run)
    return p


def _check_args(args: argparse.Namespace) -> tuple[float, float, float] | None:
    from recal.errors import RecalInputError
    from recal.nav.alignment import parse_attitude

    if not -90.0 <= args.latitude <= 90.0:
        raise RecalInputError(f"--latitude {args.latitude} is outside [-90, 90] deg")
    if not (math.isfinite(args.longitude) and math.isfinite(args.height)):
        raise RecalInputError("--longitude and --height must be finite numbers")
    for name in ("align", "nav_rate", "step"):
        value = getattr(args, name)
        if not (math.isfinite(value) and value > 0):
            raise RecalInputError(f"--{name.replace('_', '-')} must be a positive number")
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise RecalInputError("--duration must be a positive number of seconds")
    return None if args.attitude is None else parse_attitude(args.attitude)


def _read(args: argparse.Namespace, recording: Any) -> Any:
    """Stream the recording through a decimator; the input rate from the format or the data."""
    import numpy as np

    from recal.errors import RecalInputError
    from recal.nav.navigation import Decimator, decimation_factor
    from service.cli.common import progress_bar

    if set(recording.triads) != {"gyro", "accel"}:
        raise RecalInputError("navigation needs both gyro and accel columns")
    bar = None
    if recording.total_bytes >= _PROGRESS_MIN_BYTES:
        bar = progress_bar(recording.total_bytes, "reading", unit="B")
    decimator = None
    try:
        for frames in recording.frames(bar.update if bar else None):
            if decimator is None:
                rate = args.rate or getattr(getattr(recording, "config", None), "rate_hz", None)
                if rate is None:
                    t = np.asarray(frames["time_s"], float)
                    step = float(np.median(np.diff(t[:1025]))) if t.size > 1 else float("nan")
                    if not (math.isfinite(step) and step > 0):
                        raise RecalInputError("cannot tell the sample rate: give --rate HZ")
                    rate = 1.0 / step
                    if abs(rate - round(rate)) < 1e-6 * rate:  # time stamps printed to 1e-9 s
                        rate = float(round(rate))
                decimator = Decimator(rate, decimation_factor(rate, args.nav_rate))
            decimator.feed(**frames)
    finally:
        if bar is not None:
            bar.close()
    if decimator is None:
        raise RecalInputError("the recording has no frames")
    return decimator.result(), decimator.input_rate_hz


def _read_truth(path: str) -> dict[str, Any]:
    import io

    import numpy as np

    from recal.errors import RecalInputError
    from service.cli.common import read_text

    text = read_text(path, "truth file")
    try:
        table = np.genfromtxt(io.StringIO(text), delimiter=",", names=True, dtype=float)
    except ValueError as exc:
        raise RecalInputError(f"{path}: not a CSV table ({exc})") from None
    names = table.dtype.names or ()
    need = ("time_s", "latitude_deg", "longitude_deg")
    missing = [n for n in need if n not in names]
    if missing:
        raise RecalInputError(f"{path}: missing column(s) {', '.join(missing)}")
    table = np.atleast_1d(table)
    cols = {n: np.asarray(table[n], float) for n in names}
    if cols["time_s"].size < 2 or not np.all(np.diff(cols["time_s"]) > 0):
        raise RecalInputError(f"{path}: time_s must have 2+ rows and increase")
    if not all(np.all(np.isfinite(cols[n])) for n in need):
        raise RecalInputError(f"{path}: {', '.join(need)} must be finite numbers")
    return cols


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from recal.errors import RecalInputError
    from recal.model.terms import catalogue_terms
    from recal.nav.alignment import align_static
    from recal.nav.ins_static import schuler_amplitude_m
    from recal.nav.navigation import (
        NMI_M,
        attitude_matrix,
        correct_outputs,
        euler_angles,
        navigate,
        schuler_period_s,
    )
    from service.cli.common import atomic_write, load_coefficients, print_json, progress_bar
    from service.cli.recording import open_recording

    attitude = _check_args(args)
    sets = [load_coefficients(path, catalogue_terms()) for path in args.coefficients]
    truth = _read_truth(args.truth) if args.truth else None
    data, input_rate = _read(args, open_recording(args))
    rate = data.rate_hz
    omega, force = correct_outputs(sets, data)
    notes = [
        f"{input_rate:g} Hz averaged to {rate:g} Hz ({len(data)} rows); mechanization step "
        f"{args.step:g} s; height held at {args.height:g} m"
    ]
    if attitude is not None:
        start = 0
        C0 = attitude_matrix(*np.radians(attitude))
        C0 = np.broadcast_to(C0, (len(sets), 3, 3))
        alignment = None
    else:
        start = round(args.align * rate)
        if len(data) <= start + 1:
            raise RecalInputError(
                f"the recording ({len(data) / rate:.1f} s) is not longer than the alignment "
                f"period (--align {args.align:g} s)"
            )
        al = align_static(force[:, :start], omega[:, :start], args.latitude, args.height)
        C0 = al.C_bn
        alignment = {
            "period_s": start / rate,
            "attitude_deg": np.degrees(al.rpy_rad).tolist(),
            "heading_sigma_deg": np.degrees(al.heading_sigma_rad).tolist(),
        }
    stop = (
        len(data) if args.duration is None else min(len(data), start + round(args.duration * rate))
    )
    t_start = float(data.time_s[start])
    lat0, lon0, v0 = args.latitude, args.longitude, np.zeros(3)
    if truth is not None:
        tt = truth["time_s"]
        if not tt[0] <= t_start <= tt[-1]:
            raise RecalInputError(
                f"{args.truth}: does not cover the navigation start {t_start:g} s"
            )
        lat0 = float(np.interp(t_start, tt, truth["latitude_deg"]))
        lon0 = float(np.interp(t_start, tt, truth["longitude_deg"]))
        for i, col in enumerate(("v_north_m_s", "v_east_m_s")):
            if col in truth:
                v0[i] = np.interp(t_start, tt, truth[col])
    steps = (stop - start) // max(1, round(args.step * rate))
    if steps < 1:
        raise RecalInputError("nothing left to navigate after the alignment period")
    bar = progress_bar(steps, "navigating", unit="step") if steps > 3600 else None
    try:
        nav = navigate(
            omega[:, start:stop], force[:, start:stop], 1.0 / rate, lat0, lon0, args.height, C0, v0,
            args.step, bar.update if bar else None,
        )  # fmt: skip
    finally:
        if bar is not None:
            bar.close()
    if truth is None:
        north, east = nav.north_east_error_m(math.radians(lat0), math.radians(lon0))
        against = "the start position (static recording)"
    else:
        t_abs = t_start + nav.time_s
        covered = t_abs <= truth["time_s"][-1]
        lat_ref = np.radians(np.interp(t_abs, truth["time_s"], truth["latitude_deg"]))
        lon_ref = np.radians(np.interp(t_abs, truth["time_s"], truth["longitude_deg"]))
        north, east = nav.north_east_error_m(lat_ref, lon_ref)
        north, east = north[:, covered], east[:, covered]
        against = f"the truth {args.truth}"
    t = nav.time_s[: north.shape[1]]
    horizontal = np.hypot(north, east)
    rpy0 = np.degrees(euler_angles(C0))
    runs = []
    every = max(1, t.size // _CURVE_POINTS)
    for i, cs in enumerate(sets):
        runs.append(
            {
                "coefficients": str(cs.metadata.get("source", args.coefficients[i])),
                "final_error_m": float(horizontal[i, -1]),
                "max_error_m": float(horizontal[i].max()),
                "time_s": float(t[-1]),
                "north_error_m": float(north[i, -1]),
                "east_error_m": float(east[i, -1]),
                "final_error_nmi": float(horizontal[i, -1] / NMI_M),
                "max_error_nmi": float(horizontal[i].max() / NMI_M),
                "max_north_error_m": float(np.abs(north[i]).max()),
                "max_east_error_m": float(np.abs(east[i]).max()),
                "schuler_amplitude_m": _finite_or_none(
                    schuler_amplitude_m(t, horizontal[i], lat0, args.height)
                ),
                "initial_attitude_deg": rpy0[i].tolist(),
                "curve": {
                    "time_s": t[::every].tolist(),
                    "north_m": north[i, ::every].tolist(),
                    "east_m": east[i, ::every].tolist(),
                },
            }
        )
    order = sorted(range(len(runs)), key=lambda i: runs[i]["final_error_m"])
    out = {
        "runs": [runs[i] for i in order],
        "against": "truth" if truth is not None else "start position",
        "start_time_s": t_start,
        "latitude_deg": lat0,
        "longitude_deg": lon0,
        "height_m": args.height,
        "alignment": alignment,
        "input_rate_hz": input_rate,
        "nav_rate_hz": rate,
        "schuler_period_min": schuler_period_s(lat0, args.height) / 60.0,
        "earth_period_h": 23.934,
        "foucault_period_h": 23.934 / abs(math.sin(math.radians(lat0)))
        if abs(lat0) > 0.01
        else None,
        "notes": notes,
    }
    if args.report:
        from recal.report.navigation import navigation_html

        curves = [(runs[i]["coefficients"], t, north[i], east[i]) for i in order]
        page = navigation_html(
            out["runs"], curves, f"recal navigate {args.inputs[0]}", notes, against=against
        )
        atomic_write(args.report, page)
        out["report"] = args.report
        print(args.report, file=sys.stderr if args.json else sys.stdout)
    if args.json:
        print_json(out)
    else:
        _print_text(out)
    return 0


def _finite_or_none(x: float) -> float | None:
    return x if math.isfinite(x) else None


def _print_text(out: dict[str, Any]) -> None:
    lines = [
        f"navigated {out['runs'][0]['time_s'] / 3600:.2f} h against {out['against']} "
        f"(Schuler period {out['schuler_period_min']:.1f} min)"
    ]
    for r in out["runs"]:
        lines.append(
            f"  {r['coefficients']}: final {r['final_error_m']:.1f} m ({r['final_error_nmi']:.3f} "
            f"nmi; north {r['north_error_m']:.1f} m, east {r['east_error_m']:.1f} m), max "
            f"{r['max_error_m']:.1f} m ({r['max_error_nmi']:.3f} nmi)"
        )
    sys.stdout.write("\n".join(lines) + "\n")
