"""``recal positions ... --nmea LOG``: the ship's sensors from a log, joined to the windows.

The log holds the sentences the daemon reads from ``[nav] url`` (docs/service.md, `[nav]`), lines
as received. An NMEA line carries no time of the IMU's clock, so the log's first sentence is
taken at the recording's first frame; when both carry UTC (the recording's given by
``--utc-start``, the log's by an RMC date and time) they are aligned by it instead. Each window
gets the ship's mean latitude, speed over ground and true heading (``latitude_deg``, ``sog_kn``,
``heading_deg``); the underway rule (:mod:`recal.detect.underway`, as the daemon's) rejects the
windows taken under way and grows the others' gyro sigma by the transport rate of their net
displacement.

Only argparse is imported to add the options; the log is read by :mod:`drivers.nmea`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

#: recal.detect.underway.DEFAULT_MAX_SOG_KN, repeated so that building the parser imports no
#: numpy (tests/test_cli_positions_nmea.py checks they match).
MAX_SOG_KN = 1.0


def add_ship_options(p: argparse.ArgumentParser) -> None:
    s = p.add_argument_group("the ship's sensors (NMEA 0183; docs/service.md)")
    s.add_argument(
        "--nmea",
        metavar="LOG",
        help="the ship's GNSS and heading sentences (GGA, RMC, VTG, HDT, THS; any talker) logged "
        "beside the recording: each window gets latitude_deg, sog_kn and heading_deg, a window "
        "whose mean speed over ground exceeds --max-sog is rejected as underway, and the others' "
        "gyro sigma carries the transport rate of their net displacement. The log's first "
        "sentence is taken at the recording's start, unless --utc-start dates the recording",
    )
    s.add_argument(
        "--utc-start",
        metavar="ISO8601",
        help="--nmea: the UTC of the recording's first frame (e.g. 2026-03-01T12:00:00Z): the "
        "log is then aligned by the UTC its sentences carry (it needs an RMC for the date)",
    )
    s.add_argument(
        "--max-sog",
        type=float,
        metavar="KN",
        help=f"--nmea: largest mean speed over ground of a window, kn (default {MAX_SOG_KN:g}: "
        "above it the transport rate, 0.017 deg/h per knot times up to 1 + |tan lat|, is no "
        "longer small beside a window's noise)",
    )


def read_ship_log(args: argparse.Namespace) -> Any:
    """The log of ``--nmea`` (drivers.nmea.NmeaLog) and its offset: log time = window time -
    offset; None without ``--nmea``. Bad input is a one-line input error, before anything is
    read or written."""
    from recal.errors import RecalInputError

    path = getattr(args, "nmea", None)
    if path is None:
        for flag in ("utc_start", "max_sog"):
            if getattr(args, flag, None) is not None:
                raise RecalInputError(f"--{flag.replace('_', '-')} needs --nmea LOG")
        return None
    max_sog = MAX_SOG_KN if args.max_sog is None else float(args.max_sog)
    if not max_sog >= 0:
        raise RecalInputError(f"--max-sog {args.max_sog}: must be a speed >= 0 (kn)")
    log_path = Path(path)
    if not log_path.is_file():
        raise RecalInputError(f"NMEA log {path} does not exist")
    from drivers.nmea import read_log

    log = read_log(log_path.read_bytes(), source=str(path))  # DriverInputError: exit 2
    offset, by_utc = 0.0, args.utc_start is not None
    if by_utc:
        start = _utc(args.utc_start)
        if log.utc_start is None:
            raise RecalInputError(
                f"--utc-start: NMEA log {path} carries no date (no RMC sentence): it cannot be "
                "aligned by UTC; leave --utc-start out to take its first sentence at the "
                "recording's start"
            )
        offset = (log.utc_start - start).total_seconds()
    return ShipLog(log, offset, max_sog, str(path), by_utc)


class ShipLog:
    """A read ``--nmea`` log: the track, the offset (log time = window time - offset), the
    threshold, and what the join found."""

    def __init__(
        self, log: Any, offset_s: float, max_sog_kn: float, path: str, by_utc: bool = False
    ) -> None:
        self.log, self.offset_s, self.max_sog_kn, self.path = log, offset_s, max_sog_kn, path
        self.by_utc = by_utc
        self.covered = 0
        self.rejected = 0
        self.inflated = True

    def judge(self, windows: list, report: Any, gyro_units_per_dph: Any) -> tuple[list, Any]:
        """The windows the underway rule keeps, and what :meth:`columns` needs for them; the
        rejected ones are counted in ``report`` as its other reasons."""
        import numpy as np

        from recal.detect.underway import count_rejections, underway_rule

        track, off = self.log.track, self.offset_s
        ships = [track.window(w.start_s - off, w.end_s - off) for w in windows]
        rule = underway_rule(ships, self.max_sog_kn)
        count_rejections(report, windows, list(rule.reasons))
        keep = np.flatnonzero(rule.kept)
        self.rejected = rule.rejected
        ships = [ships[i] for i in keep]
        self.covered = sum(s is not None for s in ships)
        self.inflated = gyro_units_per_dph is not None
        scale = 0.0 if gyro_units_per_dph is None else gyro_units_per_dph
        return [windows[i] for i in keep], (ships, underway_rule(ships, self.max_sog_kn, scale))

    def heading_of(self, time_s: Any, first_time_s: float) -> Any:
        """The ship's true heading at frames of the recording (its ``time_s``; the first frame's
        ``first_time_s`` is the windows' zero), deg, NaN where the log has none near: the hull
        detector measures each window's heading creep from it (recal.detect.creep)."""
        import numpy as np

        from drivers.nmea import heading_at

        t = np.asarray(time_s, dtype=float) - first_time_s - self.offset_s
        return heading_at(self.log.track, t)

    @staticmethod
    def columns(columns: dict, joined: Any) -> dict:
        from recal.detect.underway import ship_columns

        ships, rule = joined
        return ship_columns(columns, ships, rule)

    def summary(self, kept: int) -> list[str]:
        lines = list(self.log.notes)
        where = (
            f"aligned by UTC: the log starts at {self.offset_s:+.1f} s of the recording"
            if self.by_utc
            else "its first sentence taken at the recording's start"
        )
        lines.append(
            f"ship's sensors: {self.path} ({self.log.duration_s:.0f} s, {where}): {self.covered} "
            f"of {kept} window(s) covered; underway: {self.rejected} window(s) rejected (mean "
            f"speed over ground above {self.max_sog_kn:g} kn)"
        )
        if kept and not self.covered:
            lines.append(
                "ship's sensors: warning: the log covers none of the windows (its times do not "
                "reach the recording's: check --utc-start, or that it was logged beside it)"
            )
        if not self.inflated and self.covered:
            lines.append(
                "ship's sensors: the gyro's output units are not known (give --prior): the "
                "transport rate is not added to the windows' gyro sigma"
            )
        return lines


def _utc(text: str):
    import datetime as dt

    from recal.errors import RecalInputError

    try:
        moment = dt.datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except ValueError:
        raise RecalInputError(
            f"--utc-start {text!r}: expected an ISO 8601 time, e.g. 2026-03-01T12:00:00Z"
        ) from None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=dt.UTC)
    return moment.astimezone(dt.UTC)


def print_lines(lines: list[str]) -> None:
    for line in lines:
        print(f"recal positions: {line}", file=sys.stderr)
