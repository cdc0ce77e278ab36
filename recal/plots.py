"""Charts for the HTML reports, drawn with matplotlib and returned as inline SVG strings.

A report must stay one self-contained file that opens offline on the vessel's computer, so each
chart is rendered on the server side to SVG text and embedded in the page; nothing is fetched
when the page is opened. No pyplot: figures are built from :class:`matplotlib.figure.Figure`
directly, which needs no GUI backend and keeps no global state between reports.

Everything here returns strings; writing a file is the caller's job (``recal`` does no I/O).
"""

from __future__ import annotations

import io
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # pragma: no cover - typing only
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

#: Default chart size in inches at 100 dpi: 9 x 3 in fits the 900 px report column.
DEFAULT_SIZE_IN = (9.0, 3.0)


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
    return text[start:] if start >= 0 else text
