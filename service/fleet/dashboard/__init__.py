"""The fleet dashboard (``GET /fleet/dashboard``): one static page in the vessel dashboard's
style, reading the shore's REST API with the token the user types (kept in sessionStorage).

Everything it loads is served here: its own page and script (``static/``), the vessel
dashboard's stylesheet (service/dashboard/static/dashboard.css) and ``plotly.min.js`` from the
installed plotly package; the vessel page's Content-Security-Policy applies (no external CDN,
no inline script). The page itself carries no data, so it needs no token; every read does.

``GET /fleet/dashboard/reanalysis`` is the page of the newest ``recal fleet reanalyse``: the
JSON that command keeps beside shore.toml (``SHORE.reanalysis.json``; ``recal fleet serve``
puts its path in ``app.state.reanalysis_path``), served to the administrator's token at
``GET /fleet/dashboard/reanalysis.json`` (404 before the first re-analysis).
"""

from __future__ import annotations

import hmac
from importlib import resources
from pathlib import Path

from fastapi import FastAPI, HTTPException, Request
from fastapi.responses import FileResponse, HTMLResponse

from service.dashboard import PAGE_HEADERS, STATIC, plotly_js

FLEET_STATIC = Path(str(resources.files(__package__) / "static"))
#: The page's own files, and the vessel dashboard's it reuses.
_ASSETS = {
    "fleet.js": (FLEET_STATIC / "fleet.js", "text/javascript"),
    "fleet.css": (FLEET_STATIC / "fleet.css", "text/css"),
    "reanalysis.js": (FLEET_STATIC / "reanalysis.js", "text/javascript"),
    "dashboard.css": (STATIC / "dashboard.css", "text/css"),
    "favicon.svg": (STATIC / "favicon.svg", "image/svg+xml"),
}


def mount_fleet_dashboard(app: FastAPI) -> None:
    """Add ``/fleet/dashboard`` and its assets under ``/fleet/dashboard/`` (not in the
    OpenAPI schema)."""
    page = (FLEET_STATIC / "index.html").read_text(encoding="utf-8")
    reanalysis_page = (FLEET_STATIC / "reanalysis.html").read_text(encoding="utf-8")

    @app.get("/fleet/dashboard", include_in_schema=False)
    def dashboard() -> HTMLResponse:
        return HTMLResponse(page, headers=PAGE_HEADERS)

    @app.get("/fleet/dashboard/reanalysis", include_in_schema=False)
    def reanalysis() -> HTMLResponse:
        return HTMLResponse(reanalysis_page, headers=PAGE_HEADERS)

    @app.get("/fleet/dashboard/reanalysis.json", include_in_schema=False)
    def reanalysis_json(request: Request) -> FileResponse:
        if not _administrator(request):
            raise HTTPException(401, "the administrator's Authorization: Bearer token is "
                                "required", {"WWW-Authenticate": "Bearer"})  # fmt: skip
        path = getattr(request.app.state, "reanalysis_path", None)
        if path is None or not Path(path).is_file():
            raise HTTPException(404, "no re-analysis yet: run recal fleet reanalyse --config "
                                "shore.toml (it keeps its JSON beside the config)")  # fmt: skip
        return FileResponse(path, media_type="application/json",
                            headers={"Cache-Control": "no-cache"})  # fmt: skip

    @app.get("/fleet/dashboard/plotly.min.js", include_in_schema=False)
    def plotly_asset() -> FileResponse:
        return FileResponse(plotly_js(), media_type="text/javascript",
                            headers={"Cache-Control": "max-age=86400"})  # fmt: skip

    for name, (path, media) in _ASSETS.items():
        app.add_api_route(f"/fleet/dashboard/{name}", _asset(path, media), methods=["GET"],
                          include_in_schema=False)  # fmt: skip


def _asset(path: Path, media: str):  # noqa: ANN202 - a route handler
    def asset() -> FileResponse:
        return FileResponse(path, media_type=media, headers={"Cache-Control": "no-cache"})

    return asset


def _administrator(request: Request) -> bool:
    """Whether the request carries the shore's administrator token (``[api] token``): the
    fleet-wide re-analysis is not a unit's to read."""
    admin = getattr(getattr(request.app.state, "fleet_api", None), "token", None)
    scheme, _, given = request.headers.get("authorization", "").partition(" ")
    if admin is None or scheme.lower() != "bearer" or not given:
        return False
    return hmac.compare_digest(given.strip().encode(), admin.get_secret_value().encode())
