"""HTML report of ``recal navigate``: position-error curves per coefficient set, as a string.

One self-contained page (inline SVG through :mod:`recal.report.plots`): the horizontal error against
time with one curve per coefficient set (and its linear prediction, dashed, when given), the
north and east components, and a table of final/max errors in m and nmi. The caller writes it.
"""

from __future__ import annotations

import html
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from recal.nav.navigation import NMI_M
from recal.report.plots import figure_svg, html_page, new_figure, time_unit


def _table(runs: Sequence[Mapping[str, Any]]) -> str:
    head = (
        "<tr><th>coefficients</th><th>final error</th><th>max error</th><th>north</th>"
        "<th>east</th><th>Schuler amplitude</th><th>predicted (linear)</th></tr>"
    )
    rows = []
    for r in runs:
        pred = r.get("predicted_final_error_m")
        pred_txt = "" if pred is None else f"{pred:.0f} m ({pred / NMI_M:.3f} nmi)"
        sch = r.get("schuler_amplitude_m")
        sch_txt = "" if sch is None else f"{sch:.0f} m"
        rows.append(
            f"<tr><td>{html.escape(str(r['coefficients']))}</td>"
            f"<td>{r['final_error_m']:.1f} m ({r['final_error_nmi']:.3f} nmi)</td>"
            f"<td>{r['max_error_m']:.1f} m ({r['max_error_nmi']:.3f} nmi)</td>"
            f"<td>{r['north_error_m']:.1f} m</td><td>{r['east_error_m']:.1f} m</td>"
            f"<td>{sch_txt}</td><td>{pred_txt}</td></tr>"
        )
    return f"<table>{head}{''.join(rows)}</table>"


def navigation_html(
    runs: Sequence[Mapping[str, Any]],
    curves: Sequence[tuple[str, np.ndarray, np.ndarray, np.ndarray]],
    title: str = "recal navigate",
    notes: Sequence[str] = (),
    predictions: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
    against: str = "the start position (static recording)",
) -> str:
    """The page: ``runs`` as in the JSON output; ``curves`` (label, time_s, north_m, east_m)
    per coefficient set; ``predictions`` label -> (time_s, horizontal_m) from the linear model."""
    duration = max(float(c[1][-1]) for c in curves) if curves else 1.0
    scale, unit = time_unit(duration)
    fig, (ax_h, ax_n, ax_e) = new_figure(3, 1)
    for label, t, north, east in curves:
        (line,) = ax_h.plot(t / scale, np.hypot(north, east), label=label, lw=1.2)
        ax_n.plot(t / scale, north, color=line.get_color(), lw=1.0, label=label)
        ax_e.plot(t / scale, east, color=line.get_color(), lw=1.0, label=label)
        if predictions and label in predictions:
            tp, hp = predictions[label]
            ax_h.plot(tp / scale, hp, ls="--", color=line.get_color(), lw=1.0,
                      label=f"{label} (linear prediction)")  # fmt: skip
    ax_h.set_ylabel("horizontal error (m)")
    ax_n.set_ylabel("north error (m)")
    ax_e.set_ylabel("east error (m)")
    for ax in (ax_h, ax_n, ax_e):
        ax.set_xlabel(f"time since navigation start ({unit})")
        ax.grid(alpha=0.3)
    ax_h.legend(fontsize="small")
    body = [
        f"<p>Free-inertial navigation, position error against {html.escape(against)}. "
        "Best coefficient set first.</p>",
        _table(runs),
        figure_svg(fig),
    ]
    if notes:
        body.append("<ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in notes) + "</ul>")
    return html_page(title, "\n".join(body))
