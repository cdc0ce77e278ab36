"""``recal drift``: have the coefficients drifted? A sequential test on a positions file.

Each row of POSITIONS.csv is a new static window; the test (:mod:`recal.diagnose.drift`) checks, window by
window in row order, whether the gyro norm, accelerometer norm and their dot product have moved
away from what the accepted coefficients (``--coefficients``) predict, beyond each window's own
noise and the coefficients' own uncertainty. It prints the statistic per window, the threshold
(derived from the configured false-alarm rate), the first window at which drift is declared and
which coefficient the change looks like. ``--report`` plots the statistic against time.

Only argparse is imported to build the parser; numpy and recal are imported by run().
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from service.cli.calibrate import add_site_options

#: An alarm before this row is more likely coefficients that never fitted than a change.
EARLY_ALARM_ROWS = 2


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "drift",
        help="sequential drift test of new static windows against accepted coefficients",
        description="Test, window by window, whether the coefficients have changed since they "
        "were accepted: a GLR test of a step in one coefficient on the gyro norm, accelerometer "
        "norm and dot product, whitened by each window's noise and the coefficients' own "
        "uncertainty. The threshold follows from the false-alarm rate (docs/drift.md).",
    )
    p.add_argument("positions", metavar="POSITIONS.csv", help="the new static windows, in order")
    p.add_argument(
        "--coefficients",
        required=True,
        metavar="COEFFS.json",
        help="the accepted coefficients (section 5 layout with 'uncertainty', or calibrate --json)",
    )
    add_site_options(p)
    p.add_argument(
        "--false-alarm-windows",
        type=float,
        default=720.0,
        metavar="N",
        help="mean windows between false alarms when nothing changes (default 720: one per 30 "
        "days at 24 windows a day)",
    )
    p.add_argument(
        "--lookback",
        type=int,
        default=30,
        metavar="W",
        help="windows searched for the change (default 30)",
    )
    p.add_argument(
        "--wander",
        choices=("auto", "none"),
        default="auto",
        help="bias wander between windows: auto (default) takes the windows as innovations "
        "under the wander the coefficients file's noise_model names (calibrate --json output; "
        "its triads not kept at their bound), so that wander is not read as a step; none: "
        "windows independent",
    )
    p.add_argument("--report", metavar="OUT.html", help="write an HTML page: statistic vs time")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from recal.diagnose.drift import DriftConfig, drift_inputs, drift_test
    from recal.errors import RecalInputError
    from service.cli.common import atomic_write, load_positions, print_json

    if args.false_alarm_windows <= 1 or args.lookback < 1:
        raise RecalInputError("--false-alarm-windows must exceed 1 and --lookback be at least 1")
    if args.latitude is None:
        print("recal: --latitude not given, assuming 45 deg (gravity and the dot product "
              "depend on it)", file=sys.stderr)  # fmt: skip
    from recal.solve.wander_model import possible_wander

    coefficients, covariance, noise_model = _load(args.coefficients)
    positions = load_positions(args.positions)
    lat = 45.0 if args.latitude is None else args.latitude
    wander = possible_wander(noise_model) if args.wander == "auto" else None
    inputs = drift_inputs(positions, coefficients, covariance, lat, args.height, wander=wander)
    result = drift_test(inputs, DriftConfig(args.false_alarm_windows, args.lookback))
    out = to_json(inputs, result)
    if result.alarm_window is not None and result.alarm_window < EARLY_ALARM_ROWS:
        out["notes"].append(
            f"drift declared at row {result.alarm_window}, on the first windows: the coefficients "
            "may not describe these windows at all (check --latitude, the units, and that the "
            "calibration fitted its own windows: its chi2_red)"
        )
    if args.report:
        atomic_write(args.report, report_html(out, f"recal drift {args.positions}"))
    if args.json:
        print_json(out)
    else:
        print(text_summary(out))
    if args.report:
        print(f"recal drift: wrote the report to {args.report}", file=sys.stderr)
    return 0


def _load(path: str):
    """A coefficients file, or a ``calibrate --json`` output (its coefficients + uncertainty),
    its ``"covariance"`` block (names + matrix) and ``"noise_model"`` when it has them."""
    from recal.errors import RecalInputError
    from recal.model.coefficient_schema import coefficients_block, parse_json
    from recal.model.coefficients import CoefficientSet
    from recal.model.terms import catalogue_terms
    from service.cli.common import read_text

    document = parse_json(read_text(path, "coefficients file"), path)
    data = coefficients_block(document, path)
    cs = CoefficientSet.from_json_dict(data, catalogue_terms(), source=str(path))
    cs.metadata["source"] = str(path)
    covariance = data.get("covariance")
    if covariance is not None and not isinstance(covariance, dict):
        raise RecalInputError(f"{path}: 'covariance' must be an object with names and matrix")
    noise_model = document.get("noise_model") if isinstance(document, dict) else None
    return cs, covariance, noise_model if isinstance(noise_model, dict) else None


def to_json(inputs, result) -> dict[str, Any]:
    """The command's JSON (docs/reference.md#cli): alarm_window, threshold, windows, suspects."""
    names = inputs.names
    windows = []
    for k in range(inputs.M):
        j = int(result.coefficient[k])
        entry = {
            "row": k,
            "statistic": float(result.statistic[k]),
            "alarm": bool(result.statistic[k] > result.threshold),
            "change_window": int(result.change_window[k]),
            "coefficient": names[j],
            "change": float(result.change[k]),
        }
        if inputs.time_s is not None:
            entry["time_s"] = float(inputs.time_s[k])
        windows.append(entry)
    return {
        "alarm_window": result.alarm_window,
        "threshold": result.threshold,
        "threshold_bound": result.threshold_bound,
        "threshold_runs": result.null_runs,
        "statistic": "GLR of a step in one coefficient, max over the change window and the "
        "coefficient (chi-square, 1 degree of freedom, under no change)",
        "false_alarm_windows": result.config.false_alarm_windows,
        "lookback": result.config.lookback,
        "directions": result.directions,
        "windows": windows,
        "suspects": result.suspects,
        "notes": list(inputs.notes),
    }


def text_summary(out: dict[str, Any]) -> str:
    lines = [f"{'row':>4} {'statistic':>10}  most like"]
    for w in out["windows"]:
        mark = "  ALARM" if w["alarm"] else ""
        lines.append(f"{w['row']:>4} {w['statistic']:>10.2f}  {w['coefficient']} "
                     f"(from row {w['change_window']}){mark}")  # fmt: skip
    how = (
        f"simulated null, {out['threshold_runs']} runs; union bound {out['threshold_bound']:.2f}"
        if out["threshold_runs"]
        else "union bound"
    )
    lines.append(
        f"threshold {out['threshold']:.2f} (one false alarm per {out['false_alarm_windows']:g} "
        f"windows; {out['lookback']} change windows x {out['directions']} coefficients; {how})"
    )
    alarm = out["alarm_window"]
    lines.append(f"first alarm: {'none' if alarm is None else f'row {alarm}'}")
    if out["suspects"]:
        s = out["suspects"][0]
        lead = "drift looks like" if alarm is not None else "largest change (not significant)"
        lines.append(f"{lead}: {s['description']} (from row {s['change_window']}, "
                     f"{abs(s['change']) / s['sigma']:.1f} sigma, rows up to {s['window']})")  # fmt: skip
        alike = [x["description"] for x in out["suspects"][1:] if x["alike"]]
        if alike and alarm is not None:
            lines.append("or, as likely on these windows: " + "; ".join(alike))
    lines += [f"note: {n}" for n in out["notes"]]
    return "\n".join(lines)


def report_html(out: dict[str, Any], title: str) -> str:
    """A self-contained page: the statistic per window against time, with the threshold."""
    import html

    import numpy as np

    from recal.report.plots import AFTER, BEFORE, figure_svg, html_page, new_figure, time_unit

    stat = np.array([w["statistic"] for w in out["windows"]])
    if all("time_s" in w for w in out["windows"]):
        t = np.array([w["time_s"] for w in out["windows"]])
        per, unit = time_unit(float(t.max() - t.min()) if t.size else 0.0)
        x, xlabel = t / per, f"window time ({unit})"
    else:
        x, xlabel = np.arange(stat.size), "window (row)"
    fig, (ax,) = new_figure(size_in=(9.0, 3.5))
    ax.plot(x, stat, "o-", color=AFTER, ms=3, label="drift statistic")
    ax.axhline(out["threshold"], color=BEFORE, ls="--", label=f"threshold {out['threshold']:.1f}")
    if out["alarm_window"] is not None:
        k = out["alarm_window"]
        ax.plot([x[k]], [stat[k]], "s", color=BEFORE, ms=8, label=f"first alarm (row {k})")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("GLR statistic (chi-square)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    body = f"<figure>{figure_svg(fig)}</figure>"
    body += '<pre style="white-space:pre-wrap">' + html.escape(text_summary(out)) + "</pre>"
    return html_page(title, body)
