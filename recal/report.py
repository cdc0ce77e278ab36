"""HTML reports of a calibration or a diagnosis: tables and inline SVG plots, as strings.

No plotting library is needed: the charts are plain SVG, so the report opens in any browser on
the vessel's computer and can be attached to an e-mail as one file. The caller writes it.
"""

from __future__ import annotations

import html
from collections.abc import Sequence

import numpy as np

from recal.calibrate import CalibrationResult
from recal.diagnose import Diagnosis

_W, _H, _PAD = 720, 220, 40
_STYLE = (
    "body{font-family:sans-serif;max-width:900px;margin:2em auto;color:#222}"
    "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px;font-size:13px}"
    "th{background:#f4f4f4}"
)


def _page(title: str, body: str) -> str:
    """A complete, self-contained HTML page (no external assets)."""
    t = html.escape(title)
    return (
        f'<!doctype html>\n<html><head><meta charset="utf-8"><title>{t}</title>'
        f"<style>{_STYLE}</style></head><body>\n<h1>{t}</h1>\n{body}</body></html>\n"
    )


def _bars(series: Sequence[tuple[str, np.ndarray, str]], floor: float | None, unit: str) -> str:
    """Grouped bars per position for several residual series, with a +-noise-floor band."""
    n = len(series[0][1])
    top = max(float(np.max(np.abs(s))) for _, s, _ in series)
    top = max(top, floor or 0.0, 1e-300) * 1.1
    x0, width = _PAD + 20, _W - _PAD - 30
    mid = _H / 2
    scale = (_H / 2 - 20) / top
    slot = width / n
    bw = slot * 0.8 / len(series)
    parts = [f'<svg width="{_W}" height="{_H}" xmlns="http://www.w3.org/2000/svg" '
             'font-family="sans-serif" font-size="11">']  # fmt: skip
    if floor:
        h = floor * scale
        parts.append(f'<rect x="{x0}" y="{mid - h:.1f}" width="{width}" height="{2 * h:.1f}" '
                     'fill="#e8f0e8"><title>noise floor (1 sigma)</title></rect>')  # fmt: skip
    parts.append(f'<line x1="{x0}" y1="{mid}" x2="{x0 + width}" y2="{mid}" stroke="#888"/>')
    for k, (label, values, colour) in enumerate(series):
        for i, v in enumerate(values):
            h = abs(v) * scale
            y = mid - h if v > 0 else mid
            x = x0 + i * slot + slot * 0.1 + k * bw
            parts.append(f'<rect x="{x:.1f}" y="{y:.1f}" width="{bw:.1f}" height="{h:.1f}" '
                         f'fill="{colour}"><title>{html.escape(label)} position {i}: '
                         f"{v:.4g} {html.escape(unit)}</title></rect>")  # fmt: skip
        parts.append(f'<text x="{x0 + 10 + 160 * k}" y="14" fill="{colour}">'
                     f"&#9632; {html.escape(label)}</text>")  # fmt: skip
    parts.append(f'<text x="4" y="{mid - _H / 2 + 30}">+{top:.3g}</text>')
    parts.append(f'<text x="4" y="{mid + _H / 2 - 24}">-{top:.3g}</text>')
    parts.append(f'<text x="{x0}" y="{_H - 4}">position (window) index; unit {html.escape(unit)}'
                 "; green band: noise floor</text>")  # fmt: skip
    parts.append("</svg>")
    return "".join(parts)


def diagnosis_html(d: Diagnosis, title: str = "recal diagnose") -> str:
    """A self-contained HTML page: invariants vs noise, candidate ranking, residual plots."""
    doc = d.to_json_dict()
    esc = html.escape
    rows = []
    for inv in doc["invariants"]:
        floor, ratio = inv["noise_floor"], inv["ratio"]
        floor_txt = "unknown" if floor is None else f"{floor:.4g}"
        ratio_txt = "" if ratio is None else f"{ratio:.2f}"
        rows.append(
            f"<tr><td>{esc(inv['name'])}</td><td>{inv['rms']:.4g}</td>"
            f"<td>{floor_txt}</td><td>{ratio_txt}</td>"
            f"<td>{esc(inv['unit'])}</td><td>{inv['worst_positions']}</td></tr>"
        )
    cands = []
    for c in doc["candidates"]:
        dbic = "-" if c["delta_bic"] is None else f"{c['delta_bic']:.1f}"
        p = "-" if c["p_value"] is None else f"{c['p_value']:.2g}"
        mark = "<b>yes</b>" if c["significant"] else "no"
        note = esc(c["reason"]) or esc(
            ", ".join(c["similar_to"]) and "cannot be told apart from " + ", ".join(c["similar_to"])
        )
        cands.append(
            f"<tr><td>{esc(c['effect'])}</td><td>{dbic}</td><td>{p}</td><td>{mark}</td>"
            f"<td>{c['explained_fraction']:.2f}</td><td>{esc(c['explanation'])}</td>"
            f"<td>{note}</td></tr>"
        )
    plots = []
    baseline = {inv["name"]: np.array(inv["per_position"]) for inv in doc["invariants"]}
    for inv in doc["invariants"]:
        name = inv["name"]
        series = [("current model", baseline[name], "#c0392b")]
        if d.suggested_effects:
            series.append(("with " + ", ".join(d.suggested_effects),
                           d.final_residuals[name], "#2471a3"))  # fmt: skip
        plots.append(f"<h3>{esc(name)} residual per position</h3>"
                     + _bars(series, inv["noise_floor"], inv["unit"]))  # fmt: skip
        if d.suggested_effects:  # zoomed: does the corrected model reach the noise band?
            plots.append(f"<h3>{esc(name)} with the suggested effects, zoomed</h3>"
                         + _bars(series[1:], inv["noise_floor"], inv["unit"]))  # fmt: skip
    suggestion = (
        "Add: <b>"
        + esc(", ".join(d.suggested_effects))
        + "</b> (recal calibrate --effects +"
        + esc(",+".join(d.suggested_effects))
        + f"); chi2_red {doc['chi2_red']:.3g} &rarr; "
        f"{doc['chi2_red_with_suggested']:.3g}."
        if d.suggested_effects
        else f"No candidate effect is significant; chi2_red {doc['chi2_red']:.3g}."
    )
    return _page(
        title,
        f"""<p>{suggestion}</p>
<h2>Invariants against their noise floor</h2>
<table><tr><th>invariant</th><th>RMS</th><th>noise floor</th><th>ratio</th><th>unit</th>
<th>worst positions</th></tr>{"".join(rows)}</table>
<h2>Candidate effects (best first)</h2>
<p>delta BIC &lt; 0 means the effect earns its parameters; significant: F-test p &lt;
{doc["alpha"]} (Bonferroni-corrected) and delta BIC &lt; 0; explained: share of the residual power
above the noise floor that the effect removes.</p>
<table><tr><th>effect</th><th>delta BIC</th><th>p</th><th>significant</th><th>explained</th>
<th>physics</th><th>note</th></tr>{"".join(cands)}</table>
{"".join(plots)}
""",
    )


def _singular_values(s: np.ndarray, names_kept: int, info_min: float) -> str:
    """Log-scale bars of the Jacobian's singular values with the observability threshold."""
    s = np.maximum(np.asarray(s, float), 1e-12)
    lo, hi = np.log10(min(s.min(), info_min) / 3), np.log10(s.max() * 3)
    x0, width = _PAD + 20, _W - _PAD - 30
    slot = width / len(s)

    def y(v: float) -> float:
        return 20 + (_H - 40) * (hi - np.log10(v)) / (hi - lo)

    parts = [f'<svg width="{_W}" height="{_H}" xmlns="http://www.w3.org/2000/svg" '
             'font-family="sans-serif" font-size="11">']  # fmt: skip
    for i, v in enumerate(s):
        colour = "#2471a3" if i < names_kept else "#aaa"
        top = y(v)
        parts.append(f'<rect x="{x0 + i * slot + 1:.1f}" y="{top:.1f}" width="{slot - 2:.1f}" '
                     f'height="{_H - 20 - top:.1f}" fill="{colour}"><title>s{i + 1} = {v:.3g}'
                     "</title></rect>")  # fmt: skip
    t = y(info_min)
    parts.append(f'<line x1="{x0}" y1="{t:.1f}" x2="{x0 + width}" y2="{t:.1f}" '
                 'stroke="#c0392b" stroke-dasharray="4 3"/>')  # fmt: skip
    parts.append(f'<text x="{x0}" y="12" fill="#c0392b">- - - observable above the dashed '
                 f"line (s = {info_min:g}: the data pin the direction down to its typical size);"
                 " grey: held at the prior</text>")  # fmt: skip
    parts.append(f'<text x="4" y="24">{10**hi:.2g}</text><text x="4" y="{_H - 22}">'
                 f"{10**lo:.2g}</text></svg>")  # fmt: skip
    return "".join(parts)


def calibration_html(result: CalibrationResult, title: str = "recal calibrate") -> str:
    """A self-contained HTML page for one calibration: coefficients with status and 1-sigma,
    residual per position before and after, and the observability spectrum."""
    from recal.observability import INFO_MIN

    esc = html.escape
    doc = result.to_json_dict()
    names = result.layout.names
    terms = result.layout.term_of()
    sd = np.concatenate([result.uncertainty[n] for n in result.layout.term_slices()])
    status = np.concatenate([result.status[n] for n in result.layout.term_slices()])
    rows = []
    for i, name in enumerate(names):
        unit = terms[i].unit_of(terms[i].params.index(name.rsplit(".", 1)[1]))
        state = status[i]
        if state == "estimated" and result.observability.share[i] < 0.99:
            state = "estimated (sum only)"
        sig = f"{sd[i]:.4g}" if np.isfinite(sd[i]) else "-"
        rows.append(f"<tr><td>{esc(name)}</td><td>{result.theta[i]:.10g}</td><td>{sig}</td>"
                    f"<td>{esc(state)}</td><td>{esc(unit)}</td></tr>")  # fmt: skip
    before = result.problem.raw_residuals(result.theta_prior[None])
    after = result.problem.raw_residuals(result.theta[None])
    plots = []
    for n, summary in doc["residuals"].items():
        series = [("prior", before[n][0], "#c0392b"), ("calibrated", after[n][0], "#2471a3")]
        plots.append(f"<h3>{esc(n)} residual per position</h3>"
                     + _bars(series, summary["noise_floor"], summary["unit"]))  # fmt: skip
    obs = result.observability
    held = "".join(f"<li>{esc(h)}</li>" for h in obs.held_directions) or "<li>none</li>"
    notes = "".join(f"<li>{esc(n)}</li>" for n in result.notes)
    return _page(
        title,
        f"""<p>{esc(result.method)}, {result.problem.M} positions, latitude {result.problem.latitude_deg:g}
deg, chi2_red {result.chi2_red:.3g}. Observability: <b>{esc(obs.verdict)}</b> &mdash;
{esc(obs.message)}</p>
<p>Prior: {esc(result.prior_source)}. 1-sigma: {esc(doc["uncertainty_kind"])}.</p>
{f"<ul>{notes}</ul>" if notes else ""}
<h2>Coefficients</h2>
<table><tr><th>coefficient</th><th>value</th><th>1-sigma</th><th>status</th><th>unit</th></tr>
{"".join(rows)}</table>
{"".join(plots)}
<h2>What the positions can show</h2>
<p>Singular values of the whitened Jacobian, each parameter scaled by its typical change.
Directions held at the prior:</p><ul>{held}</ul>
{_singular_values(obs.singular_values, obs.rank, INFO_MIN)}
""",
    )
