"""``recal noise``: the noise of a recording's still stretches, per axis.

The recording is read as by ``recal positions`` (same input and detector options, shared from
:mod:`service.cli.positions`): a first pass learns the noise floor, a second finds the still
stretches (:mod:`recal.detect.static_detector`), a third keeps the samples inside them. Their pooled overlapping
Allan deviation (:mod:`recal.detect.noise`) gives per axis the white noise (angle random walk of a
gyro, velocity random walk of an accelerometer), the bias instability and the correlation time
of a fitted white + Gauss-Markov model; ``--report`` plots the Allan deviations with their
confidence band and the model.

Only argparse is imported to build the parser; numpy, recal and drivers are imported by run().
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

#: Samples kept from the still stretches at most; beyond it pairs of samples are averaged (the
#: shortest averaging times are then lost, the rate halves) until they fit: 8 M frames of 6 axes
#: are 400 MB of float64.
MAX_FRAMES = 1 << 23
#: Units ``--units`` knows, with the factors that turn the white level (unit x sqrt(s)) into the
#: usual random-walk unit, and a bias into the usual bias unit.
GYRO_UNITS = {  # unit: (to deg/sqrt(h), to deg/h)
    "deg/h": (1 / 60, 1.0),
    "deg/s": (60.0, 3600.0),
    "rad/s": (60 * 180 / math.pi, 3600 * 180 / math.pi),
}
ACCEL_UNITS = {  # unit: (to m/s/sqrt(h), to ug)
    "g": (9.80665 * 60, 1e6),
    "m/s^2": (60.0, 1e6 / 9.80665),
}
USUAL = {"gyro": ("deg/sqrt(h)", "deg/h"), "accel": ("m/s/sqrt(h)", "ug")}


def register(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    from service.cli.positions import add_detector_options, add_input_options, add_kvh_unit_options

    p = sub.add_parser(
        "noise",
        help="noise of a recording's still stretches: random walk, bias instability, "
        "correlation time per axis",
        description="Find the still stretches of a recording (as `recal positions` does) and "
        "estimate, per axis, from their pooled overlapping Allan deviation: the white noise "
        "(angle random walk of a gyro, velocity random walk of an accelerometer, output units "
        "per sqrt(Hz), and deg/sqrt(h) or m/s/sqrt(h) when the units are known), the bias "
        "instability (minimum of the Allan deviation / 0.664) and the correlation time of a "
        "white + Gauss-Markov fit.",
    )
    add_input_options(p)
    p.add_argument(
        "--units",
        metavar="TRIAD=UNIT,...",
        help="the output units, for the usual random-walk units: gyro=deg/h|deg/s|rad/s, "
        "accel=g|m/s^2 (KVH formats: deg/h and g; others unknown unless given)",
    )
    p.add_argument(
        "--report",
        metavar="OUT.html",
        help="write an HTML page: the Allan deviation of each axis with its confidence band "
        "and the fitted model",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    add_kvh_unit_options(p)
    add_detector_options(p)
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from recal.errors import RecalInputError
    from service.cli.positions import (
        detect_file,
        detector_config,
        has_thresholds,
        learn_noise_floor,
    )
    from service.cli.recording import open_recording

    report_path = Path(args.report) if args.report else None
    if report_path and not (report_path.parent if str(report_path.parent) else Path(".")).is_dir():
        raise RecalInputError(f"output folder {report_path.parent} does not exist")
    units = parse_units(args.units, args.format)
    recording = open_recording(args)
    floor = None if has_thresholds(args) else learn_noise_floor(recording, args)
    windows, report = detect_file(recording, detector_config(args, recording, floor))
    if not windows:
        rejected = ", ".join(f"{k} {v}" for k, v in report.rejected.items() if v) or "none"
        raise RecalInputError(
            f"no still stretch found in {report.frames} frames (rejected: {rejected}): nothing "
            "to measure the noise on; check --threshold-k, --init-still and --min-duration"
        )
    rate = float(report.sample_rate_hz)
    segments, factor = collect_still_samples(recording, windows)
    result = summarize(segments, rate / factor, recording.triads, units)
    result["still_stretches"] = len(windows)
    result["still_duration_s"] = float(sum(w.duration_s for w in windows))
    result["sample_rate_hz"] = rate
    result["averaged_frames"] = factor
    if report_path:
        from service.cli.common import atomic_write

        names = " ".join(Path(p).name for p in args.inputs)
        atomic_write(report_path, report_html(result, f"recal noise {names}"))
    result["wander"] = wander_block(result["axes"])
    if args.json:
        print(json.dumps(_public(result)))
    else:
        print(text_summary(result))
        if result["wander"]:
            print(wander_line(result["wander"]))
    if report_path:
        print(f"recal noise: wrote the report to {report_path}", file=sys.stderr)
    return 0


def parse_units(text: str | None, fmt: str) -> dict[str, str | None]:
    """{"gyro": unit or None, "accel": unit or None} from ``--units`` and the format."""
    from drivers.registry import get_input_format
    from recal.errors import RecalInputError

    # the units the format gives (drivers.registry), when they are physical ones
    gyro, accel = get_input_format(fmt).units
    units: dict[str, str | None] = {
        "gyro": gyro if gyro in GYRO_UNITS else None,
        "accel": accel if accel in ACCEL_UNITS else None,
    }
    for item in filter(None, (text or "").split(",")):
        triad, _, unit = item.partition("=")
        known = {"gyro": GYRO_UNITS, "accel": ACCEL_UNITS}.get(triad.strip())
        if known is None or unit.strip() not in known:
            raise RecalInputError(
                f"--units: {item!r} is not gyro=({'|'.join(GYRO_UNITS)}) or "
                f"accel=({'|'.join(ACCEL_UNITS)})"
            )
        units[triad.strip()] = unit.strip()
    return units


def collect_still_samples(recording, windows) -> tuple[list[Any], int]:
    """Pass 3: the valid samples (gyro x y z, accel x y z) of each still stretch, (n_i, 6),
    averaged over ``factor`` consecutive frames when all of them would exceed MAX_FRAMES."""
    import numpy as np

    total = sum(w.samples for w in windows)
    factor = 1
    while total // factor > MAX_FRAMES:
        factor *= 2
    starts = np.array([w.start_index for w in windows])
    ends = np.array([w.end_index for w in windows])
    parts: list[list[Any]] = [[] for _ in windows]
    base = 0
    for frames in recording.frames():
        n = frames["time_s"].shape[0]
        idx = np.arange(base, base + n)
        base += n
        k = np.searchsorted(starts, idx, side="right") - 1
        inside = (k >= 0) & (idx <= ends[np.maximum(k, 0)])
        if frames.get("valid") is not None:
            inside &= np.asarray(frames["valid"], dtype=bool)
        if not inside.any():
            continue
        data = np.concatenate((frames["gyro"], frames["accel"]), axis=1)[inside]
        kk = k[inside]
        cuts = np.flatnonzero(np.diff(kk)) + 1
        for piece, w in zip(np.split(data, cuts), kk[np.r_[0, cuts]], strict=True):
            parts[int(w)].append(piece)
    segments = []
    for p in parts:
        x = np.concatenate(p) if p else np.zeros((0, 6))
        if factor > 1:
            m = x.shape[0] // factor
            x = x[: m * factor].reshape(m, factor, 6).mean(axis=1)
        if x.shape[0] >= 2:
            segments.append(x)
    return segments, factor


def summarize(segments, rate_hz: float, triads, units) -> dict[str, Any]:
    """The per-axis summary and the curves (for the report) of the still samples."""
    import numpy as np

    from recal.detect import noise
    from recal.errors import RecalInputError

    if not segments:
        raise RecalInputError("the still stretches hold fewer than 2 valid samples each")
    longest = max(s.shape[0] for s in segments)
    curve = noise.allan_deviation(segments, rate_hz, noise.octave_factors(longest, per_octave=4))
    axes, plots = [], []
    for c, name in enumerate(f"{s}_{a}" for s in ("gyro", "accel") for a in "xyz"):
        triad = name.split("_")[0]
        if triad not in triads:
            continue
        summary = noise.summarize_axis(curve, c, name)
        entry = summary.to_json()
        entry["kind"] = "angle random walk" if triad == "gyro" else "velocity random walk"
        entry["units"] = units.get(triad)
        unit = units.get(triad)
        if unit is not None:
            walk, bias = (GYRO_UNITS if triad == "gyro" else ACCEL_UNITS)[unit]
            entry["white_usual"] = summary.white * walk
            entry["bias_instability_usual"] = summary.bias_instability * bias
            entry["usual_units"] = list(USUAL[triad])
        axes.append(entry)
        alpha = summary.model.alpha(curve.m.astype(float))
        lo, hi = noise.deviation_interval(curve.adev[:, c], curve.edf(alpha))
        model = np.sqrt(summary.model.avar(curve.m.astype(float)))
        plots.append((name, curve.tau_s, curve.adev[:, c], lo, hi, model, summary))
    return {"axes": axes, "_plots": plots}


#: A Gauss-Markov process's Allan deviation peaks at an averaging time of about 1.89 tau.
GM_ALLAN_PEAK = 1.89


def wander_block(axes: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The bias wander between windows that ``recal calibrate --wander FILE`` takes
    (recal.solve.wander), per triad with all three axes: the Gauss-Markov part of the fit where
    it is significant, else the bias instability with a correlation time of its averaging time
    / 1.89 (where a Gauss-Markov process's Allan deviation peaks); none where neither is known
    (the curve still falls: the wander is slower than the recording shows)."""
    out: dict[str, Any] = {"kind": "gauss-markov", "source": "recal noise (still stretches)"}
    for triad in ("gyro", "accel"):
        rows = [a for a in axes if a["name"].startswith(triad + "_")]
        if len(rows) != 3:
            continue
        sigma, tau = [], []
        for a in rows:
            if a.get("gauss_markov_sigma") and a.get("correlation_time_s"):
                sigma.append(a["gauss_markov_sigma"])
                tau.append(a["correlation_time_s"])
            elif not a.get("bias_instability_upper_bound") and a.get("bias_instability"):
                sigma.append(a["bias_instability"])
                tau.append(a["bias_instability_tau_s"] / GM_ALLAN_PEAK)
            else:
                break
        else:
            out[triad] = {"sigma": sigma, "tau_s": tau}
    return out if ("gyro" in out or "accel" in out) else None


def wander_line(wander: dict[str, Any]) -> str:
    parts = [
        f"{t}: sigma {max(wander[t]['sigma']):.3g}, tau {max(wander[t]['tau_s']):.3g} s"
        for t in ("gyro", "accel")
        if t in wander
    ]
    return (
        "bias wander between windows (Gauss-Markov; recal calibrate --wander FILE takes this "
        "command's --json output): " + "; ".join(parts)
    )


def _public(result: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in result.items() if not k.startswith("_")}


def text_summary(result: dict[str, Any]) -> str:
    """One line per axis, then the still stretches used."""
    lines = []
    for a in result["axes"]:
        unit = a["units"] or "output units"
        tc = a["correlation_time_s"]
        usual = ""
        if "white_usual" in a:
            walk_u, bias_u = a["usual_units"]
            usual = (
                f" ({a['white_usual']:.4g} {walk_u}, {a['bias_instability_usual']:.4g} {bias_u})"
            )
        bound = "<=" if a["bias_instability_upper_bound"] else ""
        lines.append(
            f"{a['name']}: {a['kind']} {a['white']:.4g} {unit}/sqrt(Hz), bias instability "
            f"{bound}{a['bias_instability']:.4g} {unit} at {a['bias_instability_tau_s']:.3g} s"
            f"{usual}, correlation time "
            + (f"{tc:.3g} s" if tc is not None else "none (white at the times seen)")
        )
    lines.append(
        f"from {result['still_stretches']} still stretches, {result['still_duration_s']:.1f} s "
        f"at {result['sample_rate_hz']:.6g} Hz"
        + (
            f" (averaged over {result['averaged_frames']} frames)"
            if result["averaged_frames"] > 1
            else ""
        )
    )
    return "\n".join(lines)


def report_html(result: dict[str, Any], title: str) -> str:
    """A self-contained page: per axis, the Allan deviation with its 1-sigma band and the fit."""
    import html

    from recal.report.plots import AFTER, BEFORE, NOISE, figure_svg, html_page, new_figure

    parts = ['<pre style="white-space:pre-wrap">' + html.escape(text_summary(result)) + "</pre>"]
    for name, tau, adev, lo, hi, model, summary in result["_plots"]:
        fig, (ax,) = new_figure(size_in=(7.0, 4.0))
        ax.fill_between(tau, lo, hi, color=NOISE, alpha=0.25, label="1-sigma confidence")
        ax.loglog(tau, adev, "o-", color=AFTER, ms=3, label="Allan deviation")
        ax.loglog(tau, model, "--", color=BEFORE, label=_model_label(summary))
        ax.set_xlabel("averaging time (s)")
        ax.set_ylabel(f"Allan deviation of {name}")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
        parts.append(f"<h2>{html.escape(name)}</h2><figure>{figure_svg(fig)}</figure>")
    return html_page(title, "\n".join(parts))


def _model_label(summary) -> str:
    if summary.correlation_time_s is None:
        return "fit: white"
    return f"fit: white + Gauss-Markov (tau {summary.correlation_time_s:.3g} s)"
