"""HTML reports of a calibration or a diagnosis: tables and inline SVG charts, as strings.

The charts are drawn with matplotlib (through :mod:`recal.report.plots`; matplotlib is imported only when a chart is drawn)
and embedded as SVG text, so the report is one self-contained file that opens offline in any
browser on the vessel's computer and can be attached to an e-mail. The caller writes it.
"""

from __future__ import annotations

import html
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from recal.diagnose.effects import Candidate, Diagnosis
from recal.report.plots import AFTER, BEFORE, html_page
from recal.solve.result import CalibrationResult

_TINY = 1e-300


def _sigma(problem, name: str) -> np.ndarray | None:
    """Per-residual 1-sigma of an invariant, or None when the noise is not known."""
    return np.asarray(problem.sigma[name], dtype=float) if problem.noise_known_for(name) else None


def _xlabel(name: str) -> str:
    return "slew residual number (2 per slew)" if name == "slew" else "position number"


def _residual_chart(
    name: str,
    series: Sequence[tuple[str, np.ndarray, str]],
    sigma: np.ndarray | None,
    unit: str,
) -> str:
    """Bars per position of each residual series over the shaded noise band; when the first
    series' scale hides the last one, a second panel shows the last one zoomed."""
    from recal.report.plots import figure_svg, new_figure, residual_bars

    first = float(np.max(np.abs(series[0][1]), initial=0.0))
    last = float(np.max(np.abs(series[-1][1]), initial=0.0))
    floor = 0.0 if sigma is None else float(np.max(sigma, initial=0.0))
    zoom = len(series) > 1 and first > 4.0 * max(last, floor, _TINY)
    fig, axes = new_figure(2 if zoom else 1, 1, size_in=(9.0, 2.9 * (2 if zoom else 1)))
    residual_bars(axes[0], list(series), sigma, unit, _xlabel(name))
    axes[0].set_title(f"{name} residual", fontsize=10, loc="left")
    if zoom:
        residual_bars(axes[1], list(series[-1:]), sigma, unit, _xlabel(name))
        axes[1].set_title(f"{name}: {series[-1][0]}, zoomed", fontsize=10, loc="left")
    return figure_svg(fig)


#: Axis label of each driving variable (context column) of the catalogue effects.
_DRIVER_LABELS = {
    "temperature_c": "temperature [degC]",
    "temperature_rate_c_per_h": "temperature rate [degC/h]",
    "time_h": "session time (window middle) [h]",
}


def _driver_columns(drivers: dict[str, np.ndarray], m: int) -> list[tuple[str, np.ndarray]]:
    """(axis label, (M,) values) per driving variable; a (M, 3) vector gives three columns."""
    cols = []
    for key, v in drivers.items():
        v = np.asarray(v, dtype=float)
        if v.shape == (m,):
            cols.append((_DRIVER_LABELS.get(key, key), v))
        elif v.shape == (m, 3):
            name = "specific force" if key == "specific_force_g" else key.replace("_", " ")
            unit = " [g]" if key == "specific_force_g" else " [body axes]"
            cols += [(f"{name} {ax}{unit}", v[:, j]) for j, ax in enumerate("xyz")]
    return cols


def _driver_chart(c: Candidate, invariants: list[dict], problem) -> str:
    """Residual against the candidate's driving variable(s), current model and with it added;
    one row per invariant of the candidate's sensor (and the dot product)."""
    from recal.report.plots import figure_svg, new_figure

    if not (c.identifiable and c.residuals_after and c.drivers):
        return ""
    sensor = c.effect.split(".", 1)[0]
    rows = [inv for inv in invariants
            if inv["name"] in (f"{sensor}_norm", "dot") and inv["name"] in c.residuals_after]  # fmt: skip
    m = len(rows[0]["per_position"]) if rows else 0
    cols = _driver_columns(c.drivers, m)
    if not rows or not cols:
        return ""
    fig, axes = new_figure(len(rows), len(cols), size_in=(9.0, 2.7 * len(rows)))
    for i, inv in enumerate(rows):
        name, unit = inv["name"], inv["unit"]
        before = np.asarray(inv["per_position"], dtype=float)
        after = np.asarray(c.residuals_after[name], dtype=float)
        sigma = _sigma(problem, name)
        floor = None if sigma is None else float(np.sqrt(np.mean(sigma**2)))
        for j, (label, x) in enumerate(cols):
            ax = axes[i * len(cols) + j]
            if floor:
                ax.axhspan(-floor, floor, color="#27ae60", alpha=0.18, lw=0,
                           label="noise floor (±1σ)")  # fmt: skip
            ax.axhline(0.0, color="#555", lw=0.6)
            ax.plot(x, before, "o", ms=4, color=BEFORE, mfc="none", label="current model")
            ax.plot(x, after, "x", ms=4, color=AFTER, label=f"with {c.effect}")
            ax.set_xlabel(label)
            if j == 0:
                ax.set_ylabel(f"{name} residual\n[{unit}]")
            ax.grid(lw=0.3, alpha=0.6)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside upper center", ncols=3,
               fontsize=8, frameon=False)  # fmt: skip
    return figure_svg(fig)


def _worst_cell(inv: dict) -> str:
    """The worst positions of an invariant (0-based rows), or its worst slews / rotations."""
    for key, label in (("worst_positions", ""), ("worst_slews", "slews "),
                       ("worst_rotations", "rotations ")):  # fmt: skip
        if key in inv:
            return label + ", ".join(map(str, inv[key]))
    return ""


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
            f"<td>{esc(inv['unit'])}</td><td>{_worst_cell(inv)}</td></tr>"
        )
    cands = []
    for c in doc["candidates"]:
        dbic = "-" if c["delta_bic"] is None else f"{c['delta_bic']:.1f}"
        p = "-" if c["p_value"] is None else f"{c['p_value']:.2g}"
        mark = "<b>yes</b>" if c["significant"] else "no"
        note = esc(c["reason"]) or "; ".join(
            f"confounded with {esc(o['effect'])} (signature correlation "
            f"{o['signature_correlation']:+.2f}, evidence ratio {o['evidence_ratio']:.3g}): "
            f"{esc(o['advice'])}"
            for o in c["confounded_with"]
        )
        if c["warning"]:
            note += f"<br><b>warning:</b> {esc(c['warning'])}"
        t = c["trade_off"]
        shift = f"{abs(t['shift_sigma']):.1f}&sigma; {esc(t['coefficient'])}" if t else "-"
        cands.append(
            f"<tr><td>{esc(c['effect'])}</td><td>{dbic}</td><td>{p}</td><td>{mark}</td>"
            f"<td>{c['explained_fraction']:.2f}</td><td>{shift}</td>"
            f"<td>{esc(c['explanation'])}</td><td>{note}</td></tr>"
        )
    plots = []
    problem = d.baseline.problem
    baseline = {inv["name"]: np.array(inv["per_position"]) for inv in doc["invariants"]}
    for inv in doc["invariants"]:
        name = inv["name"]
        series = [("current model", baseline[name], BEFORE)]
        if d.suggested_effects:
            series.append(("with " + ", ".join(d.suggested_effects),
                           d.final_residuals[name], AFTER))  # fmt: skip
        chart = _residual_chart(name, series, _sigma(problem, name), inv["unit"])
        per = "slew" if name == "slew" else "position"
        plots.append(f"<h3>{esc(name)} residual per {per}</h3>{chart}")
    drivers = []
    for c in d.candidates:
        chart = _driver_chart(c, doc["invariants"], problem)
        if chart:
            verdict = "suggested" if c.effect in d.suggested_effects else (
                "significant" if c.significant else "not significant")  # fmt: skip
            drivers.append(f"<h3>{esc(c.effect)}: delta BIC {c.delta_bic:.1f}, p {c.p_value:.2g}"
                           f" ({verdict})</h3>{chart}")  # fmt: skip
    driver_part = (
        "<h2>Residual against what drives each candidate</h2><p>Each identifiable candidate: "
        "the residual of the current model (circles) and with the candidate added (crosses) "
        "against the variable the effect depends on. A trend the candidate removes is why it "
        "is suggested; a cloud without a trend is noise it cannot explain. Shaded: the noise "
        "floor (&plusmn;1&sigma;, RMS over the positions).</p>" + "".join(drivers)
        if drivers
        else "<p>No candidate effect can be shown by these positions (see the notes above): "
        "there is no residual to plot against what would drive it.</p>"
    )
    suggestion = (
        "Add: <b>"
        + esc(", ".join(d.suggested_effects))
        + "</b> (recal calibrate --effects +"
        + esc(",+".join(d.suggested_effects))
        + f"); chi2_red {doc['chi2_red']:.3g} &rarr; "
        f"{doc['chi2_red_with_suggested']:.3g}."
        + ("" if d.trustworthy else " <b>Not confirmed</b>: see the verdict.")
        if d.suggested_effects
        else "No candidate effect is significant; chi2_red "
        + ("n/a (no redundancy)." if doc["chi2_red"] is None else f"{doc['chi2_red']:.3g}.")
    )
    verdict_cls = "color:#c0392b" if d.model_fails else ""
    return html_page(
        title,
        f"""<p>{suggestion}</p>
<p style="{verdict_cls}"><b>Verdict:</b> {esc(d.verdict)}</p>
{_notes_html(d)}
{_ladder_html(doc)}
{_parameters_html(d)}
<h2>Invariants against their noise floor</h2>
<table><tr><th>invariant</th><th>RMS</th><th>noise floor</th><th>ratio</th><th>unit</th>
<th>worst positions (0-based rows)</th></tr>{"".join(rows)}</table>
<h2>Candidate effects (best first)</h2>
<p>delta BIC &lt; 0 means the effect earns its parameters; significant: family-wise p
(parametric bootstrap over all candidates, with the real correlation of the residuals) &lt;
{doc["alpha"]} and delta BIC &lt; 0; explained: share of the residual power
above the noise floor that the effect removes.</p>
<p>Core shift: the largest move of a seed coefficient (scale, bias, misalignment) when the
effect is added, in that coefficient's 1&sigma; without it. A large shift of a coefficient the
effect is strongly correlated with is warned about: they trade off in these positions.
Confounded: the changes two candidates make to the residual are correlated (1: the same);
the evidence ratio is exp(-(BIC<sub>other</sub> - BIC<sub>this</sub>)/2).</p>
<table><tr><th>effect</th><th>delta BIC</th><th>p</th><th>significant</th><th>explained</th>
<th>core shift</th><th>physics</th><th>note</th></tr>{"".join(cands)}</table>
<h2>Residual per position</h2>
<p>Bars: each position's residual; shaded: the noise band (&plusmn;1&sigma; of each position).
A zoomed panel follows when the current model's scale hides the corrected one.</p>
{"".join(plots)}
{driver_part}
""",
    )


def _notes_html(d: Diagnosis) -> str:
    items = [f"<li>{html.escape(n)}</li>" for n in d.notes]
    items += [f"<li>{html.escape(k)}: r = {v:+.2f}</li>"
              for k, v in list(d.residual_correlations.items())[:5] if d.model_fails]  # fmt: skip
    return f"<ul>{''.join(items)}</ul>" if items else ""


def _ladder_html(doc: dict) -> str:
    """Baseline, then each suggested effect in turn: chi2_red, RMS / floor per invariant and
    the change of BIC at each step."""
    names = sorted({k for r in doc["ladder"] for k in r["rms_over_floor"]})
    head = "".join(f"<th>{html.escape(n)} RMS/floor</th>" for n in names)
    rows = []
    for r in doc["ladder"]:
        cells = "".join(
            f"<td>{r['rms_over_floor'][n]:.2f}</td>" if n in r["rms_over_floor"] else "<td>-</td>"
            for n in names
        )
        chi2 = "-" if r["chi2_red"] is None else f"{r['chi2_red']:.3g}"
        held = r.get("heldout_chi2_red")
        held = "-" if held is None else f"{held:.3g}"
        step = "-" if r["delta_bic"] is None else f"{r['delta_bic']:.1f}"
        rows.append(f"<tr><td>{html.escape(r['model'])}</td><td>{chi2}</td><td>{held}</td>"
                    f"{cells}<td>{step}</td></tr>")  # fmt: skip
    return (
        "<h2>Model ladder</h2><table><tr><th>model</th><th>chi2_red</th>"
        "<th>held out (leave-one-position-out chi2 / its expectation)</th>"
        f"{head}<th>delta BIC of the step</th></tr>{''.join(rows)}</table>"
    )


def _parameters_html(d: Diagnosis) -> str:
    """Fitted parameters of each significant candidate with their 1-sigma."""
    rows = []
    for c in d.candidates:
        if not (c.significant or c.effect in d.suggested_effects):
            continue
        for k, v in c.parameters.items():
            sd = c.uncertainty.get(k, float("nan"))
            rows.append(f"<tr><td>{html.escape(c.effect)}</td><td>{html.escape(k)}</td>"
                        f"<td>{v:.5g}</td><td>{sd:.2g}</td></tr>")  # fmt: skip
    if not rows:
        return ""
    return (
        "<h2>Fitted effect parameters</h2><p>Each significant candidate fitted on top of the "
        "current model, with its Gauss-Newton 1&sigma;.</p><table><tr><th>effect</th>"
        f"<th>parameter</th><th>value</th><th>1&sigma;</th></tr>{''.join(rows)}</table>"
    )


def _singular_values(s: np.ndarray, names_kept: int, info_min: float) -> str:
    """Log-scale bars of the Jacobian's singular values with the observability threshold."""
    from recal.report.plots import figure_svg, new_figure

    s = np.maximum(np.asarray(s, float), 1e-12)
    x = np.arange(1, s.size + 1)
    fig, (ax,) = new_figure(size_in=(9.0, 3.0))
    kept = x <= names_kept
    ax.bar(x[kept], s[kept], color=AFTER, label="estimated direction")
    if (~kept).any():
        ax.bar(x[~kept], s[~kept], color="#aaa", label="held at the prior")
    ax.axhline(info_min, color=BEFORE, ls="--", lw=1.2,
               label=f"observable above s = {info_min:g}")  # fmt: skip
    ax.set_yscale("log")
    ax.set_ylim(min(s.min(), info_min) / 3, s.max() * 3)
    ax.set_xlabel("direction number (largest singular value first)")
    ax.set_ylabel("singular value\n(whitened, per typical change)")
    if s.size <= 40:
        ax.set_xticks(x if s.size <= 20 else x[::2])
    ax.grid(axis="y", lw=0.3, alpha=0.6)
    ax.legend(fontsize=8, loc="lower right", bbox_to_anchor=(1.0, 1.0), ncols=3, frameon=False,
              borderaxespad=0.1)  # fmt: skip
    return figure_svg(fig)


def calibration_html(
    result: CalibrationResult,
    title: str = "recal calibrate",
    navigation: Mapping[str, Any] | None = None,
) -> str:
    """A self-contained HTML page for one calibration: coefficients with status and 1-sigma,
    residual per position before and after, and the observability spectrum; ``navigation``
    (the calibrate JSON's ``"navigation"`` block) adds the heading and position error figures."""
    from recal.solve.observability import INFO_MIN

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
        series = [("prior", before[n][0], BEFORE), ("calibrated", after[n][0], AFTER)]
        chart = _residual_chart(n, series, _sigma(result.problem, n), summary["unit"])
        plots.append(f"<h3>{esc(n)} residual per {'slew' if n == 'slew' else 'position'}</h3>"
                     + chart)  # fmt: skip
    obs = result.observability
    held = "".join(f"<li>{esc(h)}</li>" for h in obs.held_directions) or "<li>none</li>"
    notes = "".join(f"<li>{esc(n)}</li>" for n in result.notes)
    return html_page(
        title,
        f"""<p>{esc(result.method)}, {result.problem.M} positions, latitude {result.problem.latitude_deg:g}
deg, chi2_red {result.chi2_red:.3g}. Observability: <b>{esc(obs.verdict)}</b> &mdash;
{esc(obs.message)}</p>
<p>Prior: {esc(result.prior_source)}. 1-sigma: {esc(doc["uncertainty_kind"])}.</p>
{_navigation_paragraph(navigation)}
{f"<ul>{notes}</ul>" if notes else ""}
<h2>Coefficients</h2>
<table><tr><th>coefficient</th><th>value</th><th>1-sigma</th><th>status</th><th>unit</th></tr>
{"".join(rows)}</table>
<h2>Residuals before and after</h2>
<p>Bars: each position's residual with the prior and with the calibrated coefficients; shaded:
the noise band (&plusmn;1&sigma; of each position). A zoomed panel follows when the prior's
scale hides the calibrated residual.</p>
{"".join(plots)}
<h2>What the positions can show</h2>
<p>Singular values of the whitened Jacobian, each parameter scaled by its typical change.
Directions held at the prior:</p><ul>{held}</ul>
{_singular_values(obs.singular_values, obs.rank, INFO_MIN)}
""",
    )


def _navigation_paragraph(navigation: Mapping[str, Any] | None) -> str:
    """The navigator's figures (docs/navigation.md#heading), or nothing."""
    if not navigation or not isinstance(navigation.get("summary"), str):
        return ""
    return f"<p><b>Navigation</b>: {html.escape(navigation['summary'])}.</p>"
