"""The ``recal positions --report`` page: what the static-window detector saw, as one HTML string.

The page shows the recording's moving-variance traces (log scale) with the thresholds, the gyro
and accel signals against time, the static windows found (shaded, numbered as the rows of the
positions CSV) and the quiet stretches rejected, marked by reason. It is what a user checks first
on a new recording: are the thresholds between the still and the moving levels, did every pose
give a window, why was a stretch left out.

Memory stays bounded on long recordings: :class:`RecordingEnvelope` is fed by the detector's
``on_traces`` callback during the streaming pass and keeps a min / max / mean envelope per bucket
of frames (buckets double in length as the recording grows), never the samples themselves.
Strings only; the caller writes the file.
"""

from __future__ import annotations

import html
from collections.abc import Sequence

import numpy as np

from recal.detect.floor import NoiseFloor
from recal.detect.static_report import REJECT_REASONS, DetectionReport
from recal.detect.windows import Window
from recal.report.plots import WINDOW, figure_svg, html_page, new_figure, time_unit

#: Default bucket target: the envelope keeps between this many and twice as many buckets.
ENVELOPE_POINTS = 1000
#: Channels of :class:`RecordingEnvelope`, in column order.
RECORDING_CHANNELS = (
    "accel_trace",
    "gyro_trace",
    "gyro_x",
    "gyro_y",
    "gyro_z",
    "accel_x",
    "accel_y",
    "accel_z",
    "temperature_c",
)
_REASON_STYLE = {  # colour, hatch: told apart in print as well as on screen
    "too_short": ("#e67e22", "/"),
    "invalid_status": ("#8e44ad", "x"),
    "sequence_gap": ("#c0392b", "\\"),
    "rotating": ("#2c3e50", "."),
    "gyro_not_still": ("#16a085", "|"),  # kept for the accelerometer: drawn over its window
}
_AXIS_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c")
_MAX_LABELLED_WINDOWS = 60  # more position numbers than this would overlap on the chart
_MAX_LISTED_REJECTIONS = 200
_MAX_SHADED_REJECTIONS = 300  # per reason; beyond, each is only a marker at the top


class TraceEnvelope:
    """Min, max and mean per bucket of consecutive frames, for several channels, any length.

    Buckets hold ``frames_per_bucket`` frames (a power of two). When more than twice
    ``max_points`` buckets are closed, neighbours are merged pairwise and the bucket length
    doubles, so memory stays between ``max_points`` and ``2 max_points`` buckets whatever the
    recording's length, and the result does not depend on how the frames were chunked.
    Non-finite values (invalid frames, unmeasured traces) are left out of a bucket's statistics.
    """

    def __init__(self, channels: Sequence[str], max_points: int = ENVELOPE_POINTS) -> None:
        if max_points < 1:
            raise ValueError("max_points must be >= 1")
        self.channels = tuple(channels)
        self.max_points = int(max_points)
        self.frames_per_bucket = 1
        self.frames = 0
        k = len(self.channels)
        # Row: frames, t_first, t_last, then per channel min (k), max (k), sum (k), count (k).
        self._width = 3 + 4 * k
        self._closed: list[np.ndarray] = []
        self._n_closed = 0
        self._partial: np.ndarray | None = None

    def feed(self, time_s: np.ndarray, values: np.ndarray) -> None:
        """Add frames: time (n,) in s and values (n, channels)."""
        t = np.asarray(time_s, dtype=float).reshape(-1)
        v = np.asarray(values, dtype=float).reshape(t.shape[0], len(self.channels))
        self.frames += t.shape[0]
        i = 0
        if self._partial is not None and t.size:
            need = self.frames_per_bucket - int(self._partial[0])
            head = self._reduce(t[:need], v[:need], min(need, t.shape[0]))[0]
            self._partial = self._combine(self._partial, head)
            i = min(need, t.shape[0])
            if self._partial[0] == self.frames_per_bucket:
                self._push(self._partial[None])
                self._partial = None
        b = self.frames_per_bucket
        full = (t.shape[0] - i) // b
        if full:
            self._push(self._reduce(t[i : i + full * b], v[i : i + full * b], b))
            i += full * b
        if i < t.shape[0]:
            self._partial = self._reduce(t[i:], v[i:], t.shape[0] - i)[0]
        while self._n_closed > 2 * self.max_points:
            self._merge()

    def result(self) -> dict[str, np.ndarray]:
        """``time_s`` (bucket centres, s) and per channel ``<name>_min``, ``_max``, ``_mean``
        (NaN in a bucket without a finite value)."""
        rows = list(self._closed)
        if self._partial is not None:
            rows.append(self._partial[None])
        arr = np.concatenate(rows) if rows else np.zeros((0, self._width))
        k = len(self.channels)
        lo, hi = arr[:, 3 : 3 + k], arr[:, 3 + k : 3 + 2 * k]
        total, count = arr[:, 3 + 2 * k : 3 + 3 * k], arr[:, 3 + 3 * k :]
        seen = count > 0
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(seen, total / count, np.nan)
        out = {"time_s": 0.5 * (arr[:, 1] + arr[:, 2])}
        for j, name in enumerate(self.channels):
            out[f"{name}_min"] = np.where(seen[:, j], lo[:, j], np.nan)
            out[f"{name}_max"] = np.where(seen[:, j], hi[:, j], np.nan)
            out[f"{name}_mean"] = mean[:, j]
        return out

    def _reduce(self, t: np.ndarray, v: np.ndarray, b: int) -> np.ndarray:
        """Rows for consecutive buckets of b frames (t.shape[0] a multiple of b)."""
        nb = t.shape[0] // b
        if nb == 0:
            return np.zeros((0, self._width))
        vb = v[: nb * b].reshape(nb, b, -1)
        ok = np.isfinite(vb)
        rows = np.empty((nb, self._width))
        k = len(self.channels)
        rows[:, 0] = b
        rows[:, 1], rows[:, 2] = t[: nb * b : b], t[b - 1 : nb * b : b]
        rows[:, 3 : 3 + k] = np.where(ok, vb, np.inf).min(axis=1)
        rows[:, 3 + k : 3 + 2 * k] = np.where(ok, vb, -np.inf).max(axis=1)
        rows[:, 3 + 2 * k : 3 + 3 * k] = np.where(ok, vb, 0.0).sum(axis=1)
        rows[:, 3 + 3 * k :] = ok.sum(axis=1)
        return rows

    def _combine(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Row(s) a followed by row(s) b, as one bucket each."""
        k = len(self.channels)
        out = np.empty(np.broadcast_shapes(a.shape, b.shape))
        out[..., 0] = a[..., 0] + b[..., 0]
        out[..., 1], out[..., 2] = a[..., 1], b[..., 2]
        out[..., 3 : 3 + k] = np.minimum(a[..., 3 : 3 + k], b[..., 3 : 3 + k])
        out[..., 3 + k : 3 + 2 * k] = np.maximum(
            a[..., 3 + k : 3 + 2 * k], b[..., 3 + k : 3 + 2 * k]
        )
        out[..., 3 + 2 * k :] = a[..., 3 + 2 * k :] + b[..., 3 + 2 * k :]
        return out

    def _push(self, rows: np.ndarray) -> None:
        self._closed.append(rows)
        self._n_closed += rows.shape[0]

    def _merge(self) -> None:
        arr = np.concatenate(self._closed)
        if arr.shape[0] % 2:  # the odd bucket out joins the open one (still < 2b frames)
            last = arr[-1]
            self._partial = last if self._partial is None else self._combine(last, self._partial)
            arr = arr[:-1]
        arr = self._combine(arr[0::2], arr[1::2])
        self._closed, self._n_closed = [arr], arr.shape[0]
        self.frames_per_bucket *= 2


class RecordingEnvelope(TraceEnvelope):
    """The envelope of :data:`RECORDING_CHANNELS`; pass :meth:`on_traces` to the detector."""

    def __init__(self, max_points: int = ENVELOPE_POINTS) -> None:
        super().__init__(RECORDING_CHANNELS, max_points)

    def on_traces(
        self, *, first_index, time_s, gyro, accel, temperature_c, valid, accel_trace, gyro_trace
    ) -> None:
        """recal.detect.static_detector.StaticDetector's ``on_traces`` callback: one batch of frames."""
        values = np.column_stack((accel_trace, gyro_trace, gyro, accel, temperature_c))
        values[~valid, 2:8] = np.nan  # an invalid frame may hold garbage
        self.feed(time_s, values)


def positions_html(
    envelope: TraceEnvelope,
    report: DetectionReport,
    windows: Sequence[Window],
    *,
    title: str = "recal positions",
    triads: Sequence[str] = ("gyro", "accel"),
    units: dict[str, str] | None = None,
    noise_floor: NoiseFloor | None = None,
    notes: Sequence[str] = (),
) -> str:
    """A self-contained HTML page: the detector's view of one recording (see module doc).

    ``units``: the input units of "gyro" and "accel" (e.g. deg/h, g, counts) for the labels;
    ``noise_floor``: the learned floor, drawn under the thresholds when given; ``notes``: lines
    about the input (what was read), shown above the summary.
    """
    esc = html.escape
    chart = positions_svg(envelope, report, windows, triads=triads, units=units,
                          noise_floor=noise_floor)  # fmt: skip
    lines = "".join(f"<li>{esc(s)}</li>" for s in [*notes, *report.summary_lines()])
    rows = []
    for i, w in enumerate(windows):
        temp = "" if not np.isfinite(w.temperature_c) else f"{w.temperature_c:.2f}"
        rows.append(
            f"<tr><td>{i}</td><td>{w.start_s:.2f}</td><td>{w.end_s:.2f}</td>"
            f"<td>{w.duration_s:.2f}</td><td>{w.samples}</td><td>{w.frames_lost}</td>"
            f"<td>{w.frames_invalid}</td><td>{temp}</td>"
            f"<td>{'both' if w.gyro_still else 'accel only'}</td></tr>"
        )
    stretches = sorted(report.rejected_stretches)
    rej = [
        f"<tr><td>{esc(why)}</td><td>{a:.2f}</td><td>{b:.2f}</td><td>{b - a:.2f}</td></tr>"
        for a, b, why in stretches[:_MAX_LISTED_REJECTIONS]
    ]
    more = len(stretches) - len(rej) + (sum(report.rejected.values()) - len(stretches))
    rejected_part = (
        "<p>No quiet stretch was rejected.</p>"
        if not stretches
        else "<table><tr><th>reason</th><th>start [s]</th><th>end [s]</th><th>length [s]</th>"
        f"</tr>{''.join(rej)}</table>" + (f"<p>... and {more} more.</p>" if more > 0 else "")
    )
    n = len(windows)
    return html_page(
        title,
        f"""<ul>{lines}</ul>
<h2>What the detector saw</h2>
<p>A frame is quiet when the moving variance (trace of the covariance over
{report.window_samples or "?"} frames) of both the accel and the gyro stays under its threshold
(dashed red). Quiet runs, trimmed at both ends, become the static windows (shaded green,
numbered as the rows of the positions CSV). Quiet stretches left out are marked by reason:
too short, cut by invalid frames or a sequence gap, or rotating (mean gyro off the reference).
A still stretch of the accelerometer in which the gyro never stays quiet long enough (a unit
held by hand: tremor) is kept for the accelerometer only and marked "gyro not still" over its
window; the gyro's static invariants leave it out.
Bands: min to max over {envelope.frames_per_bucket} frame(s) per point; lines: the mean.</p>
<figure data-windows="{n}" data-rejected="{len(stretches)}">{chart}</figure>
<h2>Static windows ({n})</h2>
<table><tr><th>position</th><th>start [s]</th><th>end [s]</th><th>duration [s]</th>
<th>samples</th><th>frames lost</th><th>frames invalid</th><th>temperature [degC]</th>
<th>still triads</th></tr>
{"".join(rows)}</table>
<h2>Rejected quiet stretches ({sum(report.rejected.values())})</h2>
{rejected_part}
""",
    )


def positions_figure(
    envelope: TraceEnvelope,
    report: DetectionReport,
    windows: Sequence[Window],
    *,
    triads: Sequence[str] = ("gyro", "accel"),
    units: dict[str, str] | None = None,
    noise_floor: NoiseFloor | None = None,
):
    """The matplotlib Figure of :func:`positions_html` (for the page, or a PNG to look at)."""
    units = {"gyro": "gyro units", "accel": "accel units", **(units or {})}
    env = envelope.result()
    scale, tu = time_unit(
        max(report.duration_s, float(env["time_s"][-1]) if env["time_s"].size else 0)
    )
    t = env["time_s"] / scale
    has_temp = np.isfinite(env.get("temperature_c_mean", np.zeros(0))).any()
    panels = [("trace", s) for s in ("accel", "gyro") if s in triads]
    panels += [("signal", s) for s in ("gyro", "accel") if s in triads]
    if has_temp:
        panels.append(("temperature", "temperature_c"))
    fig, axes = new_figure(len(panels), 1, size_in=(10.0, 2.3 * len(panels)), sharex=True)
    span = (0.0, max(report.duration_s, float(t[-1] * scale) if t.size else 1.0) / scale)
    for k, (ax, (kind, name)) in enumerate(zip(axes, panels, strict=True)):
        if kind == "trace":
            _trace_panel(ax, t, env, name, units[name], report, noise_floor)
        elif kind == "signal":
            _signal_panel(ax, t, env, name, units[name])
        else:
            _band(ax, t, env, "temperature_c", "#7f8c8d", "temperature")
            ax.set_ylabel("temperature\n[degC]")
        _shade(ax, windows, report.rejected_stretches, scale, k, numbered=k == 0)
        ax.set_xlim(*span)
        ax.grid(lw=0.3, alpha=0.6)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.005, 1.0), borderaxespad=0)
    axes[-1].set_xlabel(f"time from the start of the recording [{tu}]")
    return fig


def positions_svg(envelope, report, windows, **kw) -> str:
    """:func:`positions_figure` as an inline ``<svg>`` string."""
    return figure_svg(positions_figure(envelope, report, windows, **kw))


def _band(ax, t, env, name, colour, label, positive: bool = False) -> None:
    lo, hi, mean = env[f"{name}_min"], env[f"{name}_max"], env[f"{name}_mean"]
    if positive:  # log scale: zeros (noiseless or constant data) sit at the bottom edge
        floor = np.nanmin(np.where(hi > 0, hi, np.nan)) if (hi > 0).any() else 1.0
        lo, hi, mean = (np.where(v > 0, v, floor / 10) for v in (lo, hi, mean))
    ax.fill_between(t, lo, hi, color=colour, alpha=0.25, lw=0)
    ax.plot(t, mean, color=colour, lw=0.8, label=label)


def _trace_panel(ax, t, env, sensor, unit, report: DetectionReport, floor) -> None:
    colour = "#1f77b4" if sensor == "accel" else "#9b59b6"
    _band(ax, t, env, f"{sensor}_trace", colour, f"{sensor} moving variance", positive=True)
    ax.set_yscale("log")
    thr = report.accel_threshold if sensor == "accel" else report.gyro_threshold
    if thr is not None and thr > 0:
        ax.axhline(thr, color="#c0392b", ls="--", lw=1.2, label=f"threshold {thr:.3g}")
    level = None if floor is None else (floor.accel if sensor == "accel" else floor.gyro)
    if level:
        ax.axhline(level, color="#555", ls=":", lw=1.0, label=f"noise floor {level:.3g}")
    ax.set_ylabel(f"{sensor} moving\nvariance [({unit})²]")


def _signal_panel(ax, t, env, sensor, unit) -> None:
    for axis, colour in zip("xyz", _AXIS_COLOURS, strict=True):
        _band(ax, t, env, f"{sensor}_{axis}", colour, f"{sensor} {axis}")
    ax.set_ylabel(f"{sensor}\n[{unit}]")


def _shade(ax, windows, stretches, scale: float, panel: int, numbered: bool) -> None:
    """Static windows (one green rectangle each, gid ``static-windows-<panel>``) and the
    rejected stretches (hatched, one collection per reason, with a marker at the top)."""
    from matplotlib.collections import PolyCollection

    tr = ax.get_xaxis_transform()  # x in data, y in axes fraction: full-height spans

    def rects(pairs):
        return [[(a, 0), (a, 1), (b, 1), (b, 0)] for a, b in pairs]

    spans = [(w.start_s / scale, w.end_s / scale) for w in windows]
    pc = PolyCollection(rects(spans), transform=tr, facecolor=WINDOW, alpha=0.16, lw=0,
                        gid=f"static-windows-{panel}", label=f"static window ({len(spans)})")  # fmt: skip
    ax.add_collection(pc, autolim=False)
    if numbered and 0 < len(spans) <= _MAX_LABELLED_WINDOWS:
        for i, (a, b) in enumerate(spans):
            ax.text(0.5 * (a + b), 1.01, str(i), transform=tr, ha="center", va="bottom",
                    fontsize=6, color="#1e8449")  # fmt: skip
    for reason in REJECT_REASONS:
        picked = [(a / scale, b / scale) for a, b, why in stretches if why == reason]
        if not picked:
            continue
        colour, hatch = _REASON_STYLE[reason]
        if len(picked) <= _MAX_SHADED_REJECTIONS:  # more would merge into a wall: markers only
            spans = PolyCollection(rects(picked), transform=tr, facecolor=(colour, 0.08),
                                   edgecolor=(colour, 0.45), hatch=hatch, lw=0.4,
                                   gid=f"rejected-{reason}-{panel}")  # fmt: skip
            ax.add_collection(spans, autolim=False)
        mid = [0.5 * (a + b) for a, b in picked]
        ax.plot(mid, [0.96] * len(mid), transform=tr, ls="none", marker="v", ms=4, color=colour,
                label=f"rejected: {reason.replace('_', ' ')} ({len(picked)})")  # fmt: skip
