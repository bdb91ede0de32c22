"""The API docs page (`/api/v1/docs`) with swagger-ui's JavaScript and CSS served by the API
itself, from the `fastapi-offline` package: FastAPI's default page loads them from a CDN, which
leaves the page blank on a machine without internet."""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.openapi.docs import get_swagger_ui_html, get_swagger_ui_oauth2_redirect_html
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles


def swagger_assets() -> Path:
    """The folder of swagger-ui-bundle.js, swagger-ui.css and favicon.png."""
    return Path(str(files("fastapi_offline") / "static"))


def install_docs(app: FastAPI, prefix: str) -> None:
    """Serve `<prefix>/docs` (and its OAuth2 redirect) with assets under `<prefix>/docs-assets`."""
    assets = f"{prefix}/docs-assets"
    app.mount(assets, StaticFiles(directory=swagger_assets()), name="docs-assets")
    redirect = f"{prefix}/docs/oauth2-redirect"

    @app.get(f"{prefix}/docs", include_in_schema=False)
    def swagger_ui(request: Request) -> HTMLResponse:
        root = request.scope.get("root_path", "")  # behind a proxy that mounts the API under a prefix
        return get_swagger_ui_html(
            openapi_url=f"{root}{app.openapi_url}",
            title=f"{app.title} API",
            oauth2_redirect_url=f"{root}{redirect}",
            swagger_js_url=f"{root}{assets}/swagger-ui-bundle.js",
            swagger_css_url=f"{root}{assets}/swagger-ui.css",
            swagger_favicon_url=f"{root}{assets}/favicon.png",
        )

    @app.get(redirect, include_in_schema=False)
    def swagger_ui_redirect() -> HTMLResponse:
        return get_swagger_ui_oauth2_redirect_html()
