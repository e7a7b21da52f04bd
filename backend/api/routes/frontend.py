"""The map (frontend/, built by Vite) at `/`, and the little it must know before sign-in."""

from fastapi import APIRouter, FastAPI
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles

from backend.api.deps import SettingsDep
from backend.api.schemas_map import MapConfig
from backend.config import Settings

router = APIRouter(tags=["map"])

NOT_BUILT = """<!doctype html><html lang="en"><head><meta charset="utf-8">
<title>slidewatch</title></head><body><h1>slidewatch</h1>
<p>The map is not built. <code>make run</code> builds it; by hand:
<code>cd frontend &amp;&amp; npm ci &amp;&amp; npm run build</code>.</p>
<p>The API is at <a href="/docs">/docs</a>.</p></body></html>"""


@router.get("/app-config.json", response_model=MapConfig, summary="What the map needs first")
def app_config(settings: SettingsDep) -> MapConfig:
    """Public: basemap and upload settings, needed before anyone signs in."""
    return MapConfig(
        basemap_url=settings.basemap_url or None,
        basemap_attribution=settings.basemap_attribution,
        upload_chunk_bytes=settings.upload_chunk_bytes,
        max_upload_bytes=settings.max_upload_bytes,
        version="0.1.0",
    )


def mount_frontend(app: FastAPI, settings: Settings) -> None:
    """Serve the built map: its page at `/` and its bundled files under `/assets`.

    Nothing is mounted at `/` itself: a catch-all there would answer 404 for API paths hit
    with another method (GDAL's HEAD before a GET) instead of the router's 405.
    """
    dist = settings.resolved_frontend_dir
    index = dist / "index.html"
    if index.is_file():
        app.mount("/assets", StaticFiles(directory=dist / "assets"), name="map-assets")

        @app.get("/", include_in_schema=False)
        def map_page() -> FileResponse:
            # Never cached: it names the current build's assets (whose names change).
            return FileResponse(index, headers={"Cache-Control": "no-cache"})

        return

    @app.get("/", include_in_schema=False)
    def map_not_built() -> HTMLResponse:
        return HTMLResponse(NOT_BUILT)
