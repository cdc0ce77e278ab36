"""HTML report of a diagnosis: tables and inline SVG plots, returned as a string.

No plotting library is needed: the charts are plain SVG, so the report opens in any browser on
the vessel's computer and can be attached to an e-mail as one file. The caller writes it.
"""

from __future__ import annotations

import html
from collections.abc import Sequence

import numpy as np

from recal.diagnose import Diagnosis

_W, _H, _PAD = 720, 220, 40


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
    return f"""<!doctype html>
<html><head><meta charset="utf-8"><title>{esc(title)}</title>
<style>body{{font-family:sans-serif;max-width:900px;margin:2em auto;color:#222}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:3px 8px;font-size:13px}}
th{{background:#f4f4f4}}</style></head><body>
<h1>{esc(title)}</h1>
<p>{suggestion}</p>
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
</body></html>
"""
