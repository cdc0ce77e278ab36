"""Charts for the HTML reports, drawn with matplotlib and returned as inline SVG strings.

A report must stay one self-contained file that opens offline on the vessel's computer, so each
chart is rendered on the server side to SVG text and embedded in the page; nothing is fetched
when the page is opened. No pyplot: figures are built from :class:`matplotlib.figure.Figure`
directly, which needs no GUI backend and keeps no global state between reports.

Everything here returns strings; writing a file is the caller's job (``recal`` does no I/O).
"""

from __future__ import annotations

import html
import io
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # pragma: no cover - typing only
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

_STYLE = (
    "body{font-family:sans-serif;max-width:1000px;margin:2em auto;color:#222}"
    "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px;font-size:13px}"
    "th{background:#f4f4f4}figure{margin:1em 0}svg{max-width:100%;height:auto}"
)

#: Default chart size in inches at 100 dpi: 9 x 3 in fits the 900 px report column.
DEFAULT_SIZE_IN = (9.0, 3.0)


def html_page(title: str, body: str) -> str:
    """A complete, self-contained HTML page (no external assets) around ``body``."""
    t = html.escape(title)
    return (
        f'<!doctype html>\n<html><head><meta charset="utf-8"><title>{t}</title>'
        f"<style>{_STYLE}</style></head><body>\n<h1>{t}</h1>\n{body}</body></html>\n"
    )


def new_figure(
    rows: int = 1, cols: int = 1, size_in: tuple[float, float] | None = None, **subplot_kw
) -> tuple[Figure, list[Axes]]:
    """A figure with ``rows x cols`` axes (returned flat, row by row) and a constrained layout."""
    from matplotlib.figure import Figure

    w, h = size_in or (DEFAULT_SIZE_IN[0], DEFAULT_SIZE_IN[1] * rows)
    fig = Figure(figsize=(w, h), dpi=100, layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False, **subplot_kw)
    return fig, [ax for row in axes for ax in row]


def figure_svg(fig: Figure) -> str:
    """The figure as an ``<svg>`` element (no XML prolog), ready to paste into HTML."""
    buf = io.StringIO()
    # svg.hashsalt keeps element ids stable, so the same report renders byte-identical SVG.
    import matplotlib

    with matplotlib.rc_context({"svg.hashsalt": "recal", "svg.fonttype": "none"}):
        fig.savefig(buf, format="svg", metadata={"Date": None, "Creator": None})
    text = buf.getvalue()
    start = text.find("<svg")
    text = text[start:] if start >= 0 else text
    # The RDF metadata block only names namespaces (URLs a reader might take for assets).
    meta0, meta1 = text.find("<metadata>"), text.find("</metadata>")
    if 0 <= meta0 < meta1:
        text = text[:meta0] + text[meta1 + len("</metadata>") :].lstrip("\n")
    return text


#: Colours shared by the reports: before / after a fit, noise band, static windows.
BEFORE, AFTER, NOISE, WINDOW = "#c0392b", "#2471a3", "#27ae60", "#27ae60"


def noise_band(ax: Axes, x, sigma, label: str = "noise band (±1σ)") -> None:
    """Shade ±sigma about zero: one value for all, or one per x (a step band centred on x)."""
    import numpy as np

    x = np.asarray(x, dtype=float)
    sigma = np.broadcast_to(np.asarray(sigma, dtype=float), x.shape)
    if x.size == 0 or not np.isfinite(sigma).any():
        return
    if x.size == 1:
        edges = np.array([x[0] - 0.5, x[0] + 0.5])
    else:
        mid = 0.5 * (x[1:] + x[:-1])
        edges = np.concatenate(([x[0] - (mid[0] - x[0])], mid, [x[-1] + (x[-1] - mid[-1])]))
    s = np.append(sigma, sigma[-1])
    ax.fill_between(edges, -s, s, step="post", color=NOISE, alpha=0.18, lw=0, label=label)


def residual_bars(
    ax: Axes,
    series: list[tuple[str, object, str]],
    sigma=None,
    unit: str = "",
    xlabel: str = "position number",
) -> None:
    """Grouped bars of residual series (label, values, colour) per position, the noise band
    (``sigma``: one value or one per position) shaded behind, zero line, legend and labels."""
    import numpy as np

    n = len(np.asarray(series[0][1]))
    x = np.arange(n)
    if sigma is not None:
        noise_band(ax, x, sigma)
    width = 0.8 / len(series)
    for k, (label, values, colour) in enumerate(series):
        ax.bar(x - 0.4 + width * (k + 0.5), np.asarray(values, dtype=float), width,
               color=colour, label=label)  # fmt: skip
    ax.axhline(0.0, color="#555", lw=0.6)
    ax.set_xlim(-0.7, n - 0.3)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(f"residual [{unit}]" if unit else "residual")
    if n <= 40:
        ax.set_xticks(x if n <= 20 else x[::2])
    ax.grid(axis="y", lw=0.3, alpha=0.6)
    # Above the axes, right-aligned: never over a bar (a title goes on the left).
    ax.legend(fontsize=8, loc="lower right", bbox_to_anchor=(1.0, 1.0), ncols=3, frameon=False,
              borderaxespad=0.1)  # fmt: skip


def time_unit(duration_s: float) -> tuple[float, str]:
    """(seconds per axis unit, label) for a time axis: s up to 20 min, min up to 10 h, then h."""
    if duration_s <= 1200:
        return 1.0, "s"
    if duration_s <= 36000:
        return 60.0, "min"
    return 3600.0, "h"
