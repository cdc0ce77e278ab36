"""``/docs``: Swagger UI from the installed ``swagger-ui-bundle-v2`` package (no CDN, so the
page works without internet access)."""

from __future__ import annotations

from fastapi import APIRouter, FastAPI, Request
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles

_DOCS_ASSETS = "/docs-assets"

router = APIRouter(include_in_schema=False)


def add_docs(app: FastAPI) -> None:
    """Serve the Swagger UI assets at ``/docs-assets`` and the page at ``/docs``."""
    from swagger_ui_bundle import swagger_ui_path

    app.mount(_DOCS_ASSETS, StaticFiles(directory=str(swagger_ui_path)), name="docs-assets")
    app.include_router(router)


@router.get("/docs")
def docs(request: Request) -> HTMLResponse:
    app = request.app
    root = request.scope.get("root_path", "")
    return get_swagger_ui_html(
        openapi_url=f"{root}{app.openapi_url}",
        title=f"{app.title} - API",
        swagger_js_url=f"{root}{_DOCS_ASSETS}/swagger-ui-bundle.js",
        swagger_css_url=f"{root}{_DOCS_ASSETS}/swagger-ui.css",
        swagger_favicon_url=f"{root}{_DOCS_ASSETS}/favicon-32x32.png",
        oauth2_redirect_url=None,
    )
