"""The operator's dashboard at ``/``: current version, history, window coverage, health, log.

Everything the page loads comes from this package (``static/``) or from an installed Python
package (plotly's own ``plotly.min.js``), so it works on a ship without internet. The page is
static; its script reads the ordinary API (same origin, so :class:`service.api.OriginGuard`
lets it through) plus ``/dashboard/coverage``, which adds what the browser cannot work out
itself: the windows' gravity directions, the current fit's residual per window and which
orientations would show the held coefficients (:mod:`service.dashboard.coverage`). A strict
Content-Security-Policy forbids inline and foreign scripts on the page.
"""

from __future__ import annotations

import threading
from importlib import resources
from pathlib import Path
from typing import Any

from fastapi import FastAPI
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles

from service.store.records import CalibrationRecord
from service.store.repository import Store

STATIC = Path(str(resources.files(__package__) / "static"))
#: Plotly sets element styles and adds one <style> element, hence 'unsafe-inline' for styles
#: only; scripts come from this server and nowhere else.
CSP = (
    "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
    "img-src 'self' data:; connect-src 'self'; object-src 'none'; base-uri 'none'; "
    "frame-ancestors 'none'; form-action 'none'"
)
PAGE_HEADERS = {
    "Content-Security-Policy": CSP,
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-cache",
}


def plotly_js() -> Path:
    """``plotly.min.js`` as shipped inside the installed ``plotly`` Python package."""
    import plotly

    return Path(plotly.__file__).parent / "package_data" / "plotly.min.js"


def mount_dashboard(app: FastAPI, store: Store) -> None:
    """Add ``/``, ``/dashboard/static/*``, ``/dashboard/plotly.min.js``, ``/dashboard/coverage``
    and ``/dashboard/drift`` to ``app`` (none of them in the OpenAPI schema)."""
    app.mount("/dashboard/static", StaticFiles(directory=STATIC), name="dashboard-static")
    page = (STATIC / "index.html").read_text(encoding="utf-8")
    advice_cache = _AdviceCache()

    @app.get("/", include_in_schema=False)
    def dashboard() -> HTMLResponse:
        return HTMLResponse(page, headers=PAGE_HEADERS)

    @app.get("/dashboard/plotly.min.js", include_in_schema=False)
    def plotly_asset() -> FileResponse:
        return FileResponse(plotly_js(), media_type="text/javascript",
                            headers={"Cache-Control": "max-age=86400"})  # fmt: skip

    @app.get("/dashboard/drift", include_in_schema=False)
    def drift() -> dict[str, Any]:
        """The drift statistic over time (each look at new windows) and the last job's reason."""
        return drift_series(store)

    @app.get("/dashboard/coverage", include_in_schema=False)
    def coverage() -> dict[str, Any]:
        """Windows (time, temperature, gravity direction), the current fit's residual per
        window and the orientation advice for the current version."""
        from service.dashboard.coverage import windows

        table, ids = store.positions()
        current = store.current()
        out: dict[str, Any] = {"windows": windows(table, ids), "version": None,
                               "residuals": [], "advice": None}  # fmt: skip
        if current is not None:
            out["version"] = current.version
            out["residuals"] = fit_residuals(current)
            out["advice"] = advice_cache.get(current, table, ids)
        return out


#: Drift looks shown on the dashboard (one per window at most; the newest).
DRIFT_POINTS = 500


def drift_series(store: Store) -> dict[str, Any]:
    """The drift statistic at each look (the scheduler's ``drift`` events, oldest first) and
    why the newest version ran (its ``trigger`` and ``trigger_detail``)."""
    from service.triggers import describe_reason

    events = [e for e in store.events(limit=4 * DRIFT_POINTS) if e["kind"] == "drift"]
    points = [
        {"at": e["created_at"], "version": d.get("version"), "window": d.get("last_id"),
         "statistic": d.get("statistic"), "threshold": d.get("threshold"),
         "alarm": d.get("alarm_window") is not None, "suspect": d.get("suspect")}
        for e in reversed(events[:DRIFT_POINTS]) if isinstance(d := e.get("data") or {}, dict)
    ]  # fmt: skip
    newest = store.history(limit=1)
    reason = None
    if newest:
        why = newest[0].document.get("trigger_detail") or {"trigger": newest[0].trigger}
        reason = {"version": newest[0].version, "accepted": newest[0].accepted,
                  "trigger": newest[0].trigger, "text": describe_reason(why)}  # fmt: skip
    return {"points": points, "last_reason": reason}


def fit_residuals(record: CalibrationRecord) -> list[dict[str, Any]]:
    """Each invariant's residual per window of ``record`` (by position id) and noise floor."""
    used = record.positions_used
    out = []
    for name, block in (record.document.get("residuals") or {}).items():
        values = block.get("per_position") if isinstance(block, dict) else None
        if not isinstance(values, list) or len(values) != len(used):
            continue  # slews and rotations have no per-window residual
        out.append({"name": name, "unit": block.get("unit"), "noise_floor":
                    block.get("noise_floor"), "ids": used, "values": values})  # fmt: skip
    return out


class _AdviceCache:
    """The advice for the newest version only: it changes when a version is stored."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._key: int | None = None
        self._value: Any = None

    def get(self, record: CalibrationRecord, table: Any, ids: list[int]) -> Any:
        from recal.errors import RecalInputError
        from recal.model.positions import Positions
        from service.dashboard.coverage import orientation_advice

        with self._lock:
            if self._key != record.version:
                wanted = set(record.positions_used)
                rows = [i for i, pid in enumerate(ids) if pid in wanted]
                cols = {n: v[rows] for n, v in table.columns.items()}
                try:
                    value = orientation_advice(Positions.from_columns(cols), record.document)
                except (RecalInputError, ValueError, KeyError) as exc:
                    value = {"error": f"no advice for version {record.version}: {exc}"}
                self._key, self._value = record.version, value
            return self._value
