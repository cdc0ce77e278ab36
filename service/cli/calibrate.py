"""``recal calibrate``: coefficients, status, uncertainty and observability from positions.

Only argparse is imported to build the parser: numpy, the engine and scipy are imported when
the command runs, so ``recal --help`` and the other subcommands start fast.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from recal.solve.options import CalibrationOptions
    from recal.solve.result import CalibrationResult

#: recal.solve.calibrate.METHODS, repeated here to keep parser construction light (a test checks it)
METHODS = ("lm", "nafsa", "safsa", "oafsa")


def add_site_options(p: argparse.ArgumentParser) -> None:
    """--latitude (default 45 with a warning) and --height: where the unit was, for gravity and
    Earth rate."""
    p.add_argument(
        "--latitude",
        type=float,
        default=None,
        help="site latitude, deg (default 45 with a warning)",
    )
    p.add_argument("--height", type=float, default=0.0, help="site height, m (default 0)")


def add_calibration_arguments(p: argparse.ArgumentParser) -> None:
    """Options shared by calibrate and diagnose (docs/reference.md#cli)."""
    p.add_argument("positions", metavar="POSITIONS.csv")
    p.add_argument(
        "--sensor",
        choices=("gyro", "accel", "both"),
        default=None,
        help="triad(s) to calibrate (default: every triad in the file)",
    )
    p.add_argument(
        "--method",
        choices=METHODS,
        default="lm",
        help="lm (default), or a swarm repeated --mc times: nafsa, safsa, oafsa",
    )
    p.add_argument("--mc", type=int, default=100, help="Monte Carlo runs for swarms (default 100)")
    p.add_argument("--seed", type=int, default=0, help="random seed for swarms (default 0)")
    add_site_options(p)
    p.add_argument(
        "--prior",
        metavar="COEFFS.json",
        help="previous calibration: the start, and the value of held coefficients",
    )
    p.add_argument(
        "--fleet-prior",
        metavar="FLEET.json",
        help="fleet prior of the unit's model (recal.fleet_prior/N): held coefficients carry "
        "its change over --prior-age-months besides the prior's own 1-sigma",
    )
    p.add_argument(
        "--prior-age-months",
        type=float,
        metavar="M",
        help="months of service since the --prior calibration (with --fleet-prior)",
    )
    p.add_argument("--effects", metavar="+NAME,...", help="extra catalogue or plugin effects")
    p.add_argument(
        "--plugin",
        metavar="FILE.py",
        action="append",
        default=[],
        help="Python file defining TERMS = [...] (recal.model.terms.Term subclasses)",
    )
    p.add_argument(
        "--paper",
        action="store_true",
        help="swarms exactly as the seed papers (category phases, literal CF, Table 1 "
        "Visual); reproduces their shortcomings",
    )
    p.add_argument("--polish", action="store_true", help="follow a swarm by LM")
    p.add_argument("--fish", type=int, default=None, help="swarm size (default 50)")
    p.add_argument(
        "--iterations",
        type=int,
        default=None,
        help="iterations per phase (default 60, seed 000 Table 1; NAFSA on the default "
        "whitened blocks: 12)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument(
        "--slews",
        dest="slews",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="use the slews kept by `recal positions` in POSITIONS.slews.npz (default: when "
        "that file exists); --slews without it is an error",
    )
    p.add_argument(
        "--known-rotations",
        metavar="FILE.csv",
        help="commanded rotations of the slews (an indexing mechanism or fixture): CSV with "
        "axis_x,axis_y,axis_z,angle_deg[,sigma_deg][,window], one row per slew in order (row k: "
        "from window k to k+1), axis in the first window's sensor axes; the gyro frame and scale "
        "are then tied to the case (docs/engine.md)",
    )
    p.add_argument(
        "--turn-closure",
        metavar="DEG",
        type=float,
        default=None,
        help="declare that slews which turn whole revolutions about the vertical and come back "
        "to the same tilt close exactly (k x 360 deg), with this 1-sigma in deg (e.g. 0.1 for "
        "turns put back against a table edge); default 0: none declared, a turn is closed only "
        "where the Earth-rate headings of its two windows check it (a FOG; docs/engine.md)",
    )
    add_wander_argument(p)


def add_wander_argument(p: argparse.ArgumentParser) -> None:
    """``--wander``: the bias wander between windows (recal.solve.wander)."""
    p.add_argument(
        "--wander",
        metavar="auto|none|FILE.json",
        default="auto",
        help="bias wander between windows, which share noise the closer they are in time: "
        "auto (default: estimated from the fit's residuals with the windows' start_s/end_s, "
        "kept when a likelihood-ratio test says so), none (windows independent), or a JSON "
        "file with a 'wander' block (recal noise --json, or calibrate's noise_model)",
    )


def wander_option(value: str | None):
    """``--wander`` as CalibrationOptions.wander."""
    import json
    from pathlib import Path

    from recal.errors import RecalInputError
    from recal.solve.wander_model import WanderModel

    if value in (None, "none"):
        return None
    if value == "auto":
        return "auto"
    path = Path(value)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise RecalInputError(f"--wander {value}: {exc.strerror or exc}") from exc
    except json.JSONDecodeError as exc:
        raise RecalInputError(f"--wander {value}: not JSON ({exc})") from exc
    block = data.get("wander") if isinstance(data, dict) else None
    if block is None and isinstance(data, dict):
        block = (data.get("noise_model") or {}).get("wander")
    if isinstance(data, dict) and "wander" in data and data["wander"] is None:
        raise RecalInputError(
            f"--wander {value}: the file holds no wander model (recal noise found none: some "
            "axis's Allan deviation still falls at the longest averaging time, so its wander is "
            "slower than the recording shows); use auto or none"
        )
    if not isinstance(block, dict):
        raise RecalInputError(
            f"--wander {value}: no 'wander' block (expected recal noise --json output or "
            "calibrate's noise_model); use auto or none"
        )
    return WanderModel.from_json_dict(block, source=f"given ({path.name})")


def options_from_args(args: argparse.Namespace, positions=None) -> CalibrationOptions:
    """The options of the command line; ``positions`` (loaded when None and a slews side file
    exists) are what the side file is checked against."""
    from recal.errors import RecalInputError
    from recal.model.terms import catalogue_terms
    from recal.solve.options import CalibrationOptions
    from recal.solve.swarm import SwarmConfig
    from service.cli.common import load_coefficients, load_plugin, parse_effects

    plugin_terms = [t for path in args.plugin for t in load_plugin(path)]
    terms = {**catalogue_terms(), **{t.name: t for t in plugin_terms}}
    prior = load_coefficients(args.prior, terms) if args.prior else None
    if prior is not None:
        _check_prior_plugins(prior, terms, args.prior)
    import numpy as np

    latitude = args.latitude
    lat_col = None if positions is None else positions.columns.get("latitude_deg")
    lat_col = None if lat_col is None else np.asarray(lat_col, float)
    if lat_col is not None and np.isfinite(lat_col).any():
        # the ship's GNSS, per window (recal positions --nmea, [nav]): each window is judged
        # at its own latitude; --latitude only fills windows without one
        if latitude is None:
            latitude = float(np.nanmedian(lat_col))
    elif latitude is None:
        print(
            "recal: --latitude not given, assuming 45 deg (gravity and the dot product "
            "depend on it)",
            file=sys.stderr,
        )
    if (args.fish is not None and args.fish < 2) or (
        args.iterations is not None and args.iterations < 1
    ):
        raise RecalInputError("--fish must be at least 2 and --iterations at least 1")
    swarm = None
    if args.fish is not None or args.iterations is not None:
        from recal.solve.calibrate import WHITENED_NAFSA_ITERATIONS
        from recal.solve.mcs import solver_for

        cfg_cls = solver_for(args.method)[1] if args.method != "lm" else SwarmConfig
        extra = {"cf_mode": "literal"} if args.paper and args.method == "nafsa" else {}
        iterations = args.iterations
        if iterations is None:  # --fish alone: the method's own default iterations
            whitened = args.method == "nafsa" and not args.paper
            iterations = WHITENED_NAFSA_ITERATIONS if whitened else cfg_cls().iterations
        swarm = cfg_cls(fish=50 if args.fish is None else args.fish, iterations=iterations,
                        **extra)  # fmt: skip
    slews = load_slews(args, positions)
    fleet, months = _fleet_prior(args)
    return CalibrationOptions(
        fleet_prior=fleet,
        prior_age_months=months,
        slews=slews,
        known_rotations=load_known_rotations(args, slews),
        **_turn_closure(args),
        sensor=args.sensor,
        method=args.method,
        mc_runs=args.mc,
        seed=args.seed,
        latitude_deg=45.0 if latitude is None else latitude,
        height_m=args.height,
        prior=prior,
        effects=parse_effects(args.effects),
        plugin_terms=plugin_terms,
        paper=args.paper,
        polish=args.polish,
        swarm_config=swarm,
        wander=wander_option(getattr(args, "wander", None)),
    )


def _turn_closure(args: argparse.Namespace) -> dict[str, float]:
    """``--turn-closure DEG`` as CalibrationOptions.turn_closure_sigma_deg: the declared closed
    turns' 1-sigma (not given or 0: none declared, only turns checked by Earth rate)."""
    from recal.errors import RecalInputError

    value = getattr(args, "turn_closure", None)
    if value is None:
        return {}
    if not (value >= 0 and value < 180):
        raise RecalInputError(f"--turn-closure must be between 0 and 180 deg, not {value}")
    return {"turn_closure_sigma_deg": float(value)}


def _fleet_prior(args: argparse.Namespace) -> tuple[Any, float | None]:
    """``--fleet-prior`` read and checked (format first), with ``--prior-age-months``."""
    from recal.errors import RecalInputError
    from recal.fleet.prior import read_fleet_prior
    from service.cli.common import read_text

    path, months = getattr(args, "fleet_prior", None), getattr(args, "prior_age_months", None)
    if path is None and months is None:
        return None, None
    if path is None or months is None or not getattr(args, "prior", None):
        raise RecalInputError("--fleet-prior and --prior-age-months go together, with --prior "
                              "(the calibration the months are counted from)")  # fmt: skip
    if not months >= 0:
        raise RecalInputError(f"--prior-age-months must be >= 0, not {months:g}")
    return read_fleet_prior(read_text(path, "fleet prior"), source=str(path)), months


def _check_prior_plugins(prior, terms: dict, path: str) -> None:
    """A prior holding a plugin effect needs that plugin: without it the effect would be
    dropped silently."""
    from recal.errors import RecalInputError
    from recal.model.plugins import builtin_names

    known = builtin_names() | set(terms)
    missing = [n for n in prior.values if n not in known]
    if missing:
        files = prior.metadata.get("plugins") or {}
        which = ", ".join(f"{n} (from {files[n]})" if n in files else n for n in missing)
        raise RecalInputError(
            f"{path} holds plugin effect(s) {which}: load the plugin with --plugin FILE.py"
        )


def load_slews(args: argparse.Namespace, positions=None):
    """The slews side file of the positions (recal.detect.slew_data.Slews), or None (--no-slews, absent,
    or written for another positions file: ignored with one line on stderr saying why, an
    error with an explicit --slews). Nothing is announced as used here: whether the fit uses
    them is known only after it (:func:`announce_slews`)."""

    from recal.detect.slew_data import Slews
    from recal.errors import RecalInputError
    from service.cli.common import load_positions, read_bytes
    from service.cli.positions import slews_path

    use = getattr(args, "slews", None)  # diagnose: when the side file exists
    if use is False:
        return None
    path = slews_path(args.positions)
    if not path.is_file():
        if use:
            raise RecalInputError(f"--slews: no slews file {path} (made by `recal positions`)")
        return None
    data = read_bytes(path, "slews file")
    slews = Slews.from_npz_bytes(data, str(path))
    why = side_file_mismatch(slews, positions if positions is not None else load_positions(
        args.positions))  # fmt: skip
    if why is None:
        return slews
    origin = f"it was written for another positions file than {args.positions}: {why}"
    if use:
        raise RecalInputError(f"--slews: {path}: {origin}; run `recal positions` to rebuild it")
    print(f"recal: ignoring {path}: {origin}; calibrating without slews (`recal positions` "
          "rebuilds the file; --no-slews skips it)", file=sys.stderr)  # fmt: skip
    return None


def side_file_mismatch(slews, positions) -> str | None:
    """Why a slews side file does not belong to these positions (window count or times, with
    the first window that differs), or None when it does."""
    import numpy as np

    cols = positions.columns
    if "start_s" not in cols or "end_s" not in cols:
        return "the positions file has no start_s/end_s columns to match its windows"
    why = slews.mismatch(cols["start_s"], cols["end_s"])
    if why is None or not why.startswith("the window times"):
        return why
    start, end = cols["start_s"][slews.first], cols["end_s"][slews.first]
    off = np.abs(start - slews.window_start_s[:, 0]) + np.abs(end - slews.window_end_s[:, 0])
    k = int(np.argmax(off > 0.5 * slews.period_s))
    row = int(slews.first[k])
    return (
        f"window {row} (0-based row) spans {start[k]:.6g}-{end[k]:.6g} s in the positions "
        f"file, {slews.window_start_s[k, 0]:.6g}-{slews.window_end_s[k, 0]:.6g} s in the "
        f"slews file ({len(positions)} windows here, {len(slews)} slews there)"
    )


def announce_slews(args: argparse.Namespace, slews, used: bool, notes: list[str]) -> None:
    """One line on stderr after the fit: the side file's slews were used, or why not (the
    engine's note), so the command never says 'using' and then 'not used'."""
    from service.cli.positions import slews_path

    if slews is None:
        return
    path = slews_path(args.positions)
    if used:
        print(f"recal: used {len(slews)} slews from {path}", file=sys.stderr)
        return
    why = next((n for n in notes if n.startswith("slews not used")), "slews not used")
    print(f"recal: {path}: {why}", file=sys.stderr)


def load_known_rotations(args: argparse.Namespace, slews):
    """``--known-rotations FILE`` (recal.detect.known_rotations.KnownRotations), or None."""
    path = getattr(args, "known_rotations", None)
    if path is None:
        return None
    from recal.detect.known_rotations import KnownRotations
    from recal.errors import RecalInputError
    from service.cli.common import read_text

    if slews is None:
        raise RecalInputError(
            "--known-rotations: no slews to attach them to (run `recal positions` without "
            "--no-slews, and calibrate without --no-slews)"
        )
    import numpy as np

    known = KnownRotations.from_csv_text(read_text(path, "known rotations file"), path)
    on = int(np.isin(known.slew, slews.first).sum())
    print(f"recal: {len(known)} known rotations from {path}, {on} on integrated slews",
          file=sys.stderr)  # fmt: skip
    return known


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "calibrate",
        help="estimate scale, bias, misalignment (...) from a positions CSV",
        description="Recalibrate gyro and/or accelerometer triads from static positions. "
        "Coefficients the positions cannot show are held at the prior and reported as 'held'.",
    )
    add_calibration_arguments(p)
    p.add_argument(
        "-o",
        "--output",
        metavar="COEFFS.json",
        help="write the coefficients (usable as the next --prior)",
    )
    p.add_argument(
        "--report",
        metavar="OUT.html",
        help="write an HTML report: coefficients, residual plots, observability",
    )
    p.set_defaults(func=run)
    return p


def result_plugins(args: argparse.Namespace) -> list:
    """The plugin terms of the command line (loaded again: cheap, and already checked)."""
    from service.cli.common import load_plugin

    return [t for path in args.plugin for t in load_plugin(path)]


def run_calibration(args: argparse.Namespace) -> CalibrationResult:
    return _run_calibration(args)[0]


def _run_calibration(args: argparse.Namespace) -> tuple[CalibrationResult, CalibrationOptions]:
    from recal.solve.calibrate import calibrate
    from service.cli.common import load_positions, progress_bar

    positions = load_positions(args.positions)
    options = options_from_args(args, positions)
    if options.method == "lm":  # a step bar: thousands of windows with slews take seconds
        from recal.solve.calibrate import LM_STEPS

        bar = progress_bar(len(LM_STEPS), "LM", unit="step")
        try:
            result = calibrate(positions, options, progress=bar.update)
        finally:
            bar.close()
    else:
        bar = progress_bar(options.mc_runs, f"MCS-{options.method.upper()}")
        done = [0.0]

        def advance(runs: float) -> None:
            # the engine reports fractions of runs (a batch's cycles); the bar counts whole runs
            before, done[0] = done[0], done[0] + runs
            bar.update(int(done[0]) - int(before))

        try:
            result = calibrate(positions, options, progress=advance)
        finally:
            bar.close()
    announce_slews(args, options.slews, result.problem.slews is not None, result.notes)
    return result, options


def run(args: argparse.Namespace) -> int:
    from service.cli.common import atomic_write, print_json

    result, options = _run_calibration(args)
    # effects that move the core coefficients beyond diagnose's trust rule: said in the notes,
    # the JSON (effects_check) and the coefficients file's metadata (unconfirmed_effects);
    # imported only then (scipy.stats: seconds on a busy machine)
    check = None
    if options.effects:
        from recal.diagnose.effects import effects_check

        check = effects_check(result, options)
    if check and not check["trustworthy"]:
        result.notes.append(check["warning"])
        result.coefficients.metadata["unconfirmed_effects"] = check["effects"]
    unused = [t.name for t in result_plugins(args) if t.name not in result.terms]
    if unused:
        print(f"recal calibrate: plugin effect(s) {', '.join(unused)} loaded but not fitted: "
              "name them in --effects (recal diagnose tries them as candidates)",
              file=sys.stderr)  # fmt: skip
    doc = result.to_json_dict()
    if check is not None:
        doc["effects_check"] = check
    # heading and position error, before (the prior) and after, in a navigator's units
    from service.recalibration import navigation_summary

    doc["navigation"] = navigation_summary(result, prior_name=args.prior)
    # the full covariance beside the 1-sigma values: recal drift whitens with it (docs/drift.md)
    from recal.diagnose.drift_covariance import covariance_to_json

    doc["covariance"] = covariance_to_json(result.layout.names, result.covariance)
    # the temperature it was made at, carried by the coefficients file (docs/apply.md)
    from recal.model.published import calibration_temperature

    doc["coefficients"].setdefault("metadata", {})["calibration_temperature_c"] = (
        calibration_temperature(result.problem.positions.columns.get("temperature_c"))
    )
    if args.output:
        coefficients = {**doc["coefficients"], "covariance": doc["covariance"]}
        atomic_write(args.output, json.dumps(coefficients, indent=2) + "\n")
    if args.report:
        from recal.report.html import calibration_html

        title = f"recal calibrate {args.positions}"
        atomic_write(args.report, calibration_html(result, title, doc["navigation"]))
        print(f"recal calibrate: wrote the report to {args.report}", file=sys.stderr)
    if args.json:
        print_json(doc)
    else:
        sys.stdout.write(format_result(result) + f"navigation: {doc['navigation']['summary']}\n")
    return 0


def format_result(r: CalibrationResult) -> str:
    """Human-readable report: one line per coefficient, then residuals and observability."""
    import numpy as np

    lines = [
        f"recal calibrate: {r.method}, {r.problem.M} positions, sensor "
        f"{'+'.join(r.problem.sensors)}, latitude {r.problem.latitude_deg:g} deg "
        f"(g = {r.problem.gravity_g:.6f} g0), {r.wall_time_s:.2f} s",
        "",
        f"{'coefficient':34s} {'value':>16s} {'1-sigma':>13s} "
        + (f"{'MC std':>11s} " if r.mcs is not None else "")
        + " status",
    ]
    names = r.layout.names
    sd = np.concatenate([r.uncertainty[n] for n in r.layout.term_slices()])
    status = np.concatenate([r.status[n] for n in r.layout.term_slices()])
    for i, name in enumerate(names):
        term = r.layout.term_of()[i]
        unit = term.unit_of(term.params.index(name.rsplit(".", 1)[1]))
        sig = f"{sd[i]:13.4g}" if np.isfinite(sd[i]) else f"{'-':>13s}"
        mc = f"{r.mcs.std[i]:11.3g} " if r.mcs is not None else ""
        partial = status[i] == "estimated" and r.observability.share[i] < 0.99
        state = "estimated*" if partial else status[i]
        lines.append(f"{name:34s} {r.theta[i]:16.9g} {sig} {mc} {state:10s} [{unit}]")
    if r.mcs is not None and r.method.endswith("(paper mode)"):
        lines.append(
            f"MC std: the spread of the coefficient over the {r.mcs.runs.shape[0]} Monte Carlo "
            "runs of the swarm (seed 000's MCS): how repeatably the solver lands on these "
            "windows, not how well they determine the coefficient (that is 1-sigma)"
        )
    elif r.mcs is not None:
        lines.append(
            f"MC std: the spread of the coefficient over the {r.mcs.runs.shape[0]} Monte Carlo "
            "runs of the swarm (seed 000's MCS), each fitted to the windows perturbed by their "
            "noise: a check on 1-sigma (the reported uncertainty), plus the solver's own scatter"
        )
    lines.append("")
    lines.append(f"{'invariant':12s} {'RMS before':>12s} {'RMS after':>12s} {'noise floor':>12s}")
    for n, v in r.residual_summary().items():
        floor = f"{v['noise_floor']:12.4g}" if v["noise_floor"] is not None else f"{'unknown':>12s}"
        lines.append(
            f"{n:12s} {v['rms_before']:12.4g} {v['rms_after']:12.4g} {floor}  [{v['unit']}]"
        )
    if math.isfinite(r.chi2_red):
        lines.append(f"chi2_red = {r.chi2_red:.3f}")
    else:
        lines.append("chi2_red = n/a (exactly determined: the residuals cannot check the fit)")
    lines.append("")
    lines.append(f"observability: {r.observability.verdict} -- {r.observability.message}")
    if any(r.observability.share[r.observability.estimated] < 0.99):
        lines.append(
            "estimated*: only part of this coefficient is seen (e.g. the sum Exz+Eyz); the "
            "rest is held at the prior"
        )
    lines.append(f"prior: {r.prior_source}")
    if r.held_uncertainty is not None and r.observability.null.shape[1]:
        lines.append(
            "1-sigma: window noise plus what the held directions' prior uncertainty moves each "
            f"coefficient by ({r.held_uncertainty.sensor_class} defaults where the prior has none)"
        )
    if r.convergence:
        c = r.convergence
        lines.append(
            "converged: yes" if c.get("converged") else f"converged: NO -- {c.get('reason')}"
        )
    for note in r.notes:
        lines.append(f"note: {note}")
    return "\n".join(lines) + "\n"
